"""`python -m lerobot_bavo.viz` = `bavo-view`."""

import sys

from lerobot_bavo.viz.cli import main

sys.exit(main())

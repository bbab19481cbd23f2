import sys

from lerobot_bavo.teleop.server import main

sys.exit(main())

"""Kept for imports written before the metrics moved below `envs/`: the formulas are
`lerobot_bavo.metrics`."""

from lerobot_bavo.metrics import *  # noqa: F403
from lerobot_bavo.metrics import __all__  # noqa: F401

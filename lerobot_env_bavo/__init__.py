"""Plugin shim: LeRobot's CLIs import every installed `lerobot_env_*` distribution by name.

Importing `lerobot_bavo` registers the gym ids, the `bavo` EnvConfig and the policy configs. The
CLIs (and only they, since only they import this module) also get the in-memory sample loading
of BAVO training views (`lerobot_bavo.datasets.fast`; opt out with BAVO_FAST_DATASET=0).
"""

import lerobot_bavo  # noqa: F401
from lerobot_bavo.datasets.fast import install_lerobot_train_hook

install_lerobot_train_hook()

"""Plugin shim: LeRobot's CLIs import every installed `lerobot_env_*` distribution by name.

Importing `lerobot_bavo` registers the gym ids, the `bavo` EnvConfig and the policy configs.
"""

import lerobot_bavo  # noqa: F401

"""lerobot-bavo: BAVO-Bench, demonstrations, and the ManiFlow / A-FAR policies for LeRobot."""

import os

# Headless EGL rendering by default; must be set before MuJoCo is first imported.
os.environ.setdefault("MUJOCO_GL", "egl")

# Registration side effects (each module is imported once, so repeated imports are harmless):
# gym ids `lerobot_bavo/<GymName>-v0` and LeRobot's env type "bavo".
import lerobot_bavo.envs  # noqa: E402, F401
import lerobot_bavo.envs.configs  # noqa: E402, F401

# LeRobot policy types "maniflow" and "afar".
import lerobot_bavo.policies  # noqa: E402, F401

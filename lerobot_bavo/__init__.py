"""lerobot-bavo: BAVO-Bench, demonstrations, and the ManiFlow / A-FAR policies for LeRobot."""

import os

# Headless EGL rendering by default; must be set before MuJoCo is first imported.
os.environ.setdefault("MUJOCO_GL", "egl")

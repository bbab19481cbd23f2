"""lerobot-bavo: BAVO-Bench, demonstrations, and the ManiFlow / A-FAR policies for LeRobot."""

import os
import sys

# Headless EGL rendering by default; must be set before MuJoCo is first imported.
os.environ.setdefault("MUJOCO_GL", "egl")

# `bavo-view` only reads datasets and writes rerun recordings: it skips the registrations below, whose
# LeRobot / PyTorch imports take seconds (BAVO_LIGHT_IMPORT=1 does the same in any program).
_LIGHT_IMPORT = os.environ.get("BAVO_LIGHT_IMPORT") == "1" or os.path.basename(sys.argv[0] if sys.argv else "") == "bavo-view"

if not _LIGHT_IMPORT:
    # Registration side effects (each module is imported once, so repeated imports are harmless):
    # gym ids `lerobot_bavo/<GymName>-v0` and LeRobot's env type "bavo".
    import lerobot_bavo.envs  # noqa: E402, F401
    import lerobot_bavo.envs.configs  # noqa: E402, F401

    # LeRobot policy types "maniflow" and "afar".
    import lerobot_bavo.policies  # noqa: E402, F401

"""lerobot-bavo: BAVO-Bench, demonstrations, and the ManiFlow / A-FAR policies for LeRobot."""

import os
import sys

# Headless EGL rendering by default; must be set before MuJoCo is first imported.
os.environ.setdefault("MUJOCO_GL", "egl")

# Gym ids `lerobot_bavo/<GymName>-v0` (light: MuJoCo and gymnasium, no PyTorch).
import lerobot_bavo.envs  # noqa: E402, F401

# LeRobot's env type "bavo" and policy types "maniflow" and "afar": these import LeRobot and PyTorch (seconds).
# They are skipped where nothing needs them: `bavo-view`, and the worker processes of `bavo-eval` /
# `bavo-collect` on Ray (BAVO_LIGHT_IMPORT=1, set by `runtime.ray_pool.worker_env_vars`), which step envs and
# experts; a worker that loads a checkpoint registers them then (`LeRobotPolicyAgent`, `register_lerobot_types`).
# `bavo-collect`'s own process needs LeRobot's dataset writer but none of these types; importing it lazily (when
# the dataset is opened) lets its worker processes start their set-up meanwhile (issue 11).
_LIGHT_IMPORT = (os.environ.get("BAVO_LIGHT_IMPORT") == "1"
                 or os.path.basename(sys.argv[0] if sys.argv else "") in ("bavo-view", "bavo-collect"))


def register_lerobot_types() -> None:
    """Register the "bavo" env type and the "maniflow" / "afar" policy types with LeRobot (idempotent: each
    module is imported once)."""
    import lerobot_bavo.envs.configs  # noqa: F401
    import lerobot_bavo.policies  # noqa: F401


if not _LIGHT_IMPORT:
    register_lerobot_types()

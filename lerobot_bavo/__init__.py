"""lerobot-bavo: BAVO-Bench, demonstrations, and the ManiFlow / A-FAR policies for LeRobot.

`import lerobot_bavo` is light (MuJoCo, gymnasium, numpy: no LeRobot, no PyTorch): it registers the gym
ids `lerobot_bavo/<GymName>-v0`, so that every CLI answers `--help` at once and worker processes that only
step envs and experts start quickly.

LeRobot's env type "bavo" and policy types "maniflow" / "afar" import LeRobot and PyTorch (seconds), so
they are registered explicitly, where they are needed, and never by guessing from the command line:

- LeRobot's CLIs (`lerobot-train`, `lerobot-eval`) import the plugin shim `lerobot_env_bavo`, which calls
  `register_lerobot_types()`;
- importing `lerobot_bavo.envs.configs` or `lerobot_bavo.policies` registers what they define (LeRobot's
  own convention: a config class registers itself where it is defined);
- loading a checkpoint (`eval.rollout.LeRobotPolicyAgent`, `checkpoints`) registers them first;
- the workers of a `runtime.pool.WorkerPool` register them unless the pool is `light_import=True`.
"""

import os

# Headless EGL rendering by default; must be set before MuJoCo is first imported.
os.environ.setdefault("MUJOCO_GL", "egl")

# Gym ids `lerobot_bavo/<GymName>-v0` (light: MuJoCo and gymnasium, no PyTorch).
import lerobot_bavo.envs  # noqa: E402, F401


def register_lerobot_types() -> None:
    """Register the "bavo" env type and the "maniflow" / "afar" policy types with LeRobot (idempotent: each
    module is imported once). Imports LeRobot and PyTorch."""
    import lerobot_bavo.envs.configs  # noqa: F401
    import lerobot_bavo.policies  # noqa: F401

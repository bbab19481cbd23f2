"""BAVO-Bench environments and their gymnasium registration.

Importing this package registers one gym id per implemented task, `lerobot_bavo/<GymName>-v0`
(e.g. `lerobot_bavo/CubeHandoff-v0`), so that `gym.make` and LeRobot's `EnvConfig.create_envs`
(including its AsyncVectorEnv workers, which re-import the package) find them. Keyword arguments
of `gym.make(id, **kwargs)` go to `BavoEnv` (condition, image_height, image_width, n_points,
point_frame, fovy, render_mode, render_height); `gym.make`'s own `max_episode_steps` sets the
`TimeLimit` wrapper (default: the task's limit), which is what LeRobot's rollout reads.
"""

from __future__ import annotations

import gymnasium as gym

from lerobot_bavo.envs.bavo_env import BavoEnv
from lerobot_bavo.envs.tasks import TASKS, gym_name

GYM_NAMESPACE = "lerobot_bavo"
ENTRY_POINT = "lerobot_bavo.envs.bavo_env:BavoEnv"


def gym_id(task: str) -> str:
    """The gym id of a BAVO-Bench task, e.g. `gym_id("cube_handoff") == "lerobot_bavo/CubeHandoff-v0"`."""
    TASKS.lookup(task)  # raises for unknown names, listing the registered ones
    return f"{GYM_NAMESPACE}/{gym_name(task)}-v0"


def register_envs() -> list[str]:
    """Register every task in `TASKS` with gymnasium; idempotent (call again after `register_task` to
    give a task registered later its gym id). Returns the ids registered now."""
    registered = []
    for name, task_cls in TASKS.items():
        env_id = gym_id(name)
        if env_id in gym.registry:
            continue
        gym.register(
            id=env_id,
            entry_point=ENTRY_POINT,
            kwargs={"task": name},
            max_episode_steps=task_cls.max_episode_steps,
        )
        registered.append(env_id)
    return registered


register_envs()

__all__ = ["ENTRY_POINT", "GYM_NAMESPACE", "BavoEnv", "gym_id", "register_envs"]

"""Privileged scripted experts, one module per task (`experts/<task>.py`), via `make_expert`.

Each expert module defines one `ScriptedExpert` subclass whose `task_name` equals the module
name; the registry imports the modules that exist (import errors propagate).
"""

from __future__ import annotations

from lerobot_bavo.envs.tasks import TASK_NAMES
from lerobot_bavo.experts.base import ScriptedExpert
from lerobot_bavo.registry import discover


EXPERTS: dict[str, type[ScriptedExpert]] = discover(
    __name__, TASK_NAMES, lambda cls, name: issubclass(cls, ScriptedExpert) and cls.task_name == name
)


def make_expert(env, seed: int | None = None, frozen_camera: bool = False) -> ScriptedExpert:
    """The scripted expert for `env`'s task. Call `reset()` on it after every `env.reset()`.

    `frozen_camera=True` gives the reference variant whose camera arm never moves.
    """
    name = env.unwrapped.task.name
    if name not in EXPERTS:
        raise NotImplementedError(f"no scripted expert for task {name!r}; available: {', '.join(EXPERTS)}")
    return EXPERTS[name](env, seed=seed, frozen_camera=frozen_camera)


__all__ = ["EXPERTS", "ScriptedExpert", "make_expert"]

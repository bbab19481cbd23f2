"""Privileged scripted experts, one module per task (`experts/<task>.py`), via `make_expert`.

Every `ScriptedExpert` subclass defined in a module of this package is registered under its
`task_name` (walking the package; import errors propagate); experts defined elsewhere join with
`@register_expert`.
"""

from __future__ import annotations

from lerobot_bavo.experts.base import ScriptedExpert
from lerobot_bavo.registry import Registry

EXPERTS = Registry("expert", key="task_name")
register_expert = EXPERTS.register
EXPERTS.discover(__name__, ScriptedExpert)


def make_expert(env, seed: int | None = None, frozen_camera: bool = False,
                square_grasps: bool = False) -> ScriptedExpert:
    """The scripted expert for `env`'s task. Call `reset()` on it after every `env.reset()`.

    `frozen_camera=True` gives the reference variant whose camera arm never moves; `square_grasps=True`
    the data variant whose top-down grasps keep the wrist at yaw 0 (ValueError where not implemented).
    """
    name = env.unwrapped.task.name
    if name not in EXPERTS:
        raise NotImplementedError(f"no scripted expert for task {name!r}; available: {', '.join(EXPERTS)}")
    return EXPERTS[name](env, seed=seed, frozen_camera=frozen_camera, square_grasps=square_grasps)


__all__ = ["EXPERTS", "ScriptedExpert", "make_expert", "register_expert"]

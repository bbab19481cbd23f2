"""Privileged scripted experts, one module per task (`experts/<task>.py`), via `make_expert`.

Each expert module defines one `ScriptedExpert` subclass whose `task_name` equals the module
name; the registry imports the modules that exist (import errors propagate).
"""

from __future__ import annotations

import importlib
import importlib.util
import inspect

from lerobot_bavo.envs.tasks import TASK_NAMES
from lerobot_bavo.experts.base import ScriptedExpert


def _discover() -> dict[str, type[ScriptedExpert]]:
    found = {}
    for name in TASK_NAMES:
        module_name = f"{__name__}.{name}"
        if importlib.util.find_spec(module_name) is None:
            continue
        module = importlib.import_module(module_name)
        classes = [c for _, c in inspect.getmembers(module, inspect.isclass)
                   if issubclass(c, ScriptedExpert) and getattr(c, "task_name", None) == name]
        if len(classes) != 1:
            raise ImportError(f"{module_name} must define exactly one ScriptedExpert with task_name {name!r}")
        found[name] = classes[0]
    return found


EXPERTS: dict[str, type[ScriptedExpert]] = _discover()


def make_expert(env, seed: int | None = None, frozen_camera: bool = False) -> ScriptedExpert:
    """The scripted expert for `env`'s task. Call `reset()` on it after every `env.reset()`.

    `frozen_camera=True` gives the reference variant whose camera arm never moves.
    """
    name = env.unwrapped.task.name
    if name not in EXPERTS:
        raise NotImplementedError(f"no scripted expert for task {name!r}; available: {', '.join(EXPERTS)}")
    return EXPERTS[name](env, seed=seed, frozen_camera=frozen_camera)


__all__ = ["EXPERTS", "ScriptedExpert", "make_expert"]

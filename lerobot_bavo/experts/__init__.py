"""Privileged scripted experts, one per task, built with `make_expert(env, seed=None)`."""

from __future__ import annotations

from lerobot_bavo.experts.base import ScriptedExpert
from lerobot_bavo.experts.cube_handoff import CubeHandoffExpert

EXPERTS: dict[str, type[ScriptedExpert]] = {
    "cube_handoff": CubeHandoffExpert,
}


def make_expert(env, seed: int | None = None) -> ScriptedExpert:
    """The scripted expert for `env`'s task. Call `reset()` on it after every `env.reset()`."""
    name = env.unwrapped.task.name
    if name not in EXPERTS:
        raise NotImplementedError(f"no scripted expert for task {name!r}; available: {', '.join(EXPERTS)}")
    return EXPERTS[name](env, seed=seed)


__all__ = ["EXPERTS", "ScriptedExpert", "make_expert"]

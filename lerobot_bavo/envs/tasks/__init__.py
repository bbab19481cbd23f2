"""Task registry: one module per task (`lerobot_bavo/envs/tasks/<name>.py`), found by name.

Each task module defines one `Task` subclass whose `name` equals the module name. The registry
imports the modules that exist, so adding a task is adding its file; import errors in a task
module propagate (they are bugs, not missing tasks).
"""

from __future__ import annotations

import functools

from lerobot_bavo.envs.tasks.base import Task
from lerobot_bavo.registry import discover

# The five BAVO-Bench tasks in the paper's order; gym ids are `lerobot_bavo/<GymName>-v0`.
TASK_NAMES = ("cube_handoff", "block_stacking", "drawer_stowing", "slide_retrieval", "dustpan_sweeping")
GYM_NAMES = {
    "cube_handoff": "CubeHandoff",
    "block_stacking": "BlockStacking",
    "drawer_stowing": "DrawerStowing",
    "slide_retrieval": "SlideRetrieval",
    "dustpan_sweeping": "DustpanSweeping",
}


# Tasks implemented in this version, in the paper's order.
TASKS: dict[str, type[Task]] = discover(
    __name__, TASK_NAMES, lambda cls, name: issubclass(cls, Task) and cls.name == name
)


def make_task(name: str) -> Task:
    """Instantiate a task by benchmark name, with a clear error for unknown or missing tasks."""
    if name not in TASK_NAMES:
        raise ValueError(f"unknown task {name!r}; BAVO-Bench tasks are {', '.join(TASK_NAMES)}")
    if name not in TASKS:
        raise NotImplementedError(
            f"task {name!r} is part of BAVO-Bench but not implemented in this version; "
            f"available: {', '.join(TASKS)}"
        )
    return TASKS[name]()


@functools.lru_cache(maxsize=None)
def environment_state_dim(name: str) -> int:
    """Size of a task's `environment_state` (7 per object pose), read from its compiled model once."""
    import mujoco

    from lerobot_bavo.sim.scene import build_base_spec

    task = make_task(name)
    spec = build_base_spec()
    task.build(spec)
    model = spec.compile()
    data = mujoco.MjData(model)
    task.bind(model)
    mujoco.mj_forward(model, data)
    return int(task.environment_state(model, data).shape[0])


__all__ = ["GYM_NAMES", "TASKS", "TASK_NAMES", "Task", "environment_state_dim", "make_task"]

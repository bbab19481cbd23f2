"""Task registry: every `Task` subclass defined in a module of this package, found by walking it.

Adding a benchmark task is adding its file (`lerobot_bavo/envs/tasks/<name>.py` with one `Task`
subclass); tasks defined elsewhere (plugins, tests) join with `@register_task`. Import errors in a
task module propagate (they are bugs, not missing tasks). `TASKS` lists them in the paper's order
(`Task.order`), then by registration.
"""

from __future__ import annotations

import functools

from lerobot_bavo.envs.tasks.base import Task
from lerobot_bavo.registry import Registry

TASKS = Registry("task")
register_task = TASKS.register
TASKS.discover(__name__, Task, order=lambda cls: cls.order)


def make_task(name: str) -> Task:
    """Instantiate a registered task by name; unknown names raise a ValueError listing the registered ones."""
    return TASKS.lookup(name)()


def gym_name(task: str) -> str:
    """The CamelCase name in a task's gym id: "cube_handoff" -> "CubeHandoff"."""
    return "".join(part.capitalize() for part in task.split("_"))


@functools.cache
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


__all__ = ["TASKS", "Task", "environment_state_dim", "gym_name", "make_task", "register_task"]

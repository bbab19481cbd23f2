"""Small helpers shared by the task tests (imported as `from _helpers import ...`)."""

from __future__ import annotations


def milestone_flags(**true: bool) -> dict[str, bool]:
    """The expected `evaluate()` dict: m1..m5 all False except those given as True."""
    return {f"m{i}": bool(true.get(f"m{i}", False)) for i in range(1, 6)}


class EditedScene:
    """An env reset with a seed whose MjData the test then edits by hand.

    Subclasses add task-specific setters; `evaluate` recomputes kinematics and contacts for the
    edited state, `settle` lets physics run first.
    """

    def __init__(self, env, seed: int = 0):
        self.env = env
        env.reset(seed=seed)
        self.m, self.d, self.task = env.model, env.data, env.task

    def qadr(self, joint: str) -> int:
        return int(self.m.jnt_qposadr[self.m.joint(joint).id])

    def evaluate(self) -> dict[str, bool]:
        import mujoco

        mujoco.mj_forward(self.m, self.d)
        return {k: bool(v) for k, v in self.task.evaluate(self.m, self.d).items()}

    def settle(self, n: int) -> dict[str, bool]:
        import mujoco

        for _ in range(n):
            mujoco.mj_step(self.m, self.d)
        return self.evaluate()

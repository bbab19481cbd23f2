"""Extending the benchmark through its public extension points only, with no edit to a package file.

A toy sixth task (`register_task`), its expert (`register_expert`) and a toy condition
(`register_condition`) are defined in this file and run through `BavoEnv`, the Stage and Random-time
schedules, `BavoEnvConfig` and `bavo-eval`'s rollout (`run_episode` and the worker's `run_job`).
A task whose Stage targets name a geom its build does not add fails when the env is built, with a
message that names the geom.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from lerobot_bavo.envs.bavo_env import BavoEnv
from lerobot_bavo.envs.conditions import CONDITIONS, Condition, register_condition
from lerobot_bavo.envs.configs import BavoEnvConfig
from lerobot_bavo.envs.tasks import TASKS, Task, register_task
from lerobot_bavo.eval.rollout import make_agent, run_episode
from lerobot_bavo.eval.run import run_job
from lerobot_bavo.experts import EXPERTS, ScriptedExpert, register_expert
from lerobot_bavo.sim import constants as C

SMALL = dict(image_height=48, image_width=64, n_points=16, render_mode=None)
SUCCESS_STEP = 25  # the toy task's milestones are timed: M_k at control step 5 k


class ToyPuck(Task):
    """Toy task: a puck and a pad on the table; milestone M_k holds from control step 5 k on, so an
    episode succeeds at step 25 whatever the arms do. Stage targets: puck, puck after M1, pad after M2."""

    name = "toy_puck"
    description = "Watch the puck."
    max_episode_steps = 40
    stage_targets = ("puck", "puck", "pad")
    stage_transitions = (1, 2)
    target_geom_names = {"puck": ("toy_puck_geom",), "pad": ("toy_pad_geom",)}
    pose_bodies = {"puck": "toy_puck"}

    def build(self, spec: mujoco.MjSpec) -> None:
        puck = spec.worldbody.add_body(name="toy_puck", pos=[0.1, 0.05, 0.02])
        puck.add_freejoint(name="toy_puck_joint")
        puck.add_geom(name="toy_puck_geom", type=mujoco.mjtGeom.mjGEOM_CYLINDER, size=[0.04, 0.02, 0],
                      mass=0.1, rgba=[0.9, 0.6, 0.1, 1], group=C.GROUP_OBJECT)
        spec.worldbody.add_geom(name="toy_pad_geom", type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.05, 0.05, 0.002],
                                pos=[-0.1, 0.05, 0.002], rgba=[0.2, 0.7, 0.3, 1], group=C.GROUP_OBJECT,
                                contype=0, conaffinity=0)

    def bind_objects(self, model: mujoco.MjModel) -> None:
        self.puck_joint = model.joint("toy_puck_joint").id
        self.puck_body = model.body("toy_puck").id

    def initialize_episode(self, model, data, rng: np.random.Generator) -> None:
        adr = model.jnt_qposadr[self.puck_joint]
        data.qpos[adr:adr + 2] = rng.uniform([0.05, 0.0], [0.15, 0.1])

    def evaluate(self, model, data) -> dict[str, bool]:
        step = int(round(data.time / C.CONTROL_DT))
        return {f"m{k}": step >= 5 * k for k in range(1, 6)}

    def view_points(self, model, data, depth: int) -> np.ndarray:
        return np.stack([data.xpos[self.puck_body], data.geom_xpos[self.target_geoms["pad"][0]]])


class ToyPuckExpert(ScriptedExpert):
    task_name = "toy_puck"

    def script(self):
        yield from self.wait(100, phase="watch")


class EveryTwelve(Condition):
    """Toy condition: an occlusion event every 12 control steps, CVG reported."""

    name = "toy_every12"
    description = "**Every 12**: an event every 12 steps."
    reports_cvg = True

    def due(self, schedule, step, depth):
        return step % 12 == 0


class MisnamedTarget(ToyPuck):
    name = "toy_misnamed"
    target_geom_names = {"puck": ("toy_puck_gem",), "pad": ("toy_pad_geom",)}


class MissingTarget(ToyPuck):
    name = "toy_missing"
    target_geom_names = {"puck": ("toy_puck_geom",)}


@pytest.fixture
def registered():
    """Register the toy task, expert and condition for one test, then remove them again."""
    register_task(ToyPuck)
    register_expert(ToyPuckExpert)
    register_condition(EveryTwelve)
    yield
    TASKS.pop(ToyPuck.name)
    EXPERTS.pop(ToyPuckExpert.task_name)
    CONDITIONS.pop(EveryTwelve.name)


def _events(env, seed=0):
    agent = make_agent("expert", env)
    record = run_episode(env, agent, seed)
    return record, [(p["step"], p["target"]) for p in record.get("placements", [])]


def test_toy_task_runs_under_every_condition(registered):
    for condition in CONDITIONS:
        BavoEnvConfig(task="toy_puck", condition=condition)
    env = BavoEnv(task="toy_puck", condition="clean", **SMALL)
    try:
        record, events = _events(env)
        assert record["success"] and record["steps"] == SUCCESS_STEP and events == []
        assert env._info()["object_poses"].keys() == {"puck"}
    finally:
        env.close()

    env = BavoEnv(task="toy_puck", condition="stage", **SMALL)
    try:
        record, events = _events(env)
        # Stage: at reset, then at the first step of depth 1 (target still the puck) and depth 2 (the pad)
        assert events == [(0, "puck"), (5, "puck"), (10, "pad")]
        assert record["success"]
    finally:
        env.close()

    env = BavoEnv(task="toy_puck", condition="random", episode_length=SUCCESS_STEP - 1, **SMALL)
    try:
        record, events = _events(env)
        assert events == [(0, "puck")] and not record["success"]  # the first trigger is at step >= 60
        assert record["num_events"] == 1 and len(record["triggers"]) == 6 and record["episode_cvg"] is None
    finally:
        env.close()


def test_toy_condition_runs_through_env_and_bavo_eval(registered):
    env = BavoEnv(task="cube_handoff", condition="toy_every12", episode_length=30, **SMALL)
    try:
        assert env.occluded and env.compute_cvg and env.condition == "toy_every12"
        _, events = _events(env)
        assert [s for s, _ in events] == [0, 12, 24]
    finally:
        env.close()

    record = run_job({"policy": "expert", "task": "toy_puck", "condition": "toy_every12", "seed": 1,
                       "env_kwargs": dict(SMALL)})
    assert record["task"] == "toy_puck" and record["condition"] == "toy_every12"
    assert record["success"] and [p["step"] for p in record["placements"]] == [0, 12, 24]
    assert [e["num_samples"] for e in record["events"]] == [12, 12, 2]  # each event ends at the next
    assert record["episode_cvg"] is None  # every window truncated by the next event


def test_unknown_condition_lists_the_registered_ones(registered):
    with pytest.raises(
        ValueError, match="unknown condition 'foggy'; registered: clean, stage, random, toy_every12"
    ):
        BavoEnv(task="toy_puck", condition="foggy", **SMALL)


def test_stage_target_with_a_missing_geom_fails_at_construction():
    with pytest.raises(ValueError, match=r"toy_misnamed.*'puck'.*toy_puck_gem"):
        BavoEnv(task=MisnamedTarget(), condition="clean", **SMALL)
    with pytest.raises(ValueError, match=r"toy_missing.*\['pad'\].*target_geom_names"):
        BavoEnv(task=MissingTarget(), condition="stage", **SMALL)

"""scripts/grasp_trace.py names, for each task, its first grasp (fingers closing on an object): the scripted
expert, which succeeds on every seed, must close that gripper on (within a finger's reach of) that object."""

from __future__ import annotations

import numpy as np
import pytest
from _helpers import load_script

from lerobot_bavo.envs.bavo_env import BavoEnv
from lerobot_bavo.eval.rollout import make_agent

grasp_trace = load_script("scripts/grasp_trace.py")


@pytest.mark.parametrize("task", sorted(grasp_trace.FIRST_GRASP))
def test_the_expert_closes_the_traced_gripper_on_the_traced_object(task):
    side, name = grasp_trace.FIRST_GRASP[task]
    env = BavoEnv(task=task, condition="clean")
    try:
        row = grasp_trace.trace_episode(env, make_agent("expert", env), 1000, side, name, closed=0.5)
    finally:
        env.close()
    assert row["success"]
    assert row["close_step"] is not None
    # The expert's grasp centres sit 10-11 mm above a block's centre; a handle or blade is thinner. 30 mm
    # is well inside a 4 cm object's reach and well outside a grasp on another object.
    assert np.linalg.norm(row["offset_mm"]) < 30.0, row
    # and its joint targets of that step put the gripper there too (where the policies' failed grasps differ)
    assert np.linalg.norm(row["commanded_offset_mm"]) < 30.0, row


def test_the_commanded_site_is_the_measured_one_when_the_targets_are_the_measured_joints():
    """Forward kinematics of the commanded arm joints: commanding where the arms are gives where the gripper
    is; moving one arm's shoulder target moves that gripper and not the other."""
    import mujoco

    env = BavoEnv(task="cube_handoff", condition="clean")
    try:
        env.reset(seed=0)
        scratch = mujoco.MjData(env.model)
        here = env.joint_state()
        site = "right_gripper_center"
        np.testing.assert_allclose(grasp_trace.commanded_site(env, scratch, here, site),
                                   env.data.site(site).xpos, atol=1e-9)
        moved = here.copy()
        moved[grasp_trace.C.ACTION_NAMES.index("right_shoulder")] += 0.1
        assert np.linalg.norm(grasp_trace.commanded_site(env, scratch, moved, site)
                              - env.data.site(site).xpos) > 0.01
        np.testing.assert_allclose(grasp_trace.commanded_site(env, scratch, moved, "left_gripper_center"),
                                   env.data.site("left_gripper_center").xpos, atol=1e-9)
    finally:
        env.close()


def test_an_unknown_object_name_is_refused():
    env = BavoEnv(task="cube_handoff", condition="clean")
    try:
        env.reset(seed=0)
        with pytest.raises(SystemExit, match="no body or geom named 'no_such_object'"):
            grasp_trace.object_position(env, "no_such_object")
        assert grasp_trace.object_position(env, "cube").shape == (3,)
    finally:
        env.close()

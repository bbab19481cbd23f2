"""scripts/stall_trace.py: its pure helpers by hand, and the scripted expert's Drawer Stowing episode as the
reference trace of a block that is lifted and placed (the policies' stalls are measured against it)."""

from __future__ import annotations

import numpy as np
import pytest
from _helpers import load_script

from lerobot_bavo.envs.bavo_env import BavoEnv
from lerobot_bavo.eval.rollout import make_agent, run_episode
from lerobot_bavo.sim import constants as C

stall_trace = load_script("scripts/stall_trace.py")


def test_longest_run_and_outside_distance_by_hand():
    assert stall_trace.longest_run([]) == 0
    assert stall_trace.longest_run([True, False, True, True, True, False, True]) == 3
    lo, hi = np.array([0.0, 0.0]), np.array([1.0, 2.0])
    assert stall_trace.outside_distance(np.array([0.5, 1.0]), lo, hi) == 0.0  # inside
    assert stall_trace.outside_distance(np.array([1.3, 1.0]), lo, hi) == pytest.approx(0.3)  # beside an edge
    assert stall_trace.outside_distance(np.array([-0.3, 2.4]), lo, hi) == pytest.approx(0.5)  # off a corner


def test_summarise_by_hand():
    """Three steps before M3, then four: touched twice, lifted 5 cm at most, the arm still for two steps."""
    steps = [{"progress": p, "left_touch": t, "block_z": z, "outside": 0.1, "slide": 0.12, "occluded": o}
             for p, t, z, o in [(2, False, 0.02, False), (2, False, 0.02, False), (2, False, 0.02, True),
                                (3, True, 0.02, True), (3, True, 0.07, False), (3, False, 0.04, False),
                                (3, False, 0.02, False)]]
    commands = [np.zeros(len(C.ACTION_NAMES)) for _ in steps]
    commands[5] = commands[5].copy()
    commands[5][C.LEFT_ARM] = 0.01  # one 10 mrad move into step 5, one back out of it
    row = stall_trace.summarise(steps, commands, rest_z=0.02)
    assert row["m3_step"] == 3 and row["steps_after_m3"] == 4
    assert row["touch_frac"] == 0.5
    assert row["max_lift_cm"] == pytest.approx(5.0) and row["lifted"]
    assert row["still_frac"] == pytest.approx(1 / 3, abs=1e-3) and row["longest_still"] == 1
    assert row["mean_move_mrad"] == pytest.approx(20 / 3, abs=0.01)
    assert row["event_steps_after_m3"] == 1
    assert row["end_lift_cm"] == 0.0 and row["end_outside_cm"] == 10.0
    assert stall_trace.summarise(steps[:3], commands[:3], rest_z=0.02) == {"m3_step": None}


def test_the_expert_lifts_the_block_after_m3():
    env = BavoEnv(task="drawer_stowing", condition="stage")
    agent = stall_trace.CommandLog(make_agent("expert", env))
    task, steps = env.unwrapped.task, []

    def on_step(info):
        steps.append(stall_trace.step_record(env, info))

    try:
        env.reset(seed=1000)
        rest_z = float(env.unwrapped.data.xpos[task.block_body][2])
        record = run_episode(env, agent, 1000, on_step=on_step)
    finally:
        env.close()
    row = stall_trace.summarise(steps, agent.commands, rest_z)
    assert record["success"]
    assert row["lifted"] and row["touch_frac"] > 0.2
    # the expert holds its left arm still for long stretches (while the right arm works, or the camera
    # recovers): the learned policies' commands never are (docs/results/first_grasp.md)
    assert row["longest_still"] > 20
    assert row["end_slide_cm"] <= 1.0  # the drawer closed with the block placed: M5

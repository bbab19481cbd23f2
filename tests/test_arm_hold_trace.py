"""scripts/arm_hold_trace.py: its pure helpers by hand, and its refusal of unknown hold tests."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from _helpers import load_script

from lerobot_bavo.sim import constants as C

arm_hold_trace = load_script("scripts/arm_hold_trace.py")


def test_milestone_steps_by_hand():
    assert arm_hold_trace.milestone_steps([0, 1, 1, 3, 3]) == [1, 3, 3, None, None]  # M2 comes with M3
    assert arm_hold_trace.milestone_steps([]) == [None] * 5


def test_window_travel_by_hand():
    commands = np.array([[0.0, 0.0], [0.1, 0.0], [0.1, -0.3], [0.1, -0.3]])
    assert arm_hold_trace.window_travel(commands, 2) == pytest.approx([0.3, 0.3])
    assert arm_hold_trace.window_travel(commands, 1) == pytest.approx([0.1, 0.3, 0.0])
    assert len(arm_hold_trace.window_travel(commands, 4)) == 0


def test_travel_around_stop_by_hand():
    """M1 at step 2, never more; the right shoulder moves 10 mrad per step before it and is held after it,
    with the target hidden for 3 of the 4 steps from the stop on."""
    progress = [0, 0, 1, 1, 1, 1]
    commands = np.zeros((6, len(C.ACTION_NAMES)))
    commands[:3, C.RIGHT_ARM.start + 1] = [0.0, 0.01, 0.02]
    commands[3:, C.RIGHT_ARM.start + 1] = 0.02
    hidden = [False, False, True, True, False, True]
    row = arm_hold_trace.travel_around_stop(progress, commands, hidden, window=1, held=0.005)
    assert row["stop_step"] == 2 and row["after_steps"] == 4
    assert row["travel_before_mrad"] == pytest.approx(10.0) and row["travel_after_mrad"] == 0.0
    assert row["held_share"] == 1.0 and row["hidden_share"] == 0.75
    # the camera arm's joints do not count as arm travel
    commands[:, C.CAMERA_ARM] = np.arange(6)[:, None]
    assert arm_hold_trace.travel_around_stop(progress, commands, hidden, 1, 0.005)["travel_after_mrad"] == 0.0


def test_release_or_slip_by_hand():
    commands = np.ones((6, len(C.ACTION_NAMES)))  # grippers open (1)
    commands[1:4, C.RIGHT_GRIPPER] = 0.0  # the right hand closed for steps 1-3, open again from step 4
    held = [False, True, True, True, False, False]
    row = arm_hold_trace.release_or_slip(held, commands, after=2)
    assert row == {"last_held_step": 3, "grippers_at_last_held": [1.0, 0.0], "grippers_after": [1.0, 1.0]}
    assert arm_hold_trace.release_or_slip(held, commands, after=10)["grippers_after"] == [1.0, 1.0]  # clipped
    assert arm_hold_trace.release_or_slip([False] * 6, commands, after=2) == {}


def test_unknown_hold_test_is_refused_before_any_episode():
    root = Path(__file__).resolve().parents[1]
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl"), "OMP_NUM_THREADS": "1"}
    command = [sys.executable, str(root / "scripts/arm_hold_trace.py"), "--policy", "expert",
               "--hold-tests", "m2,m9", "--seeds", "1000-1000"]
    out = subprocess.run(command, capture_output=True, text=True, env=env, timeout=300, cwd=root)
    assert out.returncode == 2
    assert "--hold-tests m9: not tests of cube_handoff; its tests: m1, m2, m3, m4, m5" in out.stderr
    assert '"seed"' not in out.stdout  # no episode was run

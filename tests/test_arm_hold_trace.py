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


def test_phase_bounds_by_hand():
    # M1 at step 2, M2 and M3 together at step 4, then no M4: phase 2 is empty, phase 3 runs to the end
    assert arm_hold_trace.phase_bounds([0, 0, 1, 1, 3, 3]) == [
        (0, 2, True), (2, 4, True), (4, 4, True), (4, 6, False)]
    assert arm_hold_trace.phase_bounds([0, 0]) == [(0, 2, False)]
    assert arm_hold_trace.phase_bounds([1, 2, 3, 4, 5]) == [
        (0, 0, True), (0, 1, True), (1, 2, True), (2, 3, True), (3, 4, True)]


def test_phase_camera_by_hand():
    commands = np.zeros((5, 21))
    commands[:, C.LEFT_ARM] = np.arange(5)[:, None]  # the arms' motion is not the camera's
    commands[2, 14] = 0.004  # one camera joint steps up at 2 and back at 3
    commands[4, 20] = -0.010
    hidden = [False, True, True, False, False]
    got = arm_hold_trace.phase_camera(commands, hidden, 2, 5)
    # changes into steps 2, 3, 4: 4, 4 and 10 mrad
    # (hidden_share is rounded to 3 places)
    assert got == {"steps": 3, "cam_mrad_per_step": pytest.approx(6.0),
                   "hidden_share": pytest.approx(1 / 3, abs=1e-3)}
    assert arm_hold_trace.phase_camera(commands, hidden, 0, 2) == {
        "steps": 2, "cam_mrad_per_step": 0.0, "hidden_share": 0.5}
    assert arm_hold_trace.phase_camera(commands, hidden, 3, 3) == {
        "steps": 0, "cam_mrad_per_step": None, "hidden_share": None}


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


def test_pool_prints_the_phase_table_of_saved_logs_and_refuses_logs_without_phases(tmp_path):
    import gzip
    import json

    def phase(k, done, steps, cam, hidden):
        return {"phase": k, "completed": done, "steps": steps, "cam_mrad_per_step": cam,
                "hidden_share": hidden}

    rows = [{"seed": 1, "success": False, "progress": 1,
             "phases": [phase(0, True, 90, 10.0, 0.1), phase(1, False, 600, 80.0, 0.75)]},
            {"seed": 2, "success": False, "progress": 1,
             "phases": [phase(0, True, 110, 20.0, 0.0), phase(1, False, 500, 40.0, 0.25)]}]
    with gzip.open(tmp_path / "a.jsonl.gz", "wt") as f:
        f.write("".join(json.dumps(r) + "\n" for r in rows))
    (tmp_path / "b.jsonl").write_text(json.dumps({"seed": 3, "success": True, "progress": 5}) + "\n")
    root = Path(__file__).resolve().parents[1]
    script = str(root / "scripts/arm_hold_trace.py")
    out = subprocess.run([sys.executable, script, "--pool", str(tmp_path / "a.jsonl.gz")],
                         capture_output=True, text=True, timeout=300, cwd=root)
    assert out.returncode == 0, out.stderr
    assert "2 episodes, 0 successes" in out.stdout
    # medians by hand: steps (90, 110) -> 100, camera (10, 20) -> 15, hidden (0.1, 0) -> 0.05; no view lost
    assert "| M0 -> M1 | yes | 2 | 100.00 | 15.00 | 0.05 | 0 |" in out.stdout
    assert "| M1 -> M2 | no | 2 | 550.00 | 60.00 | 0.50 | 1 |" in out.stdout  # one phase hidden >= half
    out = subprocess.run([sys.executable, script, "--pool", str(tmp_path / "b.jsonl")],
                         capture_output=True, text=True, timeout=300, cwd=root)
    assert out.returncode == 2 and "hold no camera phases" in out.stderr
    out = subprocess.run([sys.executable, script, "--pool", str(tmp_path / "c.jsonl")],
                         capture_output=True, text=True, timeout=300, cwd=root)
    assert out.returncode == 2 and f"no episode log at {tmp_path / 'c.jsonl'}" in out.stderr

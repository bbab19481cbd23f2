"""`scripts/gripper_switches.py`: runs of a snapped gripper command and its short interior runs on
hand-made sequences, and the pooled summary of hand-made logs."""

import gzip
import json

import pytest
from _helpers import load_script


def test_runs_and_short_runs_by_hand():
    gs = load_script("scripts/gripper_switches.py")
    levels = [1, 1, 1, 0, 0, 1, 0, 0, 0, 0, 1, 1]
    assert gs.level_runs(levels) == [(1, 0, 3), (0, 3, 2), (1, 5, 1), (0, 6, 4), (1, 10, 2)]
    # interior runs only (the first and last are cut by the episode's ends), at most 2 steps
    assert gs.short_runs(levels, 2) == [(0, 3, 2), (1, 5, 1)]
    assert gs.short_runs(levels, 4) == [(0, 3, 2), (1, 5, 1), (0, 6, 4)]
    assert gs.short_runs([1] * 5, 3) == []
    assert gs.level_runs([]) == []


def test_pool_summarises_gzipped_and_plain_logs(tmp_path, capsys):
    gs = load_script("scripts/gripper_switches.py")
    rows = [
        {"task": "cube_handoff", "condition": "stage", "seed": 1, "success": True, "progress": 5,
         "steps": 400,
         "short_runs": {"left_gripper": [], "right_gripper": [[1, 24, 3]]}},
        {"task": "cube_handoff", "condition": "stage", "seed": 2, "success": False, "progress": 2,
         "steps": 800,
         "short_runs": {"left_gripper": [[1, 36, 2]], "right_gripper": [[1, 12, 2], [1, 30, 4], [1, 48, 1]]}},
    ]
    (tmp_path / "a.jsonl.gz").write_bytes(gzip.compress((json.dumps(rows[0]) + "\n").encode()))
    (tmp_path / "b.jsonl").write_text(json.dumps(rows[1]) + "\n")
    import sys

    argv = sys.argv
    sys.argv = ["gripper_switches.py", "--pool", str(tmp_path / "a.jsonl.gz"), str(tmp_path / "b.jsonl"),
                "--chunk", "12"]
    try:
        gs.main()
    finally:
        sys.argv = argv
    out = capsys.readouterr().out
    assert "successes (1), right_gripper: short runs (<= 6 steps) per episode mean 1.0" in out
    assert "1 of 1 start a chunk" in out
    # the failure's right-gripper runs start at 12, 30 and 48: two of three at a chunk's first step
    assert "failures (1), right_gripper: short runs (<= 6 steps) per episode mean 3.0, median 3, episodes " \
        "with any 1, 2 of 3 start a chunk" in out


def test_grasp_yaw_geometry_and_summary_by_hand():
    gy = load_script("scripts/grasp_yaw.py")
    assert gy.wrap90(50.0) == -40.0 and gy.wrap90(-50.0) == 40.0 and gy.wrap90(10.0) == 10.0
    import numpy as np

    from lerobot_bavo.sim.transforms import closing_yaw, topdown_rot

    # a top-down gripper turned by +30 degrees about z: its closing axis is rot_z(30) @ (0, -1, 0)
    a = np.radians(30)
    rot = np.array([[np.cos(a), np.sin(a), 0.0], [np.sin(a), -np.cos(a), 0.0], [0.0, 0.0, -1.0]])
    assert np.degrees(closing_yaw(rot)) == pytest.approx(30.0)
    assert closing_yaw(topdown_rot([0, -1, 0], a)) == pytest.approx(a)
    rows = [{"seed": 1, "success": True, "cube_yaw": 20.0, "grip_yaw": 18.0},    # misaligned 2
            {"seed": 2, "success": False, "cube_yaw": -25.0, "grip_yaw": 10.0},  # 35
            {"seed": 3, "success": True, "cube_yaw": 5.0, "grip_yaw": -10.0},    # 15
            {"seed": 4, "success": False, "cube_yaw": 28.0, "grip_yaw": None}]   # never closed
    text = gy.summarise(rows)
    assert "4 episodes, 2 successes; 1 never closed the right gripper" in text
    assert "|misalignment| 0-10 deg: 1 of 1 succeed" in text
    assert "|misalignment| 10-20 deg: 1 of 1 succeed" in text
    assert "|misalignment| 30-46 deg: 0 of 1 succeed" in text
    assert "|cube yaw| 0-15 deg: 1 of 1 succeed" in text and "|cube yaw| 15-46 deg: 1 of 3 succeed" in text

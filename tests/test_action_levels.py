"""lerobot_bavo.datasets.action_levels: the command levels a dataset's gripper commands hold, by hand."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lerobot_bavo.datasets.action_levels import held_levels, normalised_levels


def test_held_levels_keep_values_held_long_enough_and_often_enough():
    # episode 0: open 10 frames, a 3-frame ramp, closed 6, part-open 0.45 for 5; episode 1: 0.45 for 3 then
    # 0.45 again after the boundary would make a run of 5 if runs crossed episodes (they do not)
    ramp = [0.75, 0.5, 0.25]
    ep0 = [1.0] * 10 + ramp + [0.0] * 6 + [0.45] * 5
    ep1 = [0.7] * 4 + [1.0] * 6
    values = np.array(ep0 + ep1)
    episodes = np.array([0] * len(ep0) + [1] * len(ep1))
    assert held_levels(values, episodes, min_run=5, min_share=0.0) == [0.0, 0.45, 1.0]  # 0.7 held 4 < 5
    assert held_levels(values, episodes, min_run=4, min_share=0.0) == [0.0, 0.45, 0.7, 1.0]
    # 34 frames: 0.45's 5 frames are 14.7 %, 0.0's 6 are 17.6 %
    assert held_levels(values, episodes, min_run=5, min_share=0.15) == [0.0, 1.0]
    # a run cut by an episode boundary is two runs
    assert held_levels(np.array([0.3] * 6), np.array([0, 0, 0, 1, 1, 1]), min_run=4, min_share=0.0) == []
    with pytest.raises(ValueError, match="equal-length"):
        held_levels(np.zeros(3), np.zeros(4))


def test_levels_are_normalised_as_the_min_max_normaliser_does_with_the_ends_always_in():
    low, high = np.array([0.0, 0.0, -2.0]), np.array([1.0, 1.0, 2.0])
    # dimension 0: 0.45 -> -0.1; dimension 1: 0.7 -> 0.4; dimension 2 in [-2, 2]: 1.0 -> 0.5
    assert normalised_levels({0: [0.0, 0.45, 1.0], 1: [0.7]}, low, high) == [-1.0, -0.1, 0.4, 1.0]
    assert normalised_levels({2: [1.0]}, low, high) == [-1.0, 0.5, 1.0]
    assert normalised_levels({}, low, high) == [-1.0, 1.0]
    # a constant dimension has no range to place a level in
    assert normalised_levels({0: [1.0]}, np.array([1.0]), np.array([1.0])) == [-1.0, 1.0]


def test_a_training_view_gives_the_levels_its_expert_holds(tmp_path, capsys):
    """On a written LeRobot dataset: the gripper commands' held levels, read back through the CLI."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from lerobot_bavo.datasets.action_levels import main

    rng = np.random.default_rng(0)
    rows = []
    for episode in range(2):  # a right gripper holding 1, then 0.45, then 0; a left one 1 then 0; arms random
        right = [1.0] * 20 + [0.45] * 20 + [0.0] * 20
        left = [1.0] * 30 + [0.0] * 30
        for t in range(60):
            action = rng.uniform(-1, 1, 21).astype(np.float32)
            action[6], action[13] = left[t], right[t]
            rows.append({"action": action, "episode_index": episode})
    (tmp_path / "data" / "chunk-000").mkdir(parents=True)
    actions = np.stack([r["action"] for r in rows])
    # LeRobot's layout: the action a fixed-size list column of float32, the episode index int64
    table = pa.table({"action": pa.FixedSizeListArray.from_arrays(pa.array(actions.reshape(-1)), 21),
                      "episode_index": pa.array([r["episode_index"] for r in rows], pa.int64())})
    pq.write_table(table, tmp_path / "data" / "chunk-000" / "file-000.parquet")
    (tmp_path / "meta").mkdir()
    stats = {"action": {"min": actions.min(0).tolist(), "max": actions.max(0).tolist()}}
    (tmp_path / "meta" / "stats.json").write_text(json.dumps(stats))
    main(["--root", str(tmp_path)])
    assert capsys.readouterr().out.strip() == "[-1.0,-0.1,1.0]"  # 0.45 -> -0.1; the ramps-free ends
    with pytest.raises(SystemExit, match="stats.json"):  # not a dataset: the missing file named
        main(["--root", str(tmp_path / "meta")])

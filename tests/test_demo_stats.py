"""scripts/demo_stats.py: its pure counts by hand, and one episode written to parquet and read back."""

from __future__ import annotations

import numpy as np
import pytest
from _helpers import load_script

from lerobot_bavo.sim import constants as C

demo_stats = load_script("scripts/demo_stats.py")


def test_gripper_switches_by_hand():
    assert demo_stats.gripper_switches(np.zeros(5)) == 0  # never moves
    assert demo_stats.gripper_switches(np.array([-1.0, -1.0, 1.0, 1.0, -1.0])) == 2  # one grasp, one release
    # a re-grasp: closes, opens, closes again, opens (part-open levels below the midpoint count as open)
    assert demo_stats.gripper_switches(np.array([0.0, 0.9, 0.2, 1.0, 0.1])) == 4


def test_still_share_by_hand():
    commands = np.zeros((5, 2))
    commands[2, 1] = 0.01  # a 10 mrad move into step 2 and one back out of it: 2 of 4 steps move
    assert demo_stats.still_share(commands, 1e-3) == pytest.approx(0.5)
    assert demo_stats.still_share(commands, 0.02) == pytest.approx(1.0)
    assert demo_stats.still_share(commands[:1], 1e-3) == 0.0


def test_episode_stats_read_from_a_written_view(tmp_path):
    import pyarrow as pa
    import pyarrow.parquet as pq

    n = 6
    actions = np.zeros((2 * n, len(C.ACTION_NAMES)), dtype=np.float32)
    actions[2:4, C.RIGHT_GRIPPER] = 1.0  # episode 0: one right grasp and release; the left never closes
    actions[n:, C.LEFT_ARM] = np.arange(n)[:, None] * 0.01  # episode 1: the left arm moves every step
    recovering = np.zeros((2 * n, 1), dtype=np.float32)
    recovering[n + 1:n + 4] = 1.0
    (tmp_path / "data" / "chunk-000").mkdir(parents=True)
    table = pa.table({"action": list(actions), "episode_index": np.repeat([0, 1], n),
                      "observation.teacher.recovering": list(recovering)})
    pq.write_table(table, tmp_path / "data" / "chunk-000" / "file-000.parquet")
    read_actions, episodes, read_recovering = demo_stats.read_view(tmp_path)
    first = demo_stats.episode_stats(read_actions[episodes == 0], read_recovering[episodes == 0], 1e-3)
    second = demo_stats.episode_stats(read_actions[episodes == 1], read_recovering[episodes == 1], 1e-3)
    assert first == {"frames": n, "left_switches": 0, "right_switches": 2, "arms_still": 1.0, "recovering": 0}
    assert second["arms_still"] == 0.0 and second["recovering"] == 3 and second["right_switches"] == 0

"""lerobot_bavo.datasets.action_levels: the command levels a dataset's gripper commands hold, by hand."""

from __future__ import annotations

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
    with pytest.raises(ValueError, match="constant"):
        normalised_levels({0: [0.0]}, np.array([1.0]), np.array([1.0]))

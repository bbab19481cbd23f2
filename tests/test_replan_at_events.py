"""scripts/replan_at_events.py: the non-privileged view-change trigger and the trigger/event bookkeeping, on
hand-computed cases."""

from __future__ import annotations

import numpy as np
import pytest
from _helpers import load_script

replan = load_script("scripts/replan_at_events.py")


def test_new_point_fraction_counts_points_far_from_the_previous_cloud():
    previous = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    assert replan.new_point_fraction(previous, previous, 0.02) == 0.0
    current = previous.copy()
    current[0] = [0.5, 0.5, 0.5]  # 0.87 m from every previous point
    current[1] = [1.0, 0.01, 0.0]  # 1 cm from its old place: within the radius
    assert replan.new_point_fraction(current, previous, 0.02) == 0.25
    # colour columns after xyz do not count
    with_rgb = np.concatenate([current, np.full((4, 3), 0.9)], axis=1)
    prev_rgb = np.concatenate([previous, np.zeros((4, 3))], axis=1)
    assert replan.new_point_fraction(with_rgb, prev_rgb, 0.02) == 0.25
    assert replan.new_point_fraction(current, previous[:0], 0.02) == 1.0
    assert replan.new_point_fraction(current[:0], previous, 0.02) == 0.0


def test_modes_parse_and_a_wrong_one_is_refused():
    assert replan.parse_mode("none") == ("none", None)
    assert replan.parse_mode("event") == ("event", None)
    assert replan.parse_mode("cloud:0.25") == ("cloud", 0.25)
    for bad in ("cloud", "cloud:1.5", "always"):
        with pytest.raises(ValueError):
            replan.parse_mode(bad)


def test_trigger_agreement_matches_triggers_and_events_within_the_slack():
    records = [
        {"placements": [{"step": 0}, {"step": 80}, {"step": 160}], "replan_steps": [81, 120]},
        {"placements": [{"step": 0}, {"step": 50}], "replan_steps": []},
    ]
    # triggers: 81 is within 2 of 80, 120 of none; events after step 0: 80 caught, 160 and 50 not
    assert replan.trigger_agreement(records) == (1, 2, 1, 3)

"""scripts/event_shift.py: comparing two collections' event starts, by hand."""

from __future__ import annotations

from _helpers import load_script

event_shift = load_script("scripts/event_shift.py")


def test_unchanged_schedule_holds_nothing():
    assert event_shift.compare([0, 70, 150], [0, 70, 150]) == {"events": 2, "held": 0, "delays": [],
                                                               "merged": 0}


def test_a_held_event_and_its_delay():
    # the event due at 150 waited until 162; the one at 230 is untouched
    assert event_shift.compare([0, 70, 150, 230], [0, 70, 162, 230]) == {
        "events": 3, "held": 1, "delays": [12], "merged": 0}


def test_two_events_held_into_one():
    # 150 and 215 both fell in one long hold ending at 220: one event there, one fewer in all
    row = event_shift.compare([0, 150, 215, 300], [0, 220, 300])
    assert row == {"events": 3, "held": 2, "delays": [70, 5], "merged": 1}


def test_a_held_event_after_which_none_starts():
    assert event_shift.compare([0, 470], [0])["delays"] == [None]

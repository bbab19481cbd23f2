"""scripts/event_recovery.py: the per-event-index CVG summary of bavo-eval episode logs, on hand-made logs."""

from __future__ import annotations

import json

import pytest
from _helpers import load_script


def test_per_event_index_by_hand(tmp_path, capsys):
    tool = load_script("scripts/event_recovery.py")
    episodes = [
        {"condition": "random", "task": "cube_handoff", "seed": 1, "success": True,
         "events": [{"index": 0, "start_step": 0, "cvg": 0.8}, {"index": 1, "start_step": 90, "cvg": 0.2}]},
        {"condition": "random", "task": "cube_handoff", "seed": 2, "success": False,
         "events": [{"index": 0, "start_step": 0, "cvg": 0.6}, {"index": 1, "start_step": 70, "cvg": None}]},
        {"condition": "stage", "task": "cube_handoff", "seed": 1, "success": True,
         "events": [{"index": 0, "start_step": 0, "cvg": 0.0}]},  # not Random-time: left out
    ]
    stats = tool.per_event_index([e for e in episodes if e["condition"] == "random"])
    assert stats[0] == {"n": 2, "retained": 2, "cvg_pp": pytest.approx(70.0), "start_step": 0.0}
    # a truncated event (None) counts as reached, not as retained, and not in the mean
    assert stats[1] == {"n": 2, "retained": 1, "cvg_pp": pytest.approx(20.0), "start_step": 80.0}
    log = tmp_path / "episodes.jsonl"
    log.write_text("".join(json.dumps(e) + "\n" for e in episodes))
    tool.main(["--label", f"p={log}", "--events", "3"])
    row = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| p |")][0]
    assert [c.strip() for c in row.strip("|").split("|")] == ["p", "2", "1", "2 / 2 / 70.0 / 0",
                                                              "2 / 1 / 20.0 / 80", "-"]


def test_view_regained_by_hand(tmp_path, capsys):
    """An event is regained at the first step after its start, before the next event, with V >= 0.5."""
    tool = load_script("scripts/event_recovery.py")
    events = [{"index": 0, "start_step": 0, "target": "a"}, {"index": 1, "start_step": 4, "target": "b"}]
    episodes = [
        # event 0: V 0.0, 0.2, 0.6 at steps 1-2 -> regained 2 steps after its start; event 1 (from step 4):
        # V reaches 0.5 at step 6 -> 2 steps
        {"condition": "stage", "task": "t", "seed": 1, "success": True, "events": events,
         "visibility": [0.0, 0.2, 0.6, 0.9, 0.0, None, 0.5]},
        # event 0 never regained before event 1 starts (V 0.7 at step 4 belongs to event 1, regained at once);
        {"condition": "stage", "task": "t", "seed": 2, "success": False, "events": events,
         "visibility": [0.0, 0.1, 0.3, 0.4, 0.7, 0.8]},
        {"condition": "random", "task": "t", "seed": 1, "success": True, "events": events[:1],
         "visibility": [0.0, 1.0]},
    ]
    stats = tool.view_regained([e for e in episodes if e["condition"] == "stage"])
    assert stats[(0, "a")] == {"n": 2, "regained": 1, "median_steps": 2.0}
    # episode 2's event 1 starts at step 4 with V 0.7 already; the first step after the start is 5 (V 0.8)
    assert stats[(1, "b")] == {"n": 2, "regained": 2, "median_steps": 1.5}
    log = tmp_path / "episodes.jsonl"
    log.write_text("".join(json.dumps(e) + "\n" for e in episodes))
    tool.main(["--regained", "stage", "--label", f"p={log}"])
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| p |")]
    cells = [c.strip() for c in rows[0].strip("|").split("|")]
    assert cells == ["p", "2", "1", "0 (a)", "2", "1 (50 %)", "2"]


def test_missing_log_is_a_usage_error(tmp_path, capsys):
    """A log path that does not exist is named in a usage error, not a traceback from deep in the reader."""
    tool = load_script("scripts/event_recovery.py")
    for argv in (["--label", f"p={tmp_path / 'nope.jsonl'}"], [str(tmp_path / "gone.jsonl")]):
        with pytest.raises(SystemExit) as exit_info:
            tool.main(argv)
        assert exit_info.value.code == 2
        assert "no episode log at" in capsys.readouterr().err

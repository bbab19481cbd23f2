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

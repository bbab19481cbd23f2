"""scripts/milestone_stops.py: where episodes stop and the milestone-to-milestone shares, by hand."""

from __future__ import annotations

import json

import pytest
from _helpers import load_script


def test_stops_and_rates_by_hand():
    tool = load_script("scripts/milestone_stops.py")
    records = [{"seed": s, "progress": p} for s, p in enumerate([5, 5, 2, 2, 1, 0])]
    stops = tool.stops_by_depth(records)
    assert stops == [1, 1, 2, 0, 0, 2]
    # reached M0..M5: 6, 5, 4, 2, 2, 2 -> 5/6, 4/5, 2/4, 2/2, 2/2
    assert tool.transition_rates(stops) == pytest.approx([5 / 6, 4 / 5, 0.5, 1.0, 1.0])
    # nobody past M1: the later steps have no episodes to go on from
    assert tool.transition_rates([3, 1, 0, 0, 0, 0]) == [pytest.approx(0.25), 0.0, None, None, None]


def test_out_of_range_depth_is_an_error():
    tool = load_script("scripts/milestone_stops.py")
    with pytest.raises(ValueError, match="milestone depth"):
        tool.stops_by_depth([{"seed": 7, "progress": 6}])


def test_labels_pool_their_logs(tmp_path, capsys):
    tool = load_script("scripts/milestone_stops.py")
    logs = []
    for i, depths in enumerate([[5, 1], [2, 5]]):
        log = tmp_path / f"s{i}.jsonl"
        rows = [{"task": "cube_handoff", "condition": "stage", "seed": s, "progress": d, "success": d == 5}
                for s, d in enumerate(depths)]
        rows.append({"task": "other", "condition": "stage", "seed": 9, "progress": 0, "success": False})
        log.write_text("".join(json.dumps(r) + "\n" for r in rows))
        logs.append(log)
    tool.main(["--task", "cube_handoff", "--label", f"a={logs[0]}", "--label", f"a={logs[1]}"])
    row = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| a |")]
    assert row == ["| a | stage | 4 | 0 / 1 / 1 / 0 / 0 / 2 | 100 % | 75 % | 67 % | 100 % | 100 % |"]


def test_missing_log_is_a_usage_error(tmp_path, capsys):
    tool = load_script("scripts/milestone_stops.py")
    with pytest.raises(SystemExit):
        tool.main(["--label", f"a={tmp_path / 'nope.jsonl'}"])
    assert "no episode log" in capsys.readouterr().err


def test_malformed_label_is_a_usage_error(capsys):
    tool = load_script("scripts/milestone_stops.py")
    with pytest.raises(SystemExit):
        tool.main(["--label", "just-a-path.jsonl"])
    assert "want NAME=episodes.jsonl" in capsys.readouterr().err


def test_first_trigger_split_separates_early_events(tmp_path, capsys):
    tool = load_script("scripts/milestone_stops.py")
    rows = [{"task": "cube_handoff", "condition": "random", "seed": 0, "progress": 0, "triggers": [64, 140]},
            {"task": "cube_handoff", "condition": "random", "seed": 1, "progress": 5, "triggers": [88, 160]},
            {"task": "cube_handoff", "condition": "random", "seed": 2, "progress": 2, "triggers": [111, 190]},
            {"task": "cube_handoff", "condition": "clean", "seed": 0, "progress": 1, "triggers": []}]
    log = tmp_path / "r.jsonl"
    log.write_text("".join(json.dumps(r) + "\n" for r in rows))
    # the boundary step itself counts as not before it
    assert [tool.condition_group(r, 88) for r in rows] == [
        "random, first trigger < 88", "random, first trigger >= 88", "random, first trigger >= 88", "clean"]
    assert tool.condition_group(rows[0], None) == "random"
    tool.main(["--label", f"a={log}", "--first-trigger-split", "88"])
    out = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| a |")]
    assert out == [
        "| a | clean | 1 | 0 / 1 / 0 / 0 / 0 / 0 | 100 % | 0 % | - | - | - |",
        "| a | random, first trigger < 88 | 1 | 1 / 0 / 0 / 0 / 0 / 0 | 0 % | - | - | - | - |",
        "| a | random, first trigger >= 88 | 2 | 0 / 0 / 1 / 0 / 0 / 1 "
        "| 100 % | 100 % | 50 % | 100 % | 100 % |",
    ]

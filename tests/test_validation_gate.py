"""`scripts/validation_gate.py`, the Cube Handoff plans' gate, on hand-made episode logs: the counts are the
logs' successes, the gate passes at its minimums and not one below, and logs of the wrong size are refused."""

import json

import pytest
from _helpers import load_script


def write_log(path, cells):
    """cells: (condition, first seed, successes, episodes); one JSON line per episode."""
    lines = []
    for condition, first, wins, episodes in cells:
        lines += [json.dumps({"task": "cube_handoff", "condition": condition, "seed": first + i,
                              "success": i < wins}) for i in range(episodes)]
    path.write_text("\n".join(lines) + "\n")
    return path


def run(tmp_path, capsys, clean, stage, random, more, *flags):
    gate = load_script("scripts/validation_gate.py")
    first = write_log(tmp_path / "first.jsonl", [("clean", 1000, clean, 40), ("stage", 1000, stage, 40),
                                                  ("random", 1000, random, 40)])
    second = write_log(tmp_path / "more.jsonl", [("stage", 1040, more, 80)])
    gate.main([str(first), str(second), *flags])
    return capsys.readouterr().out


def test_the_gate_adds_both_stage_logs_and_passes_at_its_minimums(tmp_path, capsys):
    flags = ("--clean-min", "20", "--random-min", "10", "--stage-min", "78")
    out = run(tmp_path, capsys, 20, 23, 10, 55, *flags)  # 23 + 55 = 78
    assert "Clean 20 / 40" in out and "Stage 23 / 40 and 78 / 120" in out
    assert out.strip().endswith("-> passed")
    assert run(tmp_path, capsys, 20, 23, 10, 54, *flags).strip().endswith("-> not passed")  # Stage 77
    assert run(tmp_path, capsys, 19, 40, 40, 80, *flags).strip().endswith("-> not passed")  # Clean 19
    assert run(tmp_path, capsys, 40, 40, 9, 80, *flags).strip().endswith("-> not passed")  # Random-time 9
    # without Clean and Random-time minimums only Stage decides
    assert run(tmp_path, capsys, 0, 23, 0, 55).strip().endswith("-> passed")


def test_logs_of_the_wrong_size_are_refused(tmp_path):
    gate = load_script("scripts/validation_gate.py")
    first = write_log(tmp_path / "first.jsonl", [("stage", 1000, 20, 39)])
    second = write_log(tmp_path / "more.jsonl", [("stage", 1040, 50, 80)])
    with pytest.raises(SystemExit, match="expected 40 episodes per condition"):
        gate.main([str(first), str(second)])


def test_condition_successes_counts_one_condition_and_only_the_given_seeds():
    from lerobot_bavo.eval.run import condition_successes

    rows = [{"condition": "stage", "seed": 1000, "success": True},
            {"condition": "stage", "seed": 1001, "success": False},
            {"condition": "stage", "seed": 1040, "success": True},
            {"condition": "clean", "seed": 1000, "success": True}]
    assert condition_successes(rows, "stage") == (2, 3)
    assert condition_successes(rows, "stage", set(range(1000, 1040))) == (1, 2)
    assert condition_successes(rows, "clean") == (1, 1)
    assert condition_successes(rows, "random") == (0, 0)

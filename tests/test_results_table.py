"""scripts/results_table.py: the paper-format table's pooled Wilson interval and macro mean over tasks and
training seeds, checked on hand-computed cases, and the paper's own macro row reproduced from its per-task
tables (a check that the transcribed numbers are consistent)."""

from __future__ import annotations

import pytest
from _helpers import load_script


@pytest.fixture(scope="module")
def table():
    return load_script("scripts/results_table.py")


def cell(sr, n, tps=50.0, cvg=None):
    joint = None if cvg is None else sr * cvg / 100
    return {"sr": sr, "tps": tps, "cvg": cvg, "joint": joint, "n_episodes": n}


def test_pooled_interval_counts_every_episode(table):
    # two training seeds, 17/40 and 23/40: pooled 40/80 = 50 %; Wilson 95 % for 40/80 is 39.3-60.7 %
    wins, n, low, high = table.pooled_sr_interval({"a": cell(42.5, 40), "b": cell(57.5, 40)})
    assert (wins, n) == (40, 80)
    assert low == pytest.approx(39.3, abs=0.1) and high == pytest.approx(60.7, abs=0.1)


def test_macro_is_mean_over_tasks_then_over_seeds(table):
    cells = {"cube_handoff/stage": {"s0": cell(40.0, 40), "s1": cell(60.0, 40)},
             "block_stacking/stage": {"s0": cell(0.0, 40), "s1": cell(20.0, 40)}}
    mean, std = table.macro(cells, ["cube_handoff", "block_stacking"], "stage", "sr")
    # seed s0: (40 + 0) / 2 = 20; seed s1: (60 + 20) / 2 = 40; mean 30, sample std sqrt(2 * 10^2 / 1) = 14.14
    assert mean == pytest.approx(30.0) and std == pytest.approx(14.1421356)


def test_a_method_with_fewer_tasks_says_so(table):
    methods = {"afar": {f"cube_handoff/{c}": {"s0": cell(50.0, 40, cvg=20.0 if c == "random" else None)}
                        for c in table.CONDITIONS}}
    text = table.report(methods, ['--run "afar=results.json"'])
    assert "| afar | 1 of 5 | 1 | 50.0 | 50.0 | 50.0 | 50.0 | 50.0 | 50.0 |" in text
    assert "(1 of 5 tasks)" in text  # no five-task CVG average from one task
    assert "50.0 [35-65] (20/40)" in text  # Wilson 95 % for 20/40: 0.5 -+ 0.148 = 35.2-64.8 %


def test_a_one_seed_task_keeps_the_several_seed_macro_of_the_others(table):
    """Two tasks with seeds s0 and s1, a third with s0 only: the five-condition macro over all three tasks
    can use s0 alone, so a second row gives the two tasks over both seeds."""
    def cells_for(task, values):
        return {f"{task}/{c}": {label: cell(sr, 40) for label, sr in values.items()}
                for c in table.CONDITIONS}

    methods = {"m": {**cells_for("cube_handoff", {"s0": 40.0, "s1": 60.0}),
                     **cells_for("slide_retrieval", {"s0": 80.0, "s1": 100.0}),
                     **cells_for("block_stacking", {"s0": 10.0})}}
    text = "\n".join(table.macro_table(methods))
    # all three tasks, seed s0 only: (40 + 10 + 80) / 3 = 43.3
    assert "| m | 3 of 5 | 1 | 43.3 | 50.0 |" in text
    # the two tasks with both seeds: s0 (40 + 80) / 2 = 60, s1 (60 + 100) / 2 = 80 -> 70.0 +- 14.1
    assert "| m, the tasks with every seed | 2 of 5 | 2 | 70.0 ± 14.1 | 50.0 ± 0.0 |" in text
    # a method with the same seeds on every task gets one row
    one = {"n": cells_for("cube_handoff", {"s0": 40.0}) | cells_for("block_stacking", {"s0": 10.0})}
    assert "every seed" not in "\n".join(table.macro_table(one))


def test_paper_macro_matches_its_per_task_tables(table):
    for method, (sr, tps) in table.PAPER_MACRO.items():
        for i in range(3):
            for values, per_task in ((sr, 0), (tps, 1)):
                mean = sum(table.PAPER_TASKS[t][method][per_task][i][0] for t in table.TASKS) / 5
                assert mean == pytest.approx(values[i][0], abs=0.15), (method, i, per_task)


def test_grid_methods_get_readable_names(table, tmp_path, capsys):
    """`--name METHOD=LABEL` relabels a grid method; an unknown method is an error naming the grid's."""
    import json

    grid = {"methods": {"afar": {"cells": {f"cube_handoff/{c}": {"seeds": {"s1000": cell(25.0, 40)}}
                                           for c in table.CONDITIONS}}}}
    path = tmp_path / "results.json"
    path.write_text(json.dumps(grid))
    table.main(["--grid", str(path), "--name", "afar=A-FAR (ours)"])
    out = capsys.readouterr().out
    assert "| A-FAR (ours) | 1 of 5 | 1 | 25.0 |" in out and "| afar |" not in out
    with pytest.raises(SystemExit):
        table.main(["--grid", str(path), "--name", "act=ACT"])
    assert "the grid has no method act (it has afar)" in capsys.readouterr().err


def test_a_run_from_its_episode_log_matches_its_results(table, tmp_path):
    """`--run LABEL=episodes.jsonl.gz`: the cells computed from the committed log are bavo-eval's (hand case:
    2 Stage episodes, one success, progress 5 and 2 -> SR 50 %, TPS (100 + 40) / 2 = 70 %)."""
    import gzip
    import json

    records = [{"task": "cube_handoff", "condition": "stage", "seed": 2000 + i, "success": i == 0,
                "progress": p, "steps": 800, "episode_cvg": None, "events": []} for i, p in enumerate((5, 2))]
    log = tmp_path / "episodes.jsonl.gz"
    log.write_bytes(gzip.compress("".join(json.dumps(r) + "\n" for r in records).encode()))
    (cell_,) = table.methods_of_runs({"act": [log]})["act"]["cube_handoff/stage"].values()
    assert cell_["sr"] == 50.0 and cell_["tps"] == 70.0 and cell_["n_episodes"] == 2

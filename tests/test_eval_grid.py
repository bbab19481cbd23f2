"""`bavo-eval --grid FILE.yaml` (issue 15): the mean ± std aggregation over training seeds (a pure function,
checked on hand-computed values), a tiny real grid run twice (the second run does no work and writes the same
results; the table's mean ± std recomputed by hand from results.json), clear errors for bad grid files, and
the grid on Ray giving the same results.json as locally (skipped without Ray).

The tiny grid is Cube Handoff under Random-time, 1 episode, methods `expert` and `mix` (two "training seeds":
the expert and the frozen-camera expert, whose CVG differ, so the std is not 0): 3 scripted episodes, ~15 s on
2 cores.
"""

from __future__ import annotations

import importlib.util
import json
import re
import statistics
from pathlib import Path

import pytest

from lerobot_bavo.eval import cli, run
from lerobot_bavo.eval.grid import GridError, aggregate_seeds, load_grid, mean_std, parse_grid, run_grid

TINY = {"tasks": ["cube_handoff"], "conditions": ["random"], "episodes": 1, "seed": 1000,
        "methods": {"expert": "expert", "mix": ["expert", "expert-frozen-camera"]}}


def test_mean_std_by_hand():
    assert mean_std([100.0, 50.0, 75.0]) == (75.0, 25.0)  # sqrt((25^2 + 25^2 + 0) / (3 - 1)) = 25
    mean, std = mean_std([10.0, 20.0])
    assert mean == 15.0 and std == pytest.approx(7.0710678)  # sqrt((5^2 + 5^2) / 1)
    assert mean_std([42.0]) == (42.0, None)  # one training seed: no std
    assert mean_std([70.0, None]) == (None, None)  # a metric missing in one seed (CVG outside Random-time)
    assert mean_std([]) == (None, None)


def test_aggregate_seeds_by_hand():
    per_seed = {"s0": {"sr": 100.0, "tps": 100.0, "cvg": 60.0, "joint": 60.0, "n_episodes": 5},
                "s1": {"sr": 60.0, "tps": 80.0, "cvg": 20.0, "joint": 12.0, "n_episodes": 5}}
    cell = aggregate_seeds(per_seed)
    assert cell["n_seeds"] == 2 and cell["seeds"] is per_seed
    assert cell["mean"] == {"sr": 80.0, "tps": 90.0, "cvg": 40.0, "joint": 36.0}
    assert cell["std"]["sr"] == pytest.approx(28.2842712)  # |100 - 60| / sqrt(2)
    assert cell["std"]["tps"] == pytest.approx(14.1421356)
    assert cell["std"]["cvg"] == pytest.approx(28.2842712)
    assert cell["std"]["joint"] == pytest.approx(33.9411255)  # |60 - 12| / sqrt(2)


def _write(path: Path, grid: dict) -> Path:
    import yaml

    path.write_text(yaml.safe_dump(grid))
    return path


def test_tiny_grid_resumes_and_reports_mean_std(tmp_path, monkeypatch, capsys):
    grid = load_grid(_write(tmp_path / "grid.yaml", TINY))
    out = tmp_path / "grid"
    first = run_grid(grid, out)
    assert "3 to run" in capsys.readouterr().out

    def no_work(job):
        raise AssertionError(f"episode {job['seed']} of {job['policy']} ran again")

    monkeypatch.setattr(run, "run_job", no_work)
    second = run_grid(grid, out)  # the same command again: every cell is finished
    assert "3 finished, 0 to run" in capsys.readouterr().out
    assert second == first
    results = json.loads((out / "results.json").read_text())
    assert results == first
    assert (out / "results.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    for label in ("0", "1"):
        assert (out / "runs" / "mix" / label / "episodes.jsonl").read_text().count("\n") == 1

    # the table, recomputed by hand from the per-seed values in results.json
    seeds = results["methods"]["mix"]["cells"]["cube_handoff/random"]["seeds"]
    assert results["methods"]["mix"]["checkpoints"] == {"0": "expert", "1": "expert-frozen-camera"}
    assert seeds["1"]["cvg"] == 0.0 and seeds["0"]["cvg"] > 0  # the frozen camera never recovers the view
    row = next(line for line in (out / "results.md").read_text().splitlines() if line.startswith("| mix |"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells[:3] == ["mix", "2", "cube_handoff"]
    expected = []
    for metric in ("sr", "tps", "cvg"):
        values = [seeds[label][metric] for label in ("0", "1")]
        expected.append(f"{statistics.mean(values):.1f} ± {statistics.stdev(values):.1f}")
    assert cells[3:] == expected
    expert_row = next(
        line for line in (out / "results.md").read_text().splitlines() if line.startswith("| expert |")
    )
    cvg = results["methods"]["expert"]["cells"]["cube_handoff/random"]["seeds"]["0"]["cvg"]
    assert expert_row.rstrip(" |").endswith(f"| {cvg:.1f}")  # one training seed: the value alone
    assert "±" not in expert_row


@pytest.mark.parametrize(
    "change, message",
    [
        ({"tasks": ["cube_handof"]}, r"unknown task 'cube_handof'; choose from cube_handoff"),
        ({"conditions": ["clean", "fog"]}, r"unknown condition 'fog'"),
        ({"episode": 3}, r"unknown key 'episode'"),
        ({"episodes": 0}, r"episodes must be an integer >= 1, got 0"),
        ({"methods": {"afar": {"checkpoint": "expert"}}}, r"methods.afar: unknown key 'checkpoint'"),
        ({"methods": {"afar": {"tasks": ["cube_handoff"]}}}, r"methods.afar: missing key 'checkpoints'"),
        (
            {"methods": {"afar": "no/such/ckpt"}},
            r"methods.afar \(training seed 0\): checkpoint 'no/such/ckpt' not found",
        ),
        (
            {"methods": {"afar": {"checkpoints": {"s1": "expert", "s2": "no/such"}}}},
            r"methods.afar \(training seed s2\): checkpoint 'no/such' not found",
        ),
        (
            {"methods": {"e": {"checkpoints": "expert", "conditions": ["stage"]}}},
            r"methods.e.conditions \(of the grid's\): unknown condition 'stage'",
        ),
        ({"methods": {"a/b": "expert"}}, r"a method name must be a plain name"),
        ({"methods": {}}, r"methods must be a non-empty mapping"),
    ],
)
def test_bad_grid_files_are_named(change, message):
    with pytest.raises(GridError, match=r"^grid: .*" + message):
        parse_grid({**TINY, **change})


def test_a_folder_without_config_json_is_not_a_checkpoint(tmp_path):
    with pytest.raises(GridError, match=re.escape(f"no config.json in {tmp_path.resolve()}")):
        parse_grid({**TINY, "methods": {"afar": str(tmp_path)}})


def test_cli_grid_errors(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text("methods: [expert\n")
    with pytest.raises(SystemExit, match=r"bavo-eval: grid file .*bad.yaml is not valid YAML"):
        cli.main(["--grid", str(bad), "--output-dir", str(tmp_path / "out")])
    with pytest.raises(SystemExit, match=r"bavo-eval: grid file .*: unknown task 'nope'"):
        cli.main(["--grid", str(_write(tmp_path / "g.yaml", {**TINY, "tasks": ["nope"]})),
                  "--output-dir", str(tmp_path / "out")])
    with pytest.raises(SystemExit):  # the file sets the policy and the episodes
        cli.main(
            ["--grid", str(bad), "--policy", "expert", "--episodes", "3", "--output-dir", str(tmp_path / "o")]
        )
    assert "--policy, --episodes cannot be used with --grid" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        cli.main(["--output-dir", str(tmp_path / "o")])
    assert "--policy (or --grid FILE.yaml) is required" in capsys.readouterr().err
    assert not (tmp_path / "out").exists() and not (tmp_path / "o").exists()


@pytest.mark.slow  # ~20 s on 2 cores; test_ray_executor.py checks the Ray executor itself by default
@pytest.mark.skipif(importlib.util.find_spec("ray") is None,
                    reason="Ray is not installed (the optional extra: pip install 'lerobot_env_bavo[ray]')")
def test_grid_on_ray_gives_the_same_results_as_local(tmp_path):
    """One scripted-expert episode of Cube Handoff (clean) per method, on a private 1-CPU Ray and locally."""
    grid = parse_grid({**TINY, "conditions": ["clean"], "methods": {"expert": "expert"}})
    local = run_grid(grid, tmp_path / "local")
    on_ray = run_grid(grid, tmp_path / "ray", executor="ray")
    assert on_ray == local
    assert json.loads((tmp_path / "ray" / "results.json").read_text()) == local


CONFIGS = Path(__file__).resolve().parent.parent / "configs"


@pytest.mark.parametrize("name", sorted(p.name for p in CONFIGS.glob("*.yaml")))
def test_shipped_grid_files_parse_and_name_existing_checkpoints(name, monkeypatch):
    """Every grid file in configs/ loads (its checkpoints are folders with a config.json, checked by
    load_grid) when run from the repository root, as their comments say."""
    from lerobot_bavo.eval.grid import load_grid

    root = Path(__file__).resolve().parent.parent
    monkeypatch.chdir(root)
    grid = load_grid(root / "configs" / name)
    assert grid.methods
    for method in grid.methods:
        for _, policy, _, _ in method.runs(Path("out")):
            assert policy in ("expert", "expert-frozen-camera") or (root / policy / "config.json").is_file()


def test_per_task_checkpoints_get_one_run_per_task(tmp_path, monkeypatch):
    """A `{task}` checkpoint path (single-task policies, as the paper trains them): one bavo-eval run per
    (training seed, task) with that task's checkpoint, in runs/<method>/<label>/<task>/, and the method's
    cells and macro mean gathered from all of them."""
    for task in ("cube_handoff", "block_stacking"):
        (tmp_path / f"ck_{task}").mkdir()
        (tmp_path / f"ck_{task}" / "config.json").write_text("{}")
    spec = {"tasks": ["cube_handoff", "block_stacking"], "conditions": ["stage"], "episodes": 2, "seed": 2000,
            "methods": {"afar": {"checkpoints": {"s1": str(tmp_path / "ck_{task}")}}}}
    grid = parse_grid(spec)
    (method,) = grid.methods
    assert method.per_task
    assert [(label, policy, tasks, folder.relative_to(tmp_path)) for label, policy, tasks, folder
            in method.runs(tmp_path)] == [
        ("s1", str(tmp_path / "ck_cube_handoff"), ("cube_handoff",), Path("runs/afar/s1/cube_handoff")),
        ("s1", str(tmp_path / "ck_block_stacking"), ("block_stacking",), Path("runs/afar/s1/block_stacking")),
    ]
    calls = []
    sr = {"cube_handoff": 50.0, "block_stacking": 0.0}

    def fake_evaluate(policy, tasks, conditions, episodes, seed, output_dir, **kwargs):
        calls.append((Path(policy).name, tuple(tasks), Path(output_dir).relative_to(tmp_path)))
        (task,) = tasks
        return {"cells": {f"{task}/stage": {"sr": sr[task], "tps": 80.0, "cvg": None, "joint": None,
                                             "n_episodes": episodes}}}

    monkeypatch.setattr(run, "evaluate", fake_evaluate)
    results = run_grid(grid, tmp_path)
    assert calls == [("ck_cube_handoff", ("cube_handoff",), Path("runs/afar/s1/cube_handoff")),
                     ("ck_block_stacking", ("block_stacking",), Path("runs/afar/s1/block_stacking"))]
    afar = results["methods"]["afar"]
    assert afar["cells"]["cube_handoff/stage"]["mean"]["sr"] == 50.0
    assert afar["cells"]["block_stacking/stage"]["mean"]["sr"] == 0.0
    assert afar["mean_over_tasks"]["stage"]["mean"]["sr"] == 25.0  # (50 + 0) / 2
    assert afar["runs"] == {"s1/cube_handoff": "runs/afar/s1/cube_handoff",
                            "s1/block_stacking": "runs/afar/s1/block_stacking"}


def test_a_checkpoint_path_holds_no_other_field(tmp_path):
    spec = {"methods": {"afar": {"checkpoints": {"s1": str(tmp_path / "ck_{seed}")}}}}
    with pytest.raises(GridError, match=r"the only field a checkpoint path may hold is \{task\}"):
        parse_grid(spec)


def run_grid_with_stage_sr(grid, output_dir, monkeypatch, sr_of_folder: dict[str, float]) -> dict:
    """`run_grid` with `evaluate` replaced: each single-task run's Stage cell gets the SR named for its
    checkpoint folder (TPS 80), so that the aggregation can be checked against hand-computed means."""

    def fake_evaluate(policy, tasks, conditions, episodes, seed, output_dir, **kwargs):
        (task,) = tasks
        return {"cells": {f"{task}/stage": {"sr": sr_of_folder[Path(policy).name], "tps": 80.0, "cvg": None,
                                             "joint": None, "n_episodes": episodes}}}

    monkeypatch.setattr(run, "evaluate", fake_evaluate)
    return run_grid(grid, output_dir)


def test_a_training_seed_on_fewer_tasks(tmp_path, monkeypatch):
    """`{path, tasks}` for a training seed (extra seeds on Cube Handoff only): that seed is run and averaged
    only on its tasks; a cell's mean ± std is over the seeds that have it, the macro mean over the seeds that
    have every task (hand-computed below)."""
    for name in ("ck_cube_handoff", "ck_block_stacking", "ck_cube_handoff_s2"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "config.json").write_text("{}")
    spec = {"tasks": ["cube_handoff", "block_stacking"], "conditions": ["stage"], "episodes": 2, "seed": 2000,
            "methods": {"afar": {"checkpoints": {
                "s1": str(tmp_path / "ck_{task}"),
                "s2": {"path": str(tmp_path / "ck_{task}_s2"), "tasks": ["cube_handoff"]}}}}}
    grid = parse_grid(spec)
    (method,) = grid.methods
    assert [(label, Path(policy).name, tasks) for label, policy, tasks, _ in method.runs(tmp_path)] == [
        ("s1", "ck_cube_handoff", ("cube_handoff",)), ("s1", "ck_block_stacking", ("block_stacking",)),
        ("s2", "ck_cube_handoff_s2", ("cube_handoff",))]
    sr = {"ck_cube_handoff": 50.0, "ck_block_stacking": 10.0, "ck_cube_handoff_s2": 20.0}
    results = run_grid_with_stage_sr(grid, tmp_path, monkeypatch, sr)
    afar = results["methods"]["afar"]
    cube = afar["cells"]["cube_handoff/stage"]
    assert cube["n_seeds"] == 2 and cube["mean"]["sr"] == 35.0  # (50 + 20) / 2
    assert cube["std"]["sr"] == pytest.approx(21.2132034)  # |50 - 20| / sqrt(2)
    assert afar["cells"]["block_stacking/stage"]["n_seeds"] == 1
    assert afar["mean_over_tasks"]["stage"]["n_seeds"] == 1  # only s1 has both tasks
    assert afar["mean_over_tasks"]["stage"]["mean"]["sr"] == 30.0  # (50 + 10) / 2
    assert afar["checkpoints"]["s2"] == {"path": str(tmp_path / "ck_{task}_s2"), "tasks": ["cube_handoff"]}
    assert json.loads((tmp_path / "grid.json").read_text())["methods"]["afar"]["checkpoints"]["s2"]["tasks"] \
        == ["cube_handoff"]
    table = (tmp_path / "results.md").read_text().splitlines()
    rows = [line for line in table if line.startswith("| afar |")]
    assert [r.split("|")[2:4] for r in rows] == [[" 2 ", " cube_handoff "], [" 1 ", " block_stacking "],
                                                 [" 1 ", " **mean of 2** "]]
    for bad, message in (({"path": "expert"}, "exactly the keys path and tasks"),
                         ({"path": "expert", "tasks": ["drawer_stowing"]}, "unknown task 'drawer_stowing'")):
        spec["methods"]["afar"]["checkpoints"]["s2"] = bad
        with pytest.raises(GridError, match=message):
            parse_grid(spec)


def test_a_checkpoint_named_per_task(tmp_path, monkeypatch):
    """A training seed given as task -> checkpoint (a setting chosen per task on the validation seeds, e.g.
    lr 1e-3 where it passed its gate and the recipe's elsewhere): one run per task with that task's folder,
    and the macro mean over those tasks (hand-computed below)."""
    for name in ("ck_cube_lr", "ck_block_recipe"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "config.json").write_text("{}")
    chosen = {"cube_handoff": str(tmp_path / "ck_cube_lr"),
              "block_stacking": str(tmp_path / "ck_block_recipe")}
    spec = {"tasks": ["cube_handoff", "block_stacking"], "conditions": ["stage"], "episodes": 2, "seed": 2000,
            "methods": {"afar-chosen": {"checkpoints": {"s1": dict(chosen)}}}}
    grid = parse_grid(spec)
    (method,) = grid.methods
    assert method.per_task and method.tasks_of("s1") == ("cube_handoff", "block_stacking")
    assert [(label, Path(policy).name, tasks, folder.relative_to(tmp_path)) for label, policy, tasks, folder
            in method.runs(tmp_path)] == [
        ("s1", "ck_cube_lr", ("cube_handoff",), Path("runs/afar-chosen/s1/cube_handoff")),
        ("s1", "ck_block_recipe", ("block_stacking",), Path("runs/afar-chosen/s1/block_stacking"))]
    sr = {"ck_cube_lr": 62.5, "ck_block_recipe": 7.5}
    results = run_grid_with_stage_sr(grid, tmp_path, monkeypatch, sr)
    chosen_results = results["methods"]["afar-chosen"]
    assert chosen_results["mean_over_tasks"]["stage"]["mean"]["sr"] == 35.0  # (62.5 + 7.5) / 2
    assert chosen_results["checkpoints"]["s1"] == chosen
    assert json.loads((tmp_path / "grid.json").read_text())["methods"]["afar-chosen"]["checkpoints"]["s1"] \
        == chosen
    for bad, message in (({"cube_handof": chosen["cube_handoff"]}, r"unknown task 'cube_handof'"),
                         ({"cube_handoff": 3}, r"on cube_handoff must be a path, got 3"),
                         ({"cube_handoff": str(tmp_path / "ck_{task}")}, r"named per task holds no field"),
                         ({"cube_handoff": "no/such"},
                          r"task cube_handoff\): checkpoint 'no/such' not found"),
                         ({"drawer_stowing": chosen["cube_handoff"]}, r"unknown task 'drawer_stowing'")):
        spec["methods"]["afar-chosen"]["checkpoints"]["s1"] = bad
        with pytest.raises(GridError, match=message):
            parse_grid(spec)

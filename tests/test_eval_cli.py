"""`bavo-eval` (lerobot_bavo.eval.cli): help, a tiny expert run, results layout, resume and
argument errors.

The run uses the CLI's default image sizes (it has no size flags), one episode per cell.
Slow (run with `-m slow`): everything but the argument checks; about 90 s on a shared 2-core
machine (three default-size expert episodes with videos, and two `--help` subprocesses that
each import torch through `lerobot_bavo` -> `lerobot.configs`, ~15 s wall apiece there).
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

from lerobot_bavo.eval.cli import evaluate

REPO = Path(__file__).resolve().parents[1]
TASK = "cube_handoff"
REQUIRED = ("sr", "tps", "cvg", "joint", "n_episodes", "episodes")


def _lines(path: Path) -> int:
    return sum(1 for line in path.read_text().splitlines() if line.strip())


@pytest.mark.slow
def test_help_runs():
    env = dict(os.environ, PYTHONPATH=str(REPO), MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"))
    out = subprocess.run([sys.executable, "-m", "lerobot_bavo.eval.cli", "--help"], cwd=REPO, env=env,
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    for flag in ("--policy", "--tasks", "--conditions", "--episodes", "--seed", "--output-dir", "--videos"):
        assert flag in out.stdout
    script = Path(sys.executable).parent / "bavo-eval"
    if script.exists():  # the installed console script
        out = subprocess.run([str(script), "--help"], cwd=REPO, env=env, capture_output=True, text=True,
                             timeout=120)
        assert out.returncode == 0 and "--policy" in out.stdout, out.stderr


@pytest.fixture(scope="module")
def first_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("eval")
    results = evaluate("expert", [TASK], ["clean", "random"], episodes=1, seed=0, output_dir=out, videos=1)
    return out, results


@pytest.mark.slow
def test_results_layout(first_run):
    out, results = first_run
    on_disk = json.loads((out / "results.json").read_text())
    assert on_disk["cells"].keys() == results["cells"].keys() == {f"{TASK}/clean", f"{TASK}/random"}
    for key, cell in on_disk["cells"].items():
        for k in REQUIRED:
            assert k in cell, (key, k)
        assert cell["n_episodes"] == 1 and len(cell["episodes"]) == 1
        ep = cell["episodes"][0]
        assert ep["seed"] == 0
        assert 0.0 <= cell["sr"] <= 100.0 and 0.0 <= cell["tps"] <= 100.0
        assert cell["sr"] == (100.0 if ep["success"] else 0.0)
        assert cell["tps"] == pytest.approx(100.0 * ep["progress"] / 5)
    clean, rand = on_disk["cells"][f"{TASK}/clean"], on_disk["cells"][f"{TASK}/random"]
    assert clean["cvg"] is None and clean["joint"] is None
    assert isinstance(rand["cvg"], float) and math.isfinite(rand["cvg"])
    # CVG in pp: 100 x the episode's CVG (one episode)
    assert rand["cvg"] == pytest.approx(100.0 * rand["episodes"][0]["episode_cvg"])
    assert rand["joint"] == pytest.approx(rand["sr"] * rand["cvg"] / 100.0)
    md = (out / "results.md").read_text()
    assert "| cube_handoff | clean |" in md and "| cube_handoff | random |" in md
    for cond in ("clean", "random"):
        video = out / "videos" / f"{TASK}_{cond}_seed0.mp4"
        assert video.is_file() and video.stat().st_size > 1000, video
    assert _lines(out / "episodes.jsonl") == 2


@pytest.mark.slow
def test_resume_runs_only_missing_episodes(first_run):
    out, results = first_run
    log = out / "episodes.jsonl"
    evaluate("expert", [TASK], ["clean", "random"], episodes=1, seed=0, output_dir=out, videos=0)
    assert _lines(log) == 2  # nothing re-run
    first_clean = results["cells"][f"{TASK}/clean"]["episodes"][0]
    more = evaluate("expert", [TASK], ["clean"], episodes=2, seed=0, output_dir=out, videos=0)
    assert _lines(log) == 3  # only seed 1 of the clean cell ran
    cell = more["cells"][f"{TASK}/clean"]
    assert cell["n_episodes"] == 2 and [e["seed"] for e in cell["episodes"]] == [0, 1]
    assert cell["episodes"][0] == first_clean  # the finished episode was kept, not re-run
    new = json.loads(log.read_text().splitlines()[-1])
    assert (new["task"], new["condition"], new["seed"]) == (TASK, "clean", 1)


@pytest.mark.slow
def test_other_policy_in_same_dir_is_refused(first_run):
    out, _ = first_run
    with pytest.raises(SystemExit, match="different settings"):
        evaluate("expert-frozen-camera", [TASK], ["clean"], episodes=1, seed=0, output_dir=out)


def test_unknown_task_or_condition(tmp_path):
    with pytest.raises(SystemExit, match="unknown task 'no_such_task'"):
        evaluate("expert", ["no_such_task"], ["clean"], episodes=1, seed=0, output_dir=tmp_path / "a")
    with pytest.raises(SystemExit, match="unknown condition 'foggy'"):
        evaluate("expert", [TASK], ["foggy"], episodes=1, seed=0, output_dir=tmp_path / "b")
    with pytest.raises(SystemExit, match="neither"):
        evaluate("no/such/checkpoint", [TASK], ["clean"], episodes=1, seed=0, output_dir=tmp_path / "c")
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_videos_without_their_writer_are_refused_before_any_episode(tmp_path, monkeypatch):
    """Without imageio-ffmpeg, imageio's MP4 writer is PyAV's, which refuses the writer's arguments at the end
    of the first episode; the run is refused up front instead, naming the package and the way out."""
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "imageio_ffmpeg" else real(name, *a))
    with pytest.raises(SystemExit, match="imageio-ffmpeg.*--videos 0"):
        evaluate("expert", [TASK], ["clean"], episodes=1, seed=0, output_dir=tmp_path / "v", videos=1)
    assert not (tmp_path / "v").exists()


@pytest.mark.parametrize("policy, light", [
    ("expert", True), ("expert-frozen-camera", True),
    (str(REPO / "checkpoints/afar_cube_handoff_sf"), False)])
def test_worker_pool_skips_lerobot_for_scripted_experts(tmp_path, monkeypatch, policy, light):
    """Scripted experts need neither LeRobot nor PyTorch in the episode workers: their pool is made with
    `light_import=True` (worker start-up ~4.5 -> ~0.4 s of CPU on the 2-core machine); a checkpoint's pool
    registers LeRobot's policy types in every worker. The pool is stopped at its creation (no episode
    runs)."""
    import lerobot_bavo.eval.run as run

    made = []

    class PoolMade(Exception):
        pass

    def spy_pool(workers, start_method="spawn", light_import=False):
        made.append((workers, light_import))
        raise PoolMade

    monkeypatch.setattr(run, "WorkerPool", spy_pool)
    with pytest.raises(PoolMade):
        evaluate(policy, [TASK], ["clean"], episodes=2, seed=0, output_dir=tmp_path / "out", workers=2,
                 videos=0)
    assert made == [(2, light)]


def test_results_name_a_checkpoint_relative_to_the_working_directory_when_inside_it(tmp_path):
    from lerobot_bavo.eval.run import checkpoint_label

    project = tmp_path / "project"
    (project / "checkpoints" / "afar_x").mkdir(parents=True)
    outside = tmp_path / "elsewhere" / "afar_y"
    outside.mkdir(parents=True)
    (tmp_path / "link").symlink_to(project)
    assert checkpoint_label(str(project / "checkpoints" / "afar_x"), cwd=project) == "checkpoints/afar_x"
    # another spelling of the same folder (a symlinked working directory) gives the same label
    label = checkpoint_label(str(project / "checkpoints" / "afar_x"), cwd=tmp_path / "link")
    assert label == "checkpoints/afar_x"
    assert checkpoint_label(str(outside), cwd=project) == str(outside.resolve())

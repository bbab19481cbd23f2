"""`bavo-eval --executor ray` (issue 15): the same results as the local executor, resume, a killed Ray worker
retried with nothing lost or duplicated, a killed driver re-run doing only the unfinished episodes, and the
local executor never importing Ray.

The Ray tests start one private local Ray for the module (`ray.init(num_cpus=2)`, loopback only, no dashboard)
and are skipped, with the reason, where Ray (the optional 'ray' extra) is not installed. Its workers get this
checkout and this folder on PYTHONPATH (the environment Ray starts with), so they import the package under
test and this module's fake episode. The fake episodes (`fake_job`: a short sleep, a fixed record) keep the
resume and kill tests cheap: the write path, resume and lock are the real ones. The real comparison runs two
scripted-expert episodes of Cube Handoff per executor (~20 s on 2 cores); the killed-driver test runs two
`bavo-eval` commands, each starting its own private Ray (~35 s). About 65 s in all on 2 cores.
"""

from __future__ import annotations

import importlib.util
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
HERE = Path(__file__).resolve().parent
MARKS_ENV = "BAVO_TEST_RAY_MARKS"

needs_ray = pytest.mark.skipif(
    importlib.util.find_spec("ray") is None,
    reason="Ray is not installed (the optional extra: pip install 'lerobot_env_bavo[ray]')",
)


def fake_job(job: dict) -> dict:
    """A fake episode run in a Ray worker: marks `<seed>.<pid>` in $BAVO_TEST_RAY_MARKS, sleeps, returns a
    record."""
    marks = Path(os.environ[MARKS_ENV])
    (marks / f"{job['seed']}.{os.getpid()}").touch()
    time.sleep(0.4)
    return {"task": job["task"], "condition": job["condition"], "seed": job["seed"], "success": True,
            "progress": 5, "steps": 300, "pid": os.getpid()}


def start_local_ray(tmp_path_factory, marks_env: str):
    """A loopback-only local Ray with 2 CPUs whose workers import this repository and the test modules and
    find a fresh marks folder in $`marks_env`; yields (ray, marks folder) and shuts Ray down afterwards.
    Shared with tests/test_collect_ray.py."""
    ray = pytest.importorskip("ray", reason="Ray is not installed (pip install 'lerobot_env_bavo[ray]')")
    marks = tmp_path_factory.mktemp("marks")
    saved = dict(os.environ)
    os.environ.update(
        {
            "PYTHONPATH": os.pathsep.join([str(REPO), str(HERE), os.environ.get("PYTHONPATH", "")]),
            marks_env: str(marks),
            "OPENBLAS_NUM_THREADS": "1",
            "OMP_NUM_THREADS": "1",
            "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl"),
        }
    )
    try:  # the workers inherit the environment Ray starts with
        ray.init(num_cpus=2, include_dashboard=False, _node_ip_address="127.0.0.1", logging_level="WARNING")
    finally:
        os.environ.clear()
        os.environ.update(saved)
    yield ray, marks
    ray.shutdown()


@pytest.fixture(scope="module")
def local_ray(tmp_path_factory):
    yield from start_local_ray(tmp_path_factory, MARKS_ENV)


def marked_starts(marks: Path) -> dict[int, list[int]]:
    """seed -> the pids that started it."""
    out: dict[int, list[int]] = {}
    for f in marks.iterdir():
        seed, pid = f.name.split(".")
        out.setdefault(int(seed), []).append(int(pid))
    return out


def start_killer(marks: Path, victim: int, timeout_s: float = 120.0) -> tuple[threading.Thread, list[int]]:
    """A thread that SIGKILLs the first process marked as having started seed `victim` (once); returns the
    thread and the list it appends the killed pid to."""
    killed: list[int] = []

    def kill_when_started() -> None:
        deadline = time.time() + timeout_s
        while time.time() < deadline and not killed:
            started = marked_starts(marks).get(victim)
            if started:
                os.kill(started[0], signal.SIGKILL)
                killed.append(started[0])
            time.sleep(0.02)

    killer = threading.Thread(target=kill_when_started, daemon=True)
    killer.start()
    return killer, killed


def clear_marks(marks: Path) -> None:
    for f in marks.iterdir():
        f.unlink()


def _log_seeds(out: Path) -> list[int]:
    return [json.loads(line)["seed"] for line in (out / "episodes.jsonl").read_text().splitlines()]


def _without_wall_time(results: dict) -> dict:
    for cell in results["cells"].values():
        for episode in cell["episodes"]:
            episode.pop("wall_s")
    return results


@needs_ray
def test_ray_gives_the_same_results_as_local(local_ray, tmp_path):
    """Two scripted-expert episodes of Cube Handoff (clean): results.json identical but for wall times."""
    from lerobot_bavo.eval.cli import evaluate

    kw = dict(policy="expert", tasks=["cube_handoff"], conditions=["clean"], episodes=2, seed=1000, videos=0)
    evaluate(**kw, output_dir=tmp_path / "local", executor="local")
    evaluate(**kw, output_dir=tmp_path / "ray", executor="ray")
    local, on_ray = (json.loads((tmp_path / name / "results.json").read_text()) for name in ("local", "ray"))
    assert _without_wall_time(on_ray) == _without_wall_time(local)
    assert sorted(_log_seeds(tmp_path / "ray")) == [1000, 1001]


@needs_ray
def test_ray_resumes_like_local(local_ray, tmp_path, monkeypatch, capsys):
    """Three episodes run locally, then the same command for six on Ray runs only the three missing ones."""
    from lerobot_bavo.eval import cli, run

    _, marks = local_ray
    monkeypatch.setattr(run, "run_job", fake_job)
    monkeypatch.setenv(MARKS_ENV, str(marks))  # for the in-process local run
    clear_marks(marks)
    out = tmp_path / "eval"
    kw = dict(
        policy="expert", tasks=["cube_handoff"], conditions=["clean"], seed=1000, videos=0, output_dir=out
    )
    cli.evaluate(**kw, episodes=3, executor="local")
    clear_marks(marks)
    results = cli.evaluate(**kw, episodes=6, executor="ray")
    assert "3 finished episodes kept, 3 to run" in capsys.readouterr().out
    assert sorted(marked_starts(marks)) == [1003, 1004, 1005]
    assert sorted(_log_seeds(out)) == list(range(1000, 1006))
    assert results["cells"]["cube_handoff/clean"]["n_episodes"] == 6


@needs_ray
def test_a_killed_ray_worker_is_retried_and_nothing_is_lost_or_duplicated(local_ray, tmp_path, monkeypatch):
    """SIGKILL the Ray worker running seed 1003 mid-episode: Ray re-runs that episode in another worker; every
    seed is logged exactly once and results.json counts each once."""
    from lerobot_bavo.eval import cli, run

    _, marks = local_ray
    monkeypatch.setattr(run, "run_job", fake_job)
    clear_marks(marks)
    victim = 1003
    killer, killed = start_killer(marks, victim)
    out = tmp_path / "eval"
    results = cli.evaluate(
        "expert", ["cube_handoff"], ["clean"], episodes=8, seed=1000, output_dir=out, videos=0, executor="ray"
    )
    killer.join(timeout=5)
    assert killed, "the victim episode never started"
    started = marked_starts(marks)
    # killed once, run again elsewhere
    assert len(started[victim]) == 2 and killed[0] in started[victim], started
    seeds = _log_seeds(out)
    assert sorted(seeds) == list(range(1000, 1008)), seeds  # none lost, none twice
    records = json.loads((out / "results.json").read_text())["cells"]["cube_handoff/clean"]["episodes"]
    assert [r["seed"] for r in records] == list(range(1000, 1008))
    assert next(r for r in records if r["seed"] == victim)["pid"] != killed[0]
    assert results["cells"]["cube_handoff/clean"]["n_episodes"] == 8


def test_missing_ray_is_named_and_local_never_imports_ray(tmp_path):
    """Without Ray, --executor ray ends with a message naming the extra; --executor local (the default) runs
    without importing Ray (a fresh interpreter, fake episodes)."""
    script = f"""
import sys
sys.modules["ray"] = None  # as if Ray were not installed
from lerobot_bavo.eval import cli, run
def fake(job):
    return {{"task": job["task"], "condition": job["condition"], "seed": job["seed"], "success": True,
             "progress": 5}}
run.run_job = fake
args = ["--policy", "expert", "--tasks", "cube_handoff", "--conditions", "clean", "--episodes", "2",
        "--videos", "0"]
# an import of ray would fail
cli.main(args + ["--output-dir", {str(tmp_path / "local")!r}, "--workers", "2"])
try:
    cli.main(args + ["--output-dir", {str(tmp_path / "ray")!r}, "--executor", "ray"])
except SystemExit as e:
    print("EXIT:", e)
"""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]),
               OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"))
    proc = subprocess.run(
        [sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=300
    )
    assert proc.returncode == 0, proc.stderr
    assert (
        "EXIT: bavo-eval: --executor ray needs Ray, the optional 'ray' extra: pip install "
        "'lerobot_env_bavo[ray]'"
        in proc.stdout
    ), proc.stdout
    assert sorted(_log_seeds(tmp_path / "local")) == [1000, 1001]
    assert not (tmp_path / "ray").exists()


# A bavo-eval on its own private Ray whose episodes are fake (1 s each; defined in __main__, so Ray ships
# them).
FAKE_RAY_EVAL = """
import sys, time
from lerobot_bavo.eval import cli, run
def fake(job):
    time.sleep(1.0)
    return {"task": job["task"], "condition": job["condition"], "seed": job["seed"], "success": True,
            "progress": 5}
run.run_job = fake
cli.main(sys.argv[1:])
"""


@pytest.mark.slow  # ~30 s on 2 cores; the local executor's resume tests run by default
@needs_ray
def test_a_killed_driver_rerun_does_only_the_unfinished_episodes(tmp_path):
    """kill -9 of `bavo-eval --executor ray` (its own private Ray) after a few episodes; the same command
    again keeps those and runs the rest: every seed once."""
    out = tmp_path / "eval"
    cmd = [
        sys.executable,
        "-c",
        FAKE_RAY_EVAL,
        "--policy",
        "expert",
        "--tasks",
        "cube_handoff",
        "--conditions",
        "clean",
        "--episodes",
        "12",
        "--videos",
        "0",
        "--workers",
        "2",
        "--executor",
        "ray",
        "--output-dir",
        str(out),
    ]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]),
               OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"))
    env.pop("RAY_ADDRESS", None)
    first = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.time() + 180
        log = out / "episodes.jsonl"
        while (
            time.time() < deadline
            and first.poll() is None
            and not (log.exists() and log.read_text().count("\n") >= 2)
        ):
            time.sleep(0.1)
        assert first.poll() is None, (
            f"bavo-eval ended before it could be killed: {first.communicate()[1][-2000:]}"
        )
        first.kill()
        first.wait(timeout=30)
    finally:
        if first.poll() is None:
            first.kill()
    kept = _log_seeds(out)
    assert 2 <= len(kept) < 12 and len(set(kept)) == len(kept)
    rerun = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
    assert rerun.returncode == 0, rerun.stderr[-3000:]
    assert f"{len(kept)} finished episodes kept, {12 - len(kept)} to run" in rerun.stdout
    assert sorted(_log_seeds(out)) == list(range(1000, 1012))
    results = json.loads((out / "results.json").read_text())
    assert results["cells"]["cube_handoff/clean"]["n_episodes"] == 12


@needs_ray
def test_a_private_rays_workers_run_at_normal_priority_and_import_no_pytorch(tmp_path):
    """A private Ray started by `RayPool` runs its workers at the caller's priority like a local pool (Ray's
    default adds 15, which lets any other load starve the episodes) and with the package's light import (no
    PyTorch for an expert episode). The caller's niceness is this process's (`nice pytest` raises both)."""
    code = (
        "import os, sys\n"
        "from lerobot_bavo.runtime.ray_pool import RayPool\n"
        "def probe(job):\n"
        "    import lerobot_bavo.eval.cli  # what an episode job imports\n"
        "    return os.nice(0), 'torch' in sys.modules\n"
        "with RayPool(1) as pool:\n"
        "    print(list(pool.imap(probe, [{}])))\n")
    env = dict(os.environ, PYTHONPATH=str(REPO), OPENBLAS_NUM_THREADS="1", RAY_ADDRESS="")
    env.pop("RAY_worker_niceness", None)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=180, env=env,
                         cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.strip().splitlines()[-1] == f"[({os.nice(0)}, False)]", out.stdout + out.stderr[-2000:]

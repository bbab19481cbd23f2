"""Overhead of `bavo-eval --executor ray` against `--executor local` on the same cores, same run.

Runs the same evaluation (default: the scripted expert, Cube Handoff, clean, 10 episodes, no videos, 2
workers) as a whole `bavo-eval` command, once per executor and repeat, alternating which goes first, each into
a fresh folder, and prints the wall time of every run, the ratio ray / local of the best runs (target: at most
1.15x), and where the difference goes: the episodes' own time (the records' wall_s, summed, divided by the
workers) is the same on both, the rest is start-up and shut-down (for Ray: importing it, starting a private
local Ray with --workers CPUs, fresh worker processes importing MuJoCo and the package, stopping Ray).

    python benchmarks/ray_overhead.py [--episodes 10] [--workers 2] [--repeats 1] [--task cube_handoff]
    [--cluster]

`--cluster`: the Ray runs use a standing local Ray (`ray start --head` once, before the runs, as on a cluster,
stopped after them) through `--ray-address`, instead of each run starting and stopping a private one; what
then remains is connecting, the job's fresh worker processes and their imports.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


CLUSTER_PORT = 6391
# Ray >= 2.5x turns token authentication on for a local `ray.init` and keeps the token in ~/.ray/auth_token;
# a `ray start` head then refuses clients with "InvalidAuthToken". The benchmark's head listens on loopback
# only, so it runs without authentication (head and clients alike).
CLUSTER_ENV = {"RAY_AUTH_MODE": "disabled"}


def bench_env() -> dict:
    return dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]),
                OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"),
                HF_HUB_OFFLINE="1")


def ray_cli(*args: str) -> None:
    """`ray ARGS...` with the workers' environment (a standing Ray's workers inherit it from its raylet), at
    nice 0 as the cluster recipe in docs/benchmark.md starts them."""
    exe = Path(sys.executable).with_name("ray")
    env = dict(bench_env(), BAVO_LIGHT_IMPORT="1", RAY_worker_niceness="0", **CLUSTER_ENV)
    proc = subprocess.run([str(exe), *args], env=env, capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"ray {' '.join(args)} failed:\n{proc.stderr[-2000:]}")


def run(executor: str, args, out: Path) -> tuple[float, float]:
    """Wall time of one bavo-eval run and the sum of its episodes' wall_s."""
    env = bench_env()
    cmd = [sys.executable, "-m", "lerobot_bavo.eval.cli", "--policy", args.policy, "--tasks", args.task,
           "--conditions", args.condition, "--episodes", str(args.episodes), "--videos", "0",
           "--workers", str(args.workers), "--executor", executor, "--output-dir", str(out)]
    if executor == "ray" and args.cluster:
        cmd += ["--ray-address", f"127.0.0.1:{CLUSTER_PORT}"]
        env.update(CLUSTER_ENV)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"{executor} run failed:\n{proc.stderr[-3000:]}")
    records = [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines()]
    assert len(records) == args.episodes
    return wall, sum(r["wall_s"] for r in records)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--episodes", type=int, default=10)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--repeats", type=int, default=1)
    p.add_argument("--task", default="cube_handoff")
    p.add_argument("--condition", default="clean")
    p.add_argument("--policy", default="expert")
    p.add_argument("--cluster", action="store_true",
                   help="Ray runs join a standing local Ray (ray start --head) instead of starting their own")
    args = p.parse_args()
    if args.cluster:
        ray_cli("start", "--head", f"--num-cpus={args.workers}", "--include-dashboard=false",
                "--node-ip-address=127.0.0.1", f"--port={CLUSTER_PORT}", "--disable-usage-stats")
    try:
        measure(args)
    finally:
        if args.cluster:
            ray_cli("stop")


def measure(args) -> None:
    walls: dict[str, list[float]] = {"local": [], "ray": []}
    episode_s: dict[str, list[float]] = {"local": [], "ray": []}
    with tempfile.TemporaryDirectory(prefix="ray_overhead_") as tmp:
        for i in range(args.repeats):
            for executor in (("local", "ray") if i % 2 == 0 else ("ray", "local")):
                wall, eps = run(executor, args, Path(tmp) / f"{executor}{i}")
                walls[executor].append(wall)
                episode_s[executor].append(eps)
                print(
                    f"{executor:5s} run {i}: {wall:6.1f} s wall, episodes {eps:6.1f} s summed "
                    f"({eps / args.workers:5.1f} s per worker), start-up + shut-down "
                    f"~{wall - eps / args.workers:5.1f} s",
                    flush=True,
                )
    best = {k: min(v) for k, v in walls.items()}
    ray_kind = "a standing local Ray (--ray-address)" if args.cluster else "a private Ray per run"
    print(
        f"\n{args.episodes} episodes of {args.policy} on {args.task}/{args.condition}, {args.workers} "
        "workers, "
        f"{os.cpu_count()} cores, Ray runs on {ray_kind}; best of {args.repeats}:"
    )
    print(
        f"  local {best['local']:.1f} s, ray {best['ray']:.1f} s: ratio ray/local = "
        f"{best['ray'] / best['local']:.2f}x "
        "(target <= 1.15x)"
    )


if __name__ == "__main__":
    main()

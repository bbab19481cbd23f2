"""How `bavo-collect` and `bavo-eval` scale with the worker count, and how much of all CPU the coordinating
process spends (issue 30).

Why these figures: a run with N workers can be at most 1 / (s + (1 - s) / N) times faster than with one
(Amdahl), where s is the share of the work that is serial. The coordinating process (the one that schedules
episodes, writes the dataset or the episode log) is that serial part, so its share of all CPU time estimates
s without a machine with many idle cores: on a 2-core machine that also runs other jobs, wall times are noise,
CPU times are not.

For every `--workers` count and `--job` it runs the project's own command (`bavo-collect` or
`bavo-eval --policy expert`, through their `main(argv)`) in a fresh subprocess with a fresh output folder
and prints:
- wall time (s) and the speed-up over the first worker count;
- CPU time (user + sys, s) of the coordinating process itself (all its threads: `RUSAGE_SELF`, written by the
  subprocess when its command returns) and of all processes (the coordinator, its workers and anything they
  started, e.g. encoder processes): this script makes itself a child subreaper (`PR_SET_CHILD_SUBREAPER`),
  so a descendant orphaned by a worker or by the coordinator's exit is re-parented here and reaped, and
  `RUSAGE_CHILDREN` then counts every descendant's CPU;
- the coordinator's share s of all CPU, CPU seconds per episode, and the Amdahl bound 1 / (s + (1 - s) / N)
  for that worker count and for 16 workers;
- for collection, also the steady-state costs per episode from the collection record's timings: the writing
  process's CPU while it wrote and a worker's CPU per episode; their ratio is how many workers one writer
  keeps up with once start-up (the coordinator's imports, which overlap the workers' own) is over.

    python benchmarks/scale_workers.py --workers 2,4,8,16 --episodes 24 [--job collect|eval|both]
        [--task cube_handoff] [--condition stage] [--tree PATH] [--json FILE]

`--tree PATH` imports the package from another checkout (e.g. a `git worktree` of an older commit), to
measure a version before a change with the same script. The figures and the machines they were measured on:
docs/results/costs.md ("Scaling with workers").
"""

from __future__ import annotations

import argparse
import ctypes
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PR_SET_CHILD_SUBREAPER = 36  # linux/prctl.h

# Runs one command in the subprocess and writes the coordinator's own CPU seconds (all its threads) to a file
# when the command returns, before the interpreter's exit (which may still join worker processes: their CPU
# is theirs, counted through RUSAGE_CHILDREN by the benchmark).
CHILD = """import json, resource, sys, time
job, out, argv = sys.argv[1], sys.argv[2], sys.argv[3:]
t0 = time.perf_counter()
if job == "collect":
    from lerobot_bavo.datasets.collect import main
    rc = main(argv)
else:
    from lerobot_bavo.eval.cli import main
    rc = main(argv)
r = resource.getrusage(resource.RUSAGE_SELF)
with open(out, "w") as f:
    json.dump({"self_cpu_s": r.ru_utime + r.ru_stime, "wall_s": time.perf_counter() - t0, "rc": rc}, f)
"""


def become_subreaper() -> bool:
    """Orphaned descendants are re-parented to this process (so their CPU reaches RUSAGE_CHILDREN)."""
    try:
        return ctypes.CDLL("libc.so.6").prctl(PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def reap_all() -> None:
    """Wait for every remaining descendant (workers that outlive the coordinator exit within a second)."""
    while True:
        try:
            os.waitpid(-1, 0)
        except ChildProcessError:
            return


def children_cpu() -> tuple[float, float]:
    """User and kernel CPU seconds of all reaped descendants."""
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime, r.ru_stime


def command_argv(job: str, args, workers: int, out: Path) -> list[str]:
    if job == "collect":
        return ["--task", args.task, "--condition", args.condition, "--episodes", str(args.episodes),
                "--repo-id", "bench/scale_workers", "--root", str(out), "--workers", str(workers),
                "--no-progress"]
    return ["--policy", "expert", "--tasks", args.task, "--conditions", args.condition,
            "--episodes", str(args.episodes), "--workers", str(workers), "--videos", "0",
            "--output-dir", str(out)]


def run_once(job: str, args, workers: int, tmp: Path) -> dict:
    """One measured run: wall, the coordinator's CPU, all processes' CPU (seconds)."""
    out = tmp / f"{job}_{workers}"
    stats = tmp / f"{job}_{workers}.json"
    # the tree first, then whatever PYTHONPATH already held (the GPU machine installs its wheels there)
    pythonpath = os.pathsep.join(filter(None, [str(args.tree), os.environ.get("PYTHONPATH")]))
    env = dict(os.environ, PYTHONPATH=pythonpath, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1",
               HF_HUB_OFFLINE="1", MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"))
    before = children_cpu()
    t0 = time.perf_counter()
    cmd = [sys.executable, "-c", CHILD, job, str(stats), *command_argv(job, args, workers, out)]
    proc = subprocess.run(cmd, env=env, cwd=args.tree, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                          text=True)
    wall = time.perf_counter() - t0
    reap_all()
    after = children_cpu()
    kernel = after[1] - before[1]
    total = after[0] - before[0] + kernel
    if proc.returncode != 0 or not stats.exists():
        raise SystemExit(
            f"{job} with {workers} workers failed (exit {proc.returncode}):\n{proc.stderr[-3000:]}")
    own = json.loads(stats.read_text())
    per_episode = writer_costs(out) if job == "collect" else {}
    shutil.rmtree(out, ignore_errors=True)
    share = own["self_cpu_s"] / total if total > 0 else float("nan")
    return {"job": job, "workers": workers, "episodes": args.episodes, "wall_s": round(wall, 2),
            "coordinator_cpu_s": round(own["self_cpu_s"], 2), "total_cpu_s": round(total, 2),
            "coordinator_share": round(share, 4), "cpu_s_per_episode": round(total / args.episodes, 3),
            "kernel_cpu_share": round(kernel / total, 4) if total > 0 else float("nan"), **per_episode}


def writer_costs(root: Path) -> dict:
    """Steady-state costs per episode from the collection record's timings (CPU seconds): the writing
    process's while it wrote (its sessions, LeRobot's threads included) and a worker's (recording to staging).
    Their ratio bounds the speed-up once start-up is over: the writer keeps up with at most that many
    workers."""
    record = json.loads((root / "meta" / "bavo_collection.json").read_text())
    commits = record["runs"][-1]["timings"].get("commits", [])
    episodes = [e for c in commits for e in c["episodes"]]
    if not episodes:
        return {}
    writer = sum(c["cpu_s"] for c in commits) / len(episodes)
    worker = sum(e.get("cpu_s", 0.0) for e in episodes) / len(episodes)
    return {"writer_cpu_s_per_episode": round(writer, 3), "worker_cpu_s_per_episode": round(worker, 3),
            "workers_one_writer_keeps_up_with": round(worker / writer, 1) if writer > 0 else None}


def amdahl(share: float, workers: int) -> float:
    """The most a serial share `share` allows `workers` processes to speed a run up over one."""
    return 1.0 / (share + (1.0 - share) / workers)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--workers", default="2,4,8,16", help="comma-separated worker counts")
    ap.add_argument("--episodes", type=int, default=24, help="episodes per run (kept, for collect)")
    ap.add_argument("--job", choices=("collect", "eval", "both"), default="both")
    ap.add_argument("--task", default="cube_handoff")
    ap.add_argument("--condition", default="stage")
    ap.add_argument("--tree", type=Path, default=REPO, help="the checkout whose package is imported")
    ap.add_argument("--json", type=Path, default=None, help="also write the rows as JSON here")
    args = ap.parse_args()
    args.tree = args.tree.resolve()
    counts = [int(w) for w in args.workers.split(",")]
    jobs = ["collect", "eval"] if args.job == "both" else [args.job]
    if not become_subreaper():
        print("warning: not a child subreaper; CPU of orphaned descendants may be missed", file=sys.stderr)
    print(f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}; {args.episodes} x {args.task} / "
          f"{args.condition}; package from {args.tree}")
    rows = []
    tmp = Path(tempfile.mkdtemp(prefix="bavo_scale_"))
    try:
        for job in jobs:
            first = None
            print(f"\n{job}:  workers   wall s  speed-up  coord CPU s  all CPU s  CPU s/ep  coord share  "
                  "Amdahl(N)  Amdahl(16)")
            for w in counts:
                row = run_once(job, args, w, tmp)
                first = first or row
                row["speedup"] = round(first["wall_s"] / row["wall_s"], 3)
                s = row["coordinator_share"]
                row["amdahl_n"], row["amdahl_16"] = round(amdahl(s, w), 2), round(amdahl(s, 16), 2)
                rows.append(row)
                print(f"{'':6}{w:8d} {row['wall_s']:8.1f} {row['speedup']:9.2f} "
                      f"{row['coordinator_cpu_s']:12.1f} "
                      f"{row['total_cpu_s']:10.1f} {row['cpu_s_per_episode']:9.2f} {100 * s:11.1f} % "
                      f"{row['amdahl_n']:10.2f} {row['amdahl_16']:11.2f}   (kernel time "
                      f"{100 * row['kernel_cpu_share']:.0f} % of all CPU)", flush=True)
                if "writer_cpu_s_per_episode" in row:
                    print(f"{'':14}per episode: writer {row['writer_cpu_s_per_episode']:.2f} s CPU, worker "
                          f"{row['worker_cpu_s_per_episode']:.2f} s CPU -> one writer keeps up with "
                          f"{row['workers_one_writer_keeps_up_with']} workers")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    print(json.dumps(rows))


if __name__ == "__main__":
    main()

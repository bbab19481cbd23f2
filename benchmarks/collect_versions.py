"""Whole `bavo-collect` runs of this checkout against another commit, side by side.

The machines are noisy (the same 100-episode run differs by ~5 % from one hour to the next), so a change to
collection is judged by runs of both versions alternating in one sitting. This checks the other commit out
in a temporary git worktree, then runs N-episode collections (the package imported from each tree in turn,
fresh folders, `--workers` processes), `--repeats` times each, alternating which goes first, and prints the
wall time and the CPU time (the process and its workers, every descendant counted: this script is a child
subreaper, as `scale_workers.py`) of every run and the ratios of the means.

    python benchmarks/collect_versions.py --baseline f90bc49 [--episodes 30] [--repeats 2] [--task
    cube_handoff]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from scale_workers import become_subreaper, reap_all  # this folder (run as a script)

REPO = Path(__file__).resolve().parents[1]

CODE = """import sys
from lerobot_bavo.datasets.collect import CollectConfig, collect
task, condition, root = sys.argv[1], sys.argv[2], sys.argv[5]
episodes, workers = int(sys.argv[3]), int(sys.argv[4])
collect(CollectConfig(task=task, condition=condition, episodes=episodes, repo_id="bench/versions", root=root,
                      workers=workers, progress=False))
"""


def run_once(tree: Path, args, root: Path) -> tuple[float, float]:
    env = dict(
        os.environ, PYTHONPATH=str(tree), OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", HF_HUB_OFFLINE="1"
    )
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(
        [
            sys.executable,
            "-c",
            CODE,
            args.task,
            args.condition,
            str(args.episodes),
            str(args.workers),
            str(root),
        ],
        check=True,
        env=env,
        cwd=tree,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    wall = time.perf_counter() - t0
    reap_all()  # workers that outlived the run (orphans re-parented here): their CPU counts too
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--baseline", required=True, help="the commit to compare against (any git revision)")
    ap.add_argument("--episodes", type=int, default=30)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--task", default="cube_handoff")
    ap.add_argument("--condition", default="stage")
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    become_subreaper()

    tmp = Path(tempfile.mkdtemp(prefix="bavo_versions_"))
    baseline_tree = tmp / "baseline"
    subprocess.run(["git", "-C", str(REPO), "worktree", "add", "--detach", str(baseline_tree), args.baseline],
                   check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    trees = {"this checkout": REPO, f"baseline {args.baseline}": baseline_tree}
    runs: dict[str, list[tuple[float, float]]] = {name: [] for name in trees}
    print(f"{args.episodes} x {args.task} / {args.condition}, {args.workers} workers; "
          f"load average before {os.getloadavg()[0]:.1f}")
    try:
        for r in range(args.repeats):
            order = list(trees) if r % 2 == 0 else list(reversed(trees))
            for name in order:
                root = tmp / f"ds_{len(runs[name])}_{name.split()[0]}"
                wall, cpu = run_once(trees[name], args, root)
                runs[name].append((wall, cpu))
                print(
                    f"  {name:<24} run {r}: wall {wall:6.1f} s, CPU {cpu:6.1f} s (process + workers)",
                    flush=True,
                )
                shutil.rmtree(root, ignore_errors=True)
    finally:
        subprocess.run(["git", "-C", str(REPO), "worktree", "remove", "--force", str(baseline_tree)],
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        shutil.rmtree(tmp, ignore_errors=True)
    new, old = (runs[name] for name in trees)
    mean = lambda v, i: sum(x[i] for x in v) / len(v)  # noqa: E731
    print(f"mean wall: this checkout {mean(new, 0):.1f} s, baseline {mean(old, 0):.1f} s -> ratio "
          f"{mean(new, 0) / mean(old, 0):.3f}")
    print(f"mean CPU:  this checkout {mean(new, 1):.1f} s, baseline {mean(old, 1):.1f} s -> ratio "
          f"{mean(new, 1) / mean(old, 1):.3f}")
    print(json.dumps({"baseline": args.baseline, "episodes": args.episodes, "runs": runs,
                      "wall_ratio": round(mean(new, 0) / mean(old, 0), 3),
                      "cpu_ratio": round(mean(new, 1) / mean(old, 1), 3)}))


if __name__ == "__main__":
    main()

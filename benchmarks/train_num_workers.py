"""Training step rate of `lerobot-train` at `--num_workers=0` against LeRobot's default (4 workers).

Why: `scripts/train_task.sh` passes `--num_workers=0` where LeRobot's default is 4. The BAVO data path serves
whole batches from memory (`lerobot_bavo.datasets.fast`), so a worker process saves no decoding; on a 2-core
machine its worker processes compete with the training step for the same cores. This measures what that choice
is worth instead of assuming it.

Each setting runs the real `lerobot-train` (the recipe's arguments: `--policy.type=afar`,
`--policy.preset=cpu_fast`, 128 points per step, batch 128, two torch threads) for `--steps` steps into a
temporary folder, no checkpoint saved; the settings alternate run by run for `--rounds` rounds, so drifting
machine load affects each alike. Per run it reads LeRobot's own log lines (`updt_s`, `data_s`: means over each
`--log-freq` window) and skips the first window (start-up, worker spawn); per step = `updt_s + data_s`
(seconds), the step rate its inverse, and also the wall time between the first and last kept log line (1 s
resolution). Prints the median of each setting and its ratio to `--num_workers=0`, side by side.

    OPENBLAS_NUM_THREADS=1 python benchmarks/train_num_workers.py \\
        --root outputs/datasets/bavo_cube_handoff_dartsf512_points \\
        --repo-id local/bavo_cube_handoff_dartsf512_points
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile
from datetime import datetime
from pathlib import Path

LOG_LINE = re.compile(
    r"INFO (\d{4}-\d\d-\d\d \d\d:\d\d:\d\d) .*?step:(\d+) .*?updt_s:([0-9.]+) data_s:([0-9.]+)"
)


def parse_args() -> argparse.Namespace:
    class Formatter(argparse.RawDescriptionHelpFormatter, argparse.ArgumentDefaultsHelpFormatter):
        pass

    p = argparse.ArgumentParser(description=__doc__, formatter_class=Formatter)
    p.add_argument("--root", required=True, help="a BAVO points view (scripts/train_task.sh views makes one)")
    p.add_argument("--repo-id", required=True, help="its repo id")
    p.add_argument("--workers", type=int, nargs="+", default=[0, 4],
                   help="--num_workers values compared; the first is the reference of the ratios")
    p.add_argument("--steps", type=int, default=200, help="training steps per run")
    p.add_argument("--log-freq", type=int, default=50, help="lerobot-train --log_freq (steps per window)")
    p.add_argument("--rounds", type=int, default=2, help="runs per setting, alternating")
    p.add_argument("--batch", type=int, default=128)
    p.add_argument("--threads", type=int, default=2, help="torch threads of the training process")
    p.add_argument("--policy", default="afar", choices=["afar", "maniflow"])
    args = p.parse_args()
    if args.steps < 2 * args.log_freq:
        p.error(f"--steps {args.steps} leaves no timed window: at least 2 x --log-freq ({2 * args.log_freq})")
    if any(w < 0 for w in args.workers):
        p.error(f"--workers must be >= 0, got {args.workers}")
    return args


def windows(log: str) -> list[tuple[datetime, int, float]]:
    """(time, step, seconds per step) of each logged window of a lerobot-train log."""
    return [
        (datetime.strptime(t, "%Y-%m-%d %H:%M:%S"), int(step), float(updt) + float(data))
        for t, step, updt, data in LOG_LINE.findall(log)
    ]


def one_run(args: argparse.Namespace, num_workers: int, out: Path) -> tuple[float, float | None]:
    """(median s/step from LeRobot's log, wall s/step between the kept log lines) of one run."""
    cmd = [
        "lerobot-train", f"--policy.type={args.policy}", "--policy.preset=cpu_fast", "--policy.device=cpu",
        "--policy.push_to_hub=false", "--policy.points_per_step=128", "--policy.n_action_steps=12",
        f"--dataset.repo_id={args.repo_id}", f"--dataset.root={args.root}", f"--num_workers={num_workers}",
        f"--batch_size={args.batch}", f"--steps={args.steps}", f"--save_freq={args.steps * 10}",
        "--save_checkpoint=false", f"--log_freq={args.log_freq}", "--seed=1000", f"--output_dir={out}",
        "--wandb.enable=false",
    ]
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS=str(args.threads), HF_HUB_OFFLINE="1")
    done = subprocess.run(cmd, env=env, capture_output=True, text=True)
    log = done.stdout + done.stderr
    if done.returncode != 0:
        sys.exit(f"lerobot-train --num_workers={num_workers} failed (exit {done.returncode}):\n{log[-3000:]}")
    kept = windows(log)[1:]  # the first window holds start-up and the workers' spawn
    if not kept:
        sys.exit(f"no log line after the first window (--num_workers={num_workers}):\n{log[-3000:]}")
    per_step = statistics.median(s for _, _, s in kept)
    wall = None
    if len(kept) >= 2:
        (t0, s0, _), (t1, s1, _) = kept[0], kept[-1]
        wall = (t1 - t0).total_seconds() / (s1 - s0)
    return per_step, wall


def main() -> None:
    args = parse_args()
    results: dict[int, list[tuple[float, float | None]]] = {w: [] for w in args.workers}
    with tempfile.TemporaryDirectory(prefix="bavo_num_workers_") as tmp:
        for r in range(args.rounds):
            for w in args.workers:
                got = one_run(args, w, Path(tmp) / f"r{r}_w{w}")
                results[w].append(got)
                wall = f"{got[1]:.3f}" if got[1] is not None else "-"
                print(f"round {r + 1}/{args.rounds}  --num_workers={w}: {got[0]:.3f} s/step (log), "
                      f"{wall} s/step (wall)", flush=True)
    ref = statistics.median(s for s, _ in results[args.workers[0]])
    print(f"\n{args.policy}, batch {args.batch}, {args.threads} torch threads, {os.cpu_count()} CPUs, "
          f"{args.rounds} runs of {args.steps} steps per setting (median over the windows after the first)")
    print("| --num_workers | s/step (updt_s + data_s) | steps/s | wall s/step | steps/s vs the first |")
    print("|---|---|---|---|---|")
    for w in args.workers:
        s = statistics.median(x for x, _ in results[w])
        walls = [x for _, x in results[w] if x is not None]
        wall = f"{statistics.median(walls):.3f}" if walls else "-"
        print(f"| {w} | {s:.3f} | {1 / s:.2f} | {wall} | {ref / s:.2f}x |")


if __name__ == "__main__":
    main()

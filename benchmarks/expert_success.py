"""Success rate and episode length of the scripted experts (Clean unless --condition is given).

Runs `--episodes` seeded episodes per task (seeds start..start+N-1), in `--workers` processes,
and prints SR (%), TPS (%) and the steps each successful episode needed. Example:

    python benchmarks/expert_success.py --tasks cube_handoff --episodes 50 --workers 2
"""

from __future__ import annotations

import argparse
import os
import time
from concurrent.futures import ProcessPoolExecutor

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MUJOCO_GL", "egl")


def run_episode(args: tuple[str, str, int]) -> dict:
    task, condition, seed = args
    from lerobot_bavo.envs.bavo_env import BavoEnv
    from lerobot_bavo.experts import make_expert

    env = BavoEnv(task=task, condition=condition, image_height=96, image_width=128, n_points=64)
    obs, info = env.reset(seed=seed)
    expert = make_expert(env)
    expert.reset()
    steps = 0
    while True:
        obs, reward, terminated, truncated, info = env.step(expert.act(obs, info))
        steps += 1
        if terminated or truncated:
            break
    env.close()
    return {"task": task, "seed": seed, "success": info["is_success"], "progress": info["progress"],
            "steps": steps, "phase": expert.phase}


def main() -> None:
    from lerobot_bavo.envs.tasks import TASKS

    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--tasks", default=",".join(TASKS), help="comma-separated task names")
    parser.add_argument("--condition", default="clean", help="visibility condition (default: clean)")
    parser.add_argument("--episodes", type=int, default=50, help="episodes per task")
    parser.add_argument("--start-seed", type=int, default=0, help="first seed")
    parser.add_argument("--workers", type=int, default=2, help="worker processes")
    args = parser.parse_args()

    from tqdm import tqdm

    jobs = [
        (t, args.condition, args.start_seed + i) for t in args.tasks.split(",") for i in range(args.episodes)
    ]
    t0 = time.perf_counter()
    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        results = list(tqdm(pool.map(run_episode, jobs), total=len(jobs), desc="episodes"))
    wall = time.perf_counter() - t0
    print(
        f"\n{'task':<18}{'SR %':>7}{'TPS %':>8}{'steps (succ.) mean/min/max':>30}  failures "
        "(seed:progress@phase)"
    )
    for task in args.tasks.split(","):
        rs = [r for r in results if r["task"] == task]
        succ = [r for r in rs if r["success"]]
        sr = 100.0 * len(succ) / len(rs)
        tps = 100.0 * sum(r["progress"] for r in rs) / (5 * len(rs))
        st = [r["steps"] for r in succ] or [0]
        fails = " ".join(f"{r['seed']}:{r['progress']}@{r['phase']}" for r in rs if not r["success"])
        print(f"{task:<18}{sr:>7.1f}{tps:>8.1f}{sum(st) / len(st):>18.0f}/{min(st)}/{max(st)}  {fails}")
    print(f"\n{len(jobs)} episodes in {wall:.0f} s with {args.workers} workers")


if __name__ == "__main__":
    main()

"""Control-step throughput of the BAVO env, on ONE CPU core, measured side by side in one run.

For each task: replays the scripted expert's actions for one episode (so contacts and grasps
happen as in real use) and measures
  * physics only:   `env.simulate(action)` (20 substeps of 2 ms, interpolated targets),
  * full step:      `env.step(action)` = physics + milestones + RGB-D render + point cloud,
  * bare render:    one RGB-D render of the active camera,
  * self-filtered:  the full step of an env with `self_filter=True` (one more depth-only render of
                    the robot model per step, docs/results/self_filter.md),
and prints steps/s, the full-step / bare-render ratio, the self-filtered / full-step ratio and each
task's per-step cost relative to Cube Handoff. The process pins itself to one core and asks Mesa's
llvmpipe for one thread (LP_NUM_THREADS=1) before any GL context exists.

    python benchmarks/env_step.py [--tasks cube_handoff,...] [--points 256] [--height 240 --width 320]
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("LP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MUJOCO_GL", "egl")


def measure(task: str, n_points: int, height: int, width: int, repeats: int) -> dict:
    from lerobot_bavo.envs.bavo_env import BavoEnv
    from lerobot_bavo.experts import make_expert

    env = BavoEnv(task=task, image_height=height, image_width=width, n_points=n_points)
    filtered = BavoEnv(task=task, image_height=height, image_width=width, n_points=n_points, self_filter=True)
    obs, info = env.reset(seed=0)
    expert = make_expert(env)
    expert.reset()
    actions = []
    while True:
        a = expert.act(obs, info)
        actions.append(a)
        obs, _, terminated, truncated, info = env.step(a)
        if terminated or truncated:
            break

    def seconds_per_action(e: BavoEnv, advance) -> float:
        """Replay the expert's actions from the seed-0 reset through `advance`; mean seconds per action."""
        e.reset(seed=0)
        t0 = time.perf_counter()
        for a in actions:
            advance(a)
        return (time.perf_counter() - t0) / len(actions)

    best = {"physics": float("inf"), "full": float("inf"), "render": float("inf"), "filtered": float("inf")}
    for _ in range(repeats):  # interleave the four measurements; keep the best of each
        best["physics"] = min(best["physics"], seconds_per_action(env, env.simulate))
        best["full"] = min(best["full"], seconds_per_action(env, env.step))
        best["filtered"] = min(best["filtered"], seconds_per_action(filtered, filtered.step))

        t0 = time.perf_counter()
        for _ in range(len(actions) // 4):
            env._render_active()  # noqa: SLF001 - the bare render is exactly what we time
        best["render"] = min(best["render"], (time.perf_counter() - t0) / (len(actions) // 4))
    env.close()
    filtered.close()
    return {"task": task, "steps": len(actions), **best}


def main() -> None:
    from lerobot_bavo.envs.tasks import TASKS

    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--tasks", default=",".join(TASKS), help="comma-separated task names")
    parser.add_argument("--points", type=int, default=256, help="points per cloud (default 256)")
    parser.add_argument("--height", type=int, default=240, help="image height (default 240)")
    parser.add_argument("--width", type=int, default=320, help="image width (default 320)")
    parser.add_argument("--repeats", type=int, default=3, help="timing repeats; the best is kept")
    parser.add_argument("--core", type=int, default=0, help="CPU core to pin to")
    args = parser.parse_args()

    os.sched_setaffinity(0, {args.core})
    rows = [measure(t, args.points, args.height, args.width, args.repeats) for t in args.tasks.split(",")]
    ref = rows[0]["full"]
    print(f"one core (cpu {args.core}), {args.height}x{args.width} RGB-D, {args.points}-point cloud")
    print(f"{'task':<18}{'steps':>6}{'physics/s':>11}{'full/s':>9}{'render ms':>11}{'full ms':>9}"
          f"{'full/render':>13}{'vs first':>10}{'filtered ms':>13}{'filtered/full':>15}")
    for r in rows:
        print(f"{r['task']:<18}{r['steps']:>6}{1 / r['physics']:>11.0f}{1 / r['full']:>9.0f}"
              f"{1e3 * r['render']:>11.2f}{1e3 * r['full']:>9.2f}{r['full'] / r['render']:>13.2f}"
              f"{r['full'] / ref:>10.2f}{1e3 * r['filtered']:>13.2f}{r['filtered'] / r['full']:>15.2f}")


if __name__ == "__main__":
    main()

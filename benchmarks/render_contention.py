"""Does one frame cost more when many processes render at once? (issue 30)

On a 16-core GPU machine, 16 `bavo-collect` / `bavo-eval` workers kept only ~10 of the 16 cores busy and each
episode cost 1.3x the CPU it cost with 2 workers (docs/results/costs.md). One suspect is the renderer: every
worker has its own EGL context on the one GPU, and a frame read back waits behind the other contexts' work.
This script separates that from everything else. P processes start together (spawn), each builds the same
BAVO env, replays the scripted expert's episode of one seed (`env.step`: physics, milestones, render, point
cloud), then renders the active camera's view R times alone (`env.render_active_rgb`). For each P it prints,
median over the processes, the wall and CPU milliseconds per step and per bare render, and the frames per
second of all processes together, side by side in one run. If the bare render's wall time grows with P while
its CPU time does not, the processes wait for a shared renderer (the GPU); if its CPU time grows too, they
spin while waiting (NVIDIA's driver without `__GL_YIELD=USLEEP`) or share cores.

    python benchmarks/render_contention.py --procs 1,2 [--renders 200] [--task cube_handoff]   # 2 cores
    python benchmarks/render_contention.py --procs 2,8,16                                      # 16 cores
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import statistics
import time


def one_process(task: str, condition: str, seed: int, renders: int, start, out) -> None:
    """Build the env, wait for the common start, then time the episode's steps and the bare renders."""
    from lerobot_bavo.runtime.process import limit_threads

    limit_threads()  # the workers' environment: one thread, headless GL, the driver's wait policy
    from lerobot_bavo.envs.bavo_env import BavoEnv
    from lerobot_bavo.experts import make_expert

    env = BavoEnv(task=task, condition=condition)
    obs, info = env.reset(seed=seed)
    env.render_active_rgb()  # the GL context exists before the clock starts
    start.wait()
    expert = make_expert(env, seed=seed)
    expert.reset()
    steps = 0
    w0, c0 = time.perf_counter(), time.process_time()
    while True:
        obs, _, terminated, truncated, info = env.step(expert.act(obs, info))
        steps += 1
        if terminated or truncated:
            break
    w1, c1 = time.perf_counter(), time.process_time()
    for _ in range(renders):
        env.render_active_rgb()
    w2, c2 = time.perf_counter(), time.process_time()
    env.close()
    out.put({"steps": steps, "step_wall_ms": 1e3 * (w1 - w0) / steps, "step_cpu_ms": 1e3 * (c1 - c0) / steps,
             "render_wall_ms": 1e3 * (w2 - w1) / renders, "render_cpu_ms": 1e3 * (c2 - c1) / renders})


def run(procs: int, args) -> dict:
    ctx = mp.get_context("spawn")
    start = ctx.Barrier(procs)
    out = ctx.Queue()
    job = (args.task, args.condition, args.seed, args.renders, start, out)
    workers = [ctx.Process(target=one_process, args=job) for _ in range(procs)]
    for w in workers:
        w.start()
    rows = [out.get() for _ in workers]
    for w in workers:
        w.join()
    med = {k: statistics.median(r[k] for r in rows) for k in rows[0]}
    med["frames_per_s_all"] = procs * 1e3 / med["render_wall_ms"]
    return med


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--procs", default="1,2", help="comma-separated process counts, run one after another")
    ap.add_argument("--renders", type=int, default=200, help="bare renders per process after its episode")
    ap.add_argument("--task", default="cube_handoff")
    ap.add_argument("--condition", default="stage")
    ap.add_argument("--seed", type=int, default=0, help="the expert episode's seed (a data seed)")
    args = ap.parse_args()
    print(f"{os.cpu_count()} cores, MUJOCO_GL={os.environ.get('MUJOCO_GL', 'egl')}, "
          f"__GL_YIELD={os.environ.get('__GL_YIELD', '(unset: USLEEP in the processes)')}; {args.task} / "
          f"{args.condition}, seed {args.seed}; medians over the processes")
    print(f"{'procs':>5} {'steps':>6} {'step wall ms':>13} {'step CPU ms':>12} {'render wall ms':>15} "
          f"{'render CPU ms':>14} {'frames/s, all':>14}")
    for p in (int(x) for x in args.procs.split(",")):
        m = run(p, args)
        print(f"{p:5d} {m['steps']:6.0f} {m['step_wall_ms']:13.2f} {m['step_cpu_ms']:12.2f} "
              f"{m['render_wall_ms']:15.2f} {m['render_cpu_ms']:14.2f} {m['frames_per_s_all']:14.0f}",
              flush=True)


if __name__ == "__main__":
    main()

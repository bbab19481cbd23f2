"""Cost of CVG: wall time of one Random-time evaluation episode with and without CVG, ONE core.

CVG (paper Eq. 2) needs, on every step of an open recovery window, a second visibility render
from the camera frozen at the event start. This measures what that adds to a whole episode:

  * random + CVG     BavoEnv(condition="random", compute_cvg=True,  episode_length=N)
  * random, no CVG   BavoEnv(condition="random", compute_cvg=False, episode_length=N)
                     (the occluder and the realised-visibility render are still there)
  * clean            BavoEnv(condition="clean", episode_length=N) for reference
                     (no occluder, no visibility renders)

All three replay the same fixed action sequence: the scripted expert's actions, recorded once
from a Random-time run of the same seed (the expert's camera recovery depends on the events,
so its trajectory is recorded once and then replayed; the occluder never affects dynamics, so
every replay follows the same states). So that the episode really runs all N steps with every
trigger and its CVG bookkeeping (a success would end it at ~430 steps and close the CVG
summary), every env gets the task with its success milestone M5 masked out; the milestone
checks still run, so the per-step cost is unchanged. Measurements are interleaved and the best
of --repeats is kept for each variant. The process pins itself to one core and asks Mesa's
llvmpipe for one thread (LP_NUM_THREADS=1) before any GL context exists. Target: CVG adds at most 1.5x.

    python benchmarks/eval_episode.py [--steps 500] [--seed 0] [--repeats 3]
                                      [--height 240 --width 320] [--core N]
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("LP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MUJOCO_GL", "egl")


def no_success_task(name: str):
    """The task `name` with M5 (success) never reported, so an episode runs to its step limit."""
    from lerobot_bavo.envs.tasks import make_task

    task = make_task(name)
    evaluate = task.evaluate

    def evaluate_without_success(model, data):
        flags = evaluate(model, data)
        flags["m5"] = False
        return flags

    task.evaluate = evaluate_without_success
    return task


def record_actions(task: str, seed: int, steps: int, size: tuple[int, int]):
    """The expert's actions for a `steps`-step Random-time episode."""
    import numpy as np

    from lerobot_bavo.envs.bavo_env import BavoEnv
    from lerobot_bavo.experts import make_expert

    env = BavoEnv(task=no_success_task(task), condition="random", image_height=size[0], image_width=size[1],
                  episode_length=steps, render_mode=None)
    obs, info = env.reset(seed=seed)
    triggers = info["occlusion"]["triggers"]
    expert = make_expert(env)
    expert.reset()
    actions = []
    while True:
        a = expert.act(obs, info)
        actions.append(np.array(a))
        obs, _, terminated, truncated, info = env.step(a)
        if terminated or truncated:
            break
    env.close()
    return actions, triggers, info["progress"]


def replay(env, actions, seed: int) -> tuple[float, dict]:
    t0 = time.perf_counter()
    env.reset(seed=seed)
    for a in actions:
        _, _, _, _, info = env.step(a)
    return time.perf_counter() - t0, info


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--task", default="cube_handoff")
    parser.add_argument(
        "--steps", type=int, default=500, help="episode length in control steps (default 500)"
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--repeats", type=int, default=3, help="interleaved repetitions; best kept (default 3)"
    )
    parser.add_argument("--height", type=int, default=240, help="observation image height (env default 240)")
    parser.add_argument("--width", type=int, default=320, help="observation image width (env default 320)")
    parser.add_argument("--core", type=int, default=None, help="CPU core to pin to (default: lowest allowed)")
    args = parser.parse_args(argv)

    core = min(os.sched_getaffinity(0)) if args.core is None else args.core
    os.sched_setaffinity(0, {core})

    from lerobot_bavo.envs.bavo_env import BavoEnv

    size = (args.height, args.width)
    t0 = time.perf_counter()
    actions, triggers, depth = record_actions(args.task, args.seed, args.steps, size)
    print(f"task {args.task}, seed {args.seed}, {len(actions)} steps, {size[0]}x{size[1]}, core {core}; "
          f"triggers {triggers}; expert reached M{depth} (M5 masked); "
          f"recorded in {time.perf_counter() - t0:.1f} s")

    common = dict( image_height=size[0], image_width=size[1], episode_length=args.steps,
                  render_mode=None)
    envs = {
        "random + CVG": BavoEnv(
            task=no_success_task(args.task), condition="random", compute_cvg=True, **common
        ),
        "random, no CVG": BavoEnv(
            task=no_success_task(args.task), condition="random", compute_cvg=False, **common
        ),
        "clean": BavoEnv(task=no_success_task(args.task), condition="clean", **common),
    }
    for env in envs.values():  # warm up: GL contexts and lazy renderers
        replay(env, actions[:3], args.seed)

    best = {name: float("inf") for name in envs}
    infos = {}
    for r in range(args.repeats):
        for name, env in envs.items():
            dt, infos[name] = replay(env, actions, args.seed)
            best[name] = min(best[name], dt)
        print(f"  repeat {r + 1}: " + ", ".join(f"{n} {best[n]:.2f} s" for n in envs))

    n = len(actions)
    import numpy as np

    same = all(np.array_equal(env.data.qpos, envs["clean"].data.qpos) for env in envs.values())
    print(f"final states identical across the three replays: {same}")
    cvg = infos["random + CVG"].get("cvg") or {}
    frozen_steps = sum(e["num_samples"] for e in cvg.get("events", []))
    print(
        f"episode CVG (random + CVG): {cvg.get('episode_cvg')}, retained events "
        f"{cvg.get('num_retained')}/{cvg.get('num_events')}, steps inside recovery windows "
        f"{frozen_steps}/{n + 1}"
    )
    for name in envs:
        print(f"{name:>15}: {best[name]:7.2f} s  ({1000 * best[name] / n:6.1f} ms/step)")
    ratio = best["random + CVG"] / best["random, no CVG"]
    print(f"CVG / no CVG: {ratio:.3f}x (target <= 1.5x) -> {'OK' if ratio <= 1.5 else 'OVER TARGET'}")
    print(f"random + CVG / clean: {best['random + CVG'] / best['clean']:.3f}x; "
          f"random no CVG / clean: {best['random, no CVG'] / best['clean']:.3f}x")
    for env in envs.values():
        env.close()


if __name__ == "__main__":
    main()

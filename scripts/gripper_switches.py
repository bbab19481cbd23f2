"""Short gripper switches in a policy's executed commands, and where in the action chunk they start.

Why (issue 27): the learned Cube Handoff policies lose Stage episodes by running out of time, most of them
slow to lift the cube or to hand it over. A closer look at the right gripper's executed command during the
lift found it opening for a few steps and closing again, over and over, each time at the first step of a new
action chunk. This counts those short runs per episode, for each gripper: a run of one level (open or closed,
the command snapped at 0.5; commands are in [0, 1], 1 = open) that lasts at most `--short` steps between two
runs of the other level. With `--chunk N` (the checkpoint's `n_action_steps`, read from its config by
default) it also gives each short run's start step modulo N: 0 is the first action of a chunk, the episode's
first chunk starting at step 0. The demonstrations hold each level for at least 121 steps between switches
(Cube Handoff, 400 Stage + 200 Random-time data), so a short run is never demonstrated.

    python scripts/gripper_switches.py \
        --policy checkpoints/afar_cube_handoff_mixs400r200sf_b2x_lr1e3_ftstage \
        --condition stage --seeds 1000-1039 --output outputs/gripper_switches/afar_ft_s1000.jsonl
    python scripts/gripper_switches.py --pool outputs/gripper_switches/afar_ft_s1000.jsonl

Seeds default to the validation seeds (1000+); test seeds (2000+) are for reporting only. `--pool` prints the
summary of logs written before (several files pool), without rolling anything out.
"""

from __future__ import annotations

import argparse
import json
from collections import Counter
from pathlib import Path

import numpy as np

GRIPPERS = ("left_gripper", "right_gripper")


def level_runs(levels: list[int]) -> list[tuple[int, int, int]]:
    """(level, start index, length) of each maximal run of equal values in `levels`."""
    runs: list[tuple[int, int, int]] = []
    for i, v in enumerate(levels):
        if runs and runs[-1][0] == v:
            level, start, length = runs[-1]
            runs[-1] = (level, start, length + 1)
        else:
            runs.append((v, i, 1))
    return runs


def short_runs(levels: list[int], short: int) -> list[tuple[int, int, int]]:
    """The interior runs (a run of the other level before and after) of at most `short` steps."""
    runs = level_runs(levels)
    return [r for r in runs[1:-1] if r[2] <= short]


def summarise(rows: list[dict], short: int, chunk: int | None) -> str:
    lines = []
    for outcome, keep in (("successes", True), ("failures", False)):
        chosen = [r for r in rows if r["success"] == keep]
        if not chosen:
            continue
        for name in GRIPPERS:
            counts = [len(r["short_runs"][name]) for r in chosen]
            starts = [start for r in chosen for _, start, _ in r["short_runs"][name]]
            phase = Counter(start % chunk for start in starts) if chunk else {}
            at_start = f", {phase.get(0, 0)} of {sum(counts)} start a chunk" if chunk else ""
            lines.append(f"{outcome} ({len(chosen)}), {name}: short runs (<= {short} steps) per episode "
                         f"mean {np.mean(counts):.1f}, median {np.median(counts):.0f}, episodes with any "
                         f"{sum(c > 0 for c in counts)}{at_start}")
    return "\n".join(lines)


def trace_episode(env, agent, seed: int, short: int, task: str, condition: str) -> dict:
    """One episode: the executed gripper commands snapped at 0.5, and their short runs (start = env step)."""
    from lerobot_bavo.eval.rollout import run_episode
    from lerobot_bavo.sim import constants as C

    dims = {name: C.ACTION_NAMES.index(name) for name in GRIPPERS}
    levels: dict[str, list[int]] = {name: [] for name in GRIPPERS}

    def log(obs, info, action):
        for name, d in dims.items():
            levels[name].append(int(float(action[d]) >= 0.5))  # 1 open, 0 closed

    record = run_episode(env, agent, seed, on_act=log)
    return {"task": task, "condition": condition, "seed": seed, "success": bool(record["success"]),
            "progress": int(record["progress"]), "steps": int(record["steps"]),
            "short_runs": {name: [list(r) for r in short_runs(v, short)] for name, v in levels.items()}}


def main() -> None:
    from lerobot_bavo.eval.run import read_episode_records, record_episodes

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--policy", help="a checkpoint folder (pretrained_model)")
    ap.add_argument("--task", default="cube_handoff")
    ap.add_argument("--condition", default="stage")
    ap.add_argument("--seeds", default="1000-1039", help="first-last (inclusive)")
    ap.add_argument("--short", type=int, default=6, help="a run of at most this many steps is short")
    ap.add_argument("--chunk", type=int, default=None,
                    help="executed actions per chunk; default: the checkpoint's n_action_steps")
    ap.add_argument("--output", type=Path, help="JSON-lines log, one episode per line")
    ap.add_argument("--pool", type=Path, nargs="+", help="summarise these logs instead of rolling out")
    args = ap.parse_args()
    if args.short < 1:
        ap.error(f"--short must be >= 1, not {args.short}")
    if args.pool:
        rows = [row for path in args.pool for row in read_episode_records(path)]
        print(summarise(rows, args.short, args.chunk))
        return
    if not args.policy:
        ap.error("--policy is required unless --pool is given")
    chunk = args.chunk
    if chunk is None:
        chunk = int(json.loads((Path(args.policy) / "config.json").read_text())["n_action_steps"])
    first, last = (int(s) for s in args.seeds.split("-"))

    from lerobot_bavo.envs.bavo_env import BavoEnv
    from lerobot_bavo.eval.rollout import env_kwargs_for_policy, make_agent

    env = BavoEnv(task=args.task, condition=args.condition, **env_kwargs_for_policy(args.policy))
    agent = make_agent(args.policy, env)
    try:
        rows = record_episodes(range(first, last + 1), lambda seed: trace_episode(
            env, agent, seed, args.short, args.task, args.condition), args.output)
    finally:
        env.close()
    print(summarise(rows, args.short, chunk))


if __name__ == "__main__":
    main()

"""What the arms do after Drawer Stowing's M3 when the block is never placed (issue 27, a probe, not a fix).

Why: under Stage the learned policies reach M3 (the left gripper touches the block) and most then stop there,
while in Clean most go on to place it (docs/results/first_grasp.md, "A larger model on Drawer Stowing"). The
camera regains the drawer front after the event that follows M3 as fast in the episodes that stop as in those
that go on, so the stall is in the arms. Three things could be behind it, and they leave different traces:
the arms *wait* (the scripted expert holds the arms while the camera recovers the view, so a policy can learn
a pause it never leaves), the grasp *slips* (the block is touched but never lifted, or dropped on the way), or
the block is *carried to the wrong place* (lifted, released outside the drawer's opening). This rolls out
seeded episodes and, from M3 on, logs the policy's left-arm command per step (its joint targets, rad), the
left fingers' contact with the block, the block's height above its resting height (cm), and where it ends up
against the drawer's opening (xy, world frame, cm outside it; 0 = above the opening).

    python scripts/stall_trace.py --policy outputs/train/<run>/checkpoints/004000/pretrained_model \
        [--condition stage] [--seeds 1000-1009] [--output trace.jsonl]

Drawer Stowing only; seeds default to the validation seeds (1000+); test seeds (2000+) are for reporting only.
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from lerobot_bavo.envs.bavo_env import BavoEnv
from lerobot_bavo.eval.rollout import (
    CommandLog,
    env_kwargs_for_policy,
    longest_run,
    make_agent,
    run_episode,
    target_hidden,
)
from lerobot_bavo.sim import constants as C

STILL = 1e-3  # rad per step: a left-arm command that moves less than this (max over joints) is "still"
LIFTED = 0.03  # m above the block's resting height: the block is off the table, carried


def outside_distance(xy: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> float:
    """Distance (m) from a point to an axis-aligned rectangle [lo, hi] in the plane; 0 inside it."""
    return float(np.linalg.norm(np.maximum(0.0, np.maximum(lo - xy, xy - hi))))


def summarise(steps: list[dict], commands: list[np.ndarray], rest_z: float) -> dict:
    """Per-episode numbers from M3 on (None where M3 is never reached)."""
    m3 = next((i for i, s in enumerate(steps) if s["progress"] >= 3), None)
    if m3 is None:
        return {"m3_step": None}
    after = steps[m3:]
    left_cmd = np.array([c[C.LEFT_ARM] for c in commands[m3:len(steps)]])
    moves = np.abs(np.diff(left_cmd, axis=0)).max(axis=1) if len(left_cmd) > 1 else np.zeros(0)
    lift = np.array([s["block_z"] - rest_z for s in after])
    last = after[-1]
    return {
        "m3_step": m3,
        "steps_after_m3": len(after),
        "touch_frac": round(float(np.mean([s["left_touch"] for s in after])), 3),
        "max_lift_cm": round(100 * float(lift.max()), 1),
        "lifted": bool(lift.max() > LIFTED),
        "still_frac": round(float(np.mean(moves < STILL)), 3) if len(moves) else None,
        "longest_still": longest_run(list(moves < STILL)),
        "mean_move_mrad": round(1000 * float(moves.mean()), 2) if len(moves) else None,
        "event_steps_after_m3": int(sum(s["occluded"] for s in after)),
        "end_outside_cm": round(100 * last["outside"], 1),
        "end_lift_cm": round(100 * (last["block_z"] - rest_z), 1),
        "end_slide_cm": round(100 * last["slide"], 1),
        "end_left_gripper": round(float(commands[len(steps) - 1][C.LEFT_GRIPPER]), 2),
    }


def step_record(env, info: dict) -> dict:
    """What `summarise` reads of one step (world frame, m): milestone progress, the left fingers' contact
    with the block (M3's test), the block's height, its distance outside the drawer's opening, the drawer's
    slide, and whether the target is hidden (V < 0.5) by an occlusion event."""
    base = env.unwrapped
    task = base.task
    lo, hi = task.interior_opening(base.data)
    block = base.data.xpos[task.block_body]
    return {
        "progress": info["progress"], "left_touch": task.evaluate(base.model, base.data)["m3"],
        "block_z": float(block[2]), "outside": outside_distance(block[:2], lo, hi),
        "slide": task.slide(base.data),
        "occluded": target_hidden(info),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--policy", required=True)
    ap.add_argument("--condition", default="stage", choices=["clean", "stage", "random"])
    ap.add_argument("--seeds", default="1000-1009", help="first-last (inclusive); validation seeds")
    ap.add_argument("--output", help="also write one JSON line per episode here")
    args = ap.parse_args()
    first, last = (int(s) for s in args.seeds.split("-"))
    env = BavoEnv(task="drawer_stowing", condition=args.condition, **env_kwargs_for_policy(args.policy))
    agent = CommandLog(make_agent(args.policy, env))
    base = env.unwrapped
    task = base.task
    steps: list[dict] = []

    def on_step(info):
        steps.append(step_record(env, info))

    rows = []
    if args.output:
        open(args.output, "w").close()  # one line per episode is appended as each ends
    for seed in range(first, last + 1):
        steps.clear()
        env.reset(seed=seed)
        rest_z = float(base.data.xpos[task.block_body][2])
        record = run_episode(env, agent, seed, on_step=on_step)
        row = {"seed": seed, "success": record["success"], "progress": record["progress"],
               **summarise(steps, agent.commands, rest_z)}
        rows.append(row)
        print(json.dumps(row), flush=True)
        if args.output:  # the per-step series too, for analyses beyond the summary
            left = np.array([c[C.LEFT_ARM] for c in agent.commands[:len(steps)]])
            moves = np.r_[0.0, np.abs(np.diff(left, axis=0)).max(axis=1)] if len(left) else np.zeros(0)
            series = {"left_move_mrad": [round(1000 * float(m), 1) for m in moves],
                      **{k: [s[k] for s in steps] for k in ("progress", "left_touch", "occluded")},
                      "block_lift_mm": [round(1000 * (s["block_z"] - rest_z), 1) for s in steps]}
            with open(args.output, "a") as out:
                out.write(json.dumps({**row, "series": series}) + "\n")
    env.close()
    stopped = [r for r in rows if r["m3_step"] is not None and r["progress"] == 3]
    print(f"{args.policy} drawer_stowing {args.condition} seeds {args.seeds}: {len(rows)} episodes, "
          f"{sum(r['success'] for r in rows)} successes, {len(stopped)} stop at M3; of those "
          f"{sum(r['lifted'] for r in stopped)} lift the block > {100 * LIFTED:.0f} cm, median still "
          f"fraction {np.median([r['still_frac'] for r in stopped]) if stopped else float('nan'):.2f}")


if __name__ == "__main__":
    main()

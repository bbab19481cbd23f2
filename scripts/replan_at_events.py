"""Does re-planning when an occluder appears help a learned policy under Random-time occlusion?

Why (issue 27): a policy executes 12 of its 16 predicted actions per call, so when a Random-time occluder
appears mid-chunk the arms and the camera run on for up to 11 more steps on a plan made with the old view.
The issue names "action chunks that run straight through an occlusion event" as a candidate cause of the
Random-time failures, to rule in or out. This rolls a checkpoint out on validation seeds three ways:

- ``none``: as `bavo-eval` does (the baseline);
- ``event``: the queued actions are dropped at the step an occlusion event starts, so the policy re-plans
  on the first observation that shows the new occluder. The event's timing comes from the env (privileged):
  this is a diagnostic, the most that re-planning at events can buy, not a deployable policy;
- ``cloud:F``: the same, triggered without privilege when more than a fraction F of the current cloud's
  points lie over `--new-radius` metres from every point of the previous step's cloud (a new surface came
  into view; the cloud is in the robot-base frame, so the camera's own motion moves few points).

Prints SR, TPS-like progress and event CVG per mode, and for ``cloud:F`` how many of its triggers came within
two steps of a real event (precision) and how many events it caught (recall). Rollouts default to validation
seeds (1000+); test seeds (2000+) are for reporting.

    python scripts/replan_at_events.py --policy checkpoints/afar_cube_handoff_sf --task cube_handoff \
        --condition random --seeds 1000-1019 --modes none,event,cloud:0.2
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np


def new_point_fraction(current: np.ndarray, previous: np.ndarray, radius: float) -> float:
    """Share of `current`'s points (N, >=3; xyz first) farther than `radius` from every point of `previous`
    (M, >=3). Pure; O(N M) with N, M a few hundred."""
    if len(current) == 0:
        return 0.0
    if len(previous) == 0:
        return 1.0
    d2 = ((current[:, None, :3] - previous[None, :, :3]) ** 2).sum(-1)
    return float((d2.min(axis=1) > radius * radius).mean())


def parse_mode(mode: str) -> tuple[str, float | None]:
    """'none' | 'event' | 'cloud:F' -> (kind, F)."""
    if mode in ("none", "event"):
        return mode, None
    kind, sep, value = mode.partition(":")
    if kind == "cloud" and sep:
        fraction = float(value)
        if not 0.0 < fraction < 1.0:
            raise ValueError(f"cloud:F wants 0 < F < 1, got {mode!r}")
        return kind, fraction
    raise ValueError(f"unknown mode {mode!r}: none, event or cloud:F")


def make_replanning_agent(policy: str, env, mode: str, new_radius: float):
    """A `LeRobotPolicyAgent` whose queued actions are dropped when `mode` says the view changed."""
    from lerobot_bavo.datasets.lerobot_private import policy_action_queue
    from lerobot_bavo.eval.rollout import LeRobotPolicyAgent
    from lerobot_bavo.features import ENV_POINT_CLOUD_KEY

    kind, fraction = parse_mode(mode)

    class ReplanningAgent(LeRobotPolicyAgent):
        def reset(self, seed=None):
            super().reset(seed)
            self.previous_cloud = None
            self.triggers: list[int] = []

        def act(self, obs, info):
            cloud = np.asarray(obs[ENV_POINT_CLOUD_KEY])
            step = int(info.get("elapsed_steps", 0))
            if kind == "event":
                occ = info.get("occlusion") or {}
                fire = step > 0 and bool(occ.get("event_started"))
            elif kind == "cloud":
                fire = (self.previous_cloud is not None
                        and new_point_fraction(cloud, self.previous_cloud, new_radius) > fraction)
            else:
                fire = False
            self.previous_cloud = cloud
            if fire:
                self.triggers.append(step)
                queue = policy_action_queue(self.policy)
                if queue is not None:
                    queue.clear()
            return super().act(obs, info)

    return ReplanningAgent(policy, env)


def rollout(policy: str, task: str, condition: str, seeds: range, mode: str, new_radius: float) -> list[dict]:
    from lerobot_bavo.envs.bavo_env import BavoEnv
    from lerobot_bavo.eval.rollout import env_kwargs_for_policy, run_episode

    env = BavoEnv(task=task, condition=condition, compute_cvg=True, **env_kwargs_for_policy(policy))
    agent = make_replanning_agent(policy, env, mode, new_radius)
    records = []
    try:
        for seed in seeds:
            record = run_episode(env, agent, seed)
            record["replan_steps"] = list(agent.triggers)
            records.append(record)
            print(json.dumps({"mode": mode, "seed": seed, "success": record["success"],
                              "progress": record["progress"], "replans": len(agent.triggers)}), flush=True)
    finally:
        env.close()
    return records


def trigger_agreement(records: list[dict], slack: int = 2) -> tuple[int, int, int, int]:
    """(triggers near an event, triggers, events caught, events after step 0) over the episodes."""
    near = total = caught = events = 0
    for r in records:
        starts = [p["step"] for p in r.get("placements", []) if p["step"] > 0]
        trig = r.get("replan_steps", [])
        total += len(trig)
        near += sum(any(abs(t - s) <= slack for s in starts) for t in trig)
        events += len(starts)
        caught += sum(any(abs(t - s) <= slack for t in trig) for s in starts)
    return near, total, caught, events


def summary(mode: str, records: list[dict]) -> str:
    n = len(records)
    wins = sum(r["success"] for r in records)
    progress = math.fsum(r["progress"] for r in records) / (5 * n) * 100 if n else 0.0
    cvgs = [e["cvg"] for r in records for e in r.get("events") or []
            if e["index"] > 0 and e["cvg"] is not None]
    cvg = f"{100 * math.fsum(cvgs) / len(cvgs):.1f}" if cvgs else "-"
    near, total, caught, events = trigger_agreement(records)
    return (f"| {mode} | {n} | {wins} | {progress:.1f} | {cvg} | {total} | {near} / {total} | "
            f"{caught} / {events} |")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--policy", required=True, help="a shipped checkpoint folder")
    ap.add_argument("--task", required=True)
    ap.add_argument("--condition", default="random")
    ap.add_argument("--seeds", default="1000-1019", help="first-last, inclusive (validation: 1000+)")
    ap.add_argument("--modes", default="none,event", help="comma-separated: none, event, cloud:F")
    ap.add_argument("--new-radius", type=float, default=0.02, help="metres, for cloud:F (default 0.02)")
    ap.add_argument("--output", type=Path, default=None, help="write every episode record here (jsonl)")
    args = ap.parse_args(argv)
    first, last = (int(s) for s in args.seeds.split("-"))
    modes = args.modes.split(",")
    for mode in modes:
        parse_mode(mode)  # a wrong mode fails before any rollout
    results = {}
    for mode in modes:
        results[mode] = rollout(args.policy, args.task, args.condition, range(first, last + 1), mode,
                                args.new_radius)
    if args.output is not None:
        args.output.parent.mkdir(parents=True, exist_ok=True)
        with args.output.open("w") as f:
            for mode, records in results.items():
                for r in records:
                    kept = {k: v for k, v in r.items() if k != "visibility"}
                    f.write(json.dumps({"mode": mode, **kept}) + "\n")
    print(f"\n{args.policy}, {args.task}, {args.condition}, seeds {args.seeds}")
    print("| mode | episodes | successes | progress (% of 5 milestones) | event CVG after step 0 (pp) | "
          "re-plans | re-plans within 2 steps of an event | events caught |")
    print("|---|---|---|---|---|---|---|---|")
    for mode, records in results.items():
        print(summary(mode, records))


if __name__ == "__main__":
    main()

"""How well a policy recovers the view at each Random-time occlusion event, by the event's order.

Why (issue 27): A-FAR and ManiFlow, trained on Stage demonstrations, fail most Random-time episodes. A Stage
episode has its occlusion at the start; a Random-time episode has one at step 0 and more during the
manipulation. This splits the event CVG (`lerobot_bavo.metrics.event_cvg`: how much of the target's visibility
the camera restores within H samples) and the episodes' progress by event index, from `bavo-eval`'s own
per-episode logs, so a policy that recovers the view only at the first event shows as such.

    python scripts/event_recovery.py outputs/eval/grid_table/runs/afar/s1000/cube_handoff/episodes.jsonl ...
    python scripts/event_recovery.py --label expert=<log> --label afar=<log> [--task cube_handoff]
    python scripts/event_recovery.py --policy checkpoints/afar_cube_handoff --task cube_handoff \
        --condition stage --seeds 1000-1009     # roll out, with CVG computed under any condition

bavo-eval computes CVG under Random-time only; `--policy` rolls the policy (or `expert`) out here with the
frozen-camera counterfactual on (`BavoEnv(compute_cvg=True)`), so the Stage events, which come at the task's
phase transitions, can be compared with the Random-time ones, which do not. Rollouts default to the
validation seeds (1000+); test seeds (2000+) are for reporting.

Prints, per log (its Random-time episodes) or rollout: episodes, successes, then per event index the number of
events reached, how many were retained (an event cut short by the episode's end has no CVG), the mean event
CVG (pp) and the mean start step.

`--regained CONDITION` reads the logs' episodes of that condition instead (e.g. `stage`, whose logs carry no
CVG) and prints, per event index and target, how many events were reached, in how many the camera regained
the view (the target's visibility V back to >= 0.5 before the next event or the episode's end) and the median
steps that took: a check that needs only bavo-eval's per-step `visibility`, under any condition.

    python scripts/event_recovery.py --regained stage --task drawer_stowing \
        --label expert=docs/results/grid_table/runs/expert/0/episodes.jsonl.gz \
        --label afar=docs/results/grid_table/runs/afar-self-filter/s1000/drawer_stowing/episodes.jsonl.gz
"""

from __future__ import annotations

import argparse
import math
import statistics
from collections import defaultdict
from pathlib import Path

from lerobot_bavo.eval.run import episode_log_path, labelled_episode_log, read_episode_records


def per_event_index(episodes: list[dict]) -> dict[int, dict]:
    """{event index: {"n", "retained", "cvg_pp" (mean over retained, or None), "start_step" (mean)}} over
    the given episodes' `events` (bavo-eval's records)."""
    cvgs: dict[int, list] = defaultdict(list)
    starts: dict[int, list] = defaultdict(list)
    for episode in episodes:
        for event in episode.get("events") or []:
            cvgs[event["index"]].append(event["cvg"])
            starts[event["index"]].append(event["start_step"])
    out = {}
    for index in sorted(cvgs):
        kept = [v for v in cvgs[index] if v is not None]
        out[index] = {"n": len(cvgs[index]), "retained": len(kept),
                      "cvg_pp": 100.0 * math.fsum(kept) / len(kept) if kept else None,
                      "start_step": math.fsum(starts[index]) / len(starts[index])}
    return out


def view_regained(episodes: list[dict], threshold: float = 0.5) -> dict[tuple[int, str], dict]:
    """{(event index, target): {"n", "regained", "median_steps" (None if never)}} over the episodes'
    `events` and per-step `visibility` (bavo-eval's records: `visibility[k]` is V after step k,
    `visibility[0]` at reset).
    An event is regained at the first step after its start, and before the next event's start (or the
    episode's end), whose V is at least `threshold`; steps count from the event's start step."""
    found: dict[tuple[int, str], list] = defaultdict(list)
    for episode in episodes:
        vis = episode.get("visibility") or []
        events = episode.get("events") or []
        for k, event in enumerate(events):
            start = event["start_step"]
            end = events[k + 1]["start_step"] if k + 1 < len(events) else len(vis)
            hit = next((t - start for t in range(start + 1, min(end, len(vis)))
                        if vis[t] is not None and vis[t] >= threshold), None)
            found[(event["index"], event["target"])].append(hit)
    out = {}
    for key in sorted(found):
        hits = [h for h in found[key] if h is not None]
        median = float(statistics.median(hits)) if hits else None
        out[key] = {"n": len(found[key]), "regained": len(hits), "median_steps": median}
    return out


def read_episodes(path: Path, task: str | None, condition: str = "random") -> list[dict]:
    rows = read_episode_records(path)
    return [r for r in rows if r.get("condition") == condition and (task is None or r.get("task") == task)]


def rollout_episodes(policy: str, task: str, condition: str, seeds: range) -> list[dict]:
    """Episode records (bavo-eval's rollout) of `policy` with event CVG computed under any condition."""
    from lerobot_bavo.envs.bavo_env import BavoEnv
    from lerobot_bavo.eval.rollout import env_kwargs_for_policy, make_agent, run_episode

    env = BavoEnv(task=task, condition=condition, compute_cvg=True, **env_kwargs_for_policy(policy))
    agent = make_agent(policy, env)
    try:
        return [run_episode(env, agent, seed) for seed in seeds]
    finally:
        env.close()


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("logs", nargs="*", type=episode_log_path, help="bavo-eval episodes.jsonl files")
    ap.add_argument("--label", action="append", default=[], metavar="NAME=episodes.jsonl",
                    type=labelled_episode_log)
    ap.add_argument("--task", default=None, help="only this task's episodes")
    ap.add_argument("--events", type=int, default=5, help="event indices to show (default 5)")
    ap.add_argument("--policy", default=None,
                    help="roll this checkpoint (or expert) out instead of reading logs")
    ap.add_argument("--condition", default="stage", help="with --policy (default stage)")
    ap.add_argument("--seeds", default="1000-1009", help="with --policy: first-last, inclusive")
    ap.add_argument("--regained", default=None, metavar="CONDITION",
                    help="read this condition's episodes and print whether and how fast each event's view "
                         "was regained (V >= 0.5) instead of CVG")
    args = ap.parse_args(argv)
    condition = args.regained or "random"
    logs: list[tuple[str, Path]] = [(str(p), p) for p in args.logs] + args.label
    named: list[tuple[str, list[dict]]] = [(name, read_episodes(path, args.task, condition))
                                           for name, path in logs]
    if args.policy is not None:
        if args.task is None:
            ap.error("--policy needs --task")
        first, last = (int(s) for s in args.seeds.split("-"))
        episodes = rollout_episodes(args.policy, args.task, args.condition, range(first, last + 1))
        named.append((f"{args.policy} ({args.condition}, seeds {args.seeds})", episodes))
    if not named:
        ap.error("give episodes.jsonl files or --policy")
    if args.regained:
        print_regained(named)
        return
    header = " | ".join(f"event {i}: n / kept / CVG / start" for i in range(args.events))
    print(f"| log | episodes | successes | {header} |")
    print("|---|---|---|" + "---|" * args.events)
    for name, episodes in named:
        stats = per_event_index(episodes)
        cells = []
        for i in range(args.events):
            s = stats.get(i)
            if s is None:
                cells.append("-")
                continue
            cvg = "-" if s["cvg_pp"] is None else f"{s['cvg_pp']:.1f}"
            cells.append(f"{s['n']} / {s['retained']} / {cvg} / {s['start_step']:.0f}")
        wins = sum(bool(e.get("success")) for e in episodes)
        print(f"| {name} | {len(episodes)} | {wins} | " + " | ".join(cells) + " |")


def print_regained(named: list[tuple[str, list[dict]]]) -> None:
    print("| log | episodes | successes | event (target) | reached | view regained | median steps |")
    print("|---|---|---|---|---|---|---|")
    for name, episodes in named:
        wins = sum(bool(e.get("success")) for e in episodes)
        for (index, target), s in view_regained(episodes).items():
            share = 100.0 * s["regained"] / s["n"]
            median = "-" if s["median_steps"] is None else f"{s['median_steps']:.0f}"
            print(f"| {name} | {len(episodes)} | {wins} | {index} ({target}) | {s['n']} | "
                  f"{s['regained']} ({share:.0f} %) | {median} |")


if __name__ == "__main__":
    main()

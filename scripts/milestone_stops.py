"""Where the episodes of `bavo-eval` runs stop: how many end at each milestone depth, and the share that
go on from each milestone to the next, per condition.

Why: SR says how often a policy finishes, not where it fails. The write-ups in docs/results/ compare recipes
by where their episodes stop (the first grasp, the handoff, the place) and by the step from one milestone
to the next (of the episodes that reach M2, the share that reach M3). Several logs under one label (one
per training seed) are pooled: their counts add up.

    python scripts/milestone_stops.py --task cube_handoff \\
        --label 4x=outputs/eval/test_cube_mix400_b4x_s1000/episodes.jsonl \\
        --label 4x=outputs/eval/test_cube_mix400_b4x_s1001/episodes.jsonl

`--first-trigger-split STEP` splits the episodes that have sampled triggers (Random-time) into those whose
first trigger comes before STEP and the rest: whether an occlusion event that falls before a milestone (on
Cube Handoff the first grasp, M1, near step 88) is where they stop.
"""

from __future__ import annotations

import argparse

from lerobot_bavo.eval.run import labelled_episode_log, read_episode_records
from lerobot_bavo.metrics import NUM_MILESTONES, milestone_depth_counts


def stops_by_depth(records: list[dict]) -> list[int]:
    """Episodes per final milestone depth, index 0..NUM_MILESTONES (the last is success)."""
    return milestone_depth_counts([r["progress"] for r in records])


def transition_rates(stops: list[int]) -> list[float | None]:
    """Of the episodes that reach milestone k (k = 0 is every episode), the fraction that reach k + 1;
    None where no episode reaches k. Milestones are ordered, so reaching k + 1 implies reaching k."""
    reached = [sum(stops[k:]) for k in range(len(stops))]
    return [reached[k + 1] / reached[k] if reached[k] else None for k in range(len(stops) - 1)]


def condition_group(record: dict, split_step: int | None) -> str:
    """The row an episode counts in: its condition, and for an episode with sampled triggers (Random-time)
    with `split_step` given, whether its first trigger step is before `split_step` or not."""
    triggers = record.get("triggers") or []
    if split_step is None or not triggers:
        return record["condition"]
    side = "<" if triggers[0] < split_step else ">="
    return f"{record['condition']}, first trigger {side} {split_step}"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--label", action="append", required=True, metavar="NAME=episodes.jsonl",
                        type=labelled_episode_log,
                        help="a label and one episode log (.jsonl or .jsonl.gz); repeat a label to pool logs")
    parser.add_argument("--task", help="only this task's episodes (default: all)")
    parser.add_argument("--first-trigger-split", type=int, metavar="STEP",
                        help="split Random-time episodes by whether their first sampled trigger step is "
                             "before STEP (env steps)")
    args = parser.parse_args(argv)
    pooled: dict[str, list[dict]] = {}
    for name, path in args.label:
        records = [r for r in read_episode_records(path) if args.task in (None, r["task"])]
        pooled.setdefault(name, []).extend(records)
    depths = " / ".join(f"M{k}" for k in range(NUM_MILESTONES)) + " / success"
    steps = " | ".join(f"M{k}->M{k + 1}" for k in range(NUM_MILESTONES))
    print(f"| label | condition | episodes | stops {depths} | {steps} |")
    print("|---|---|---|---|" + "---|" * NUM_MILESTONES)
    for name, records in pooled.items():
        groups = [condition_group(r, args.first_trigger_split) for r in records]
        for condition in sorted(set(groups)):
            stops = stops_by_depth([r for r, g in zip(records, groups) if g == condition])
            rates = " | ".join("-" if x is None else f"{100 * x:.0f} %" for x in transition_rates(stops))
            print(f"| {name} | {condition} | {sum(stops)} | {' / '.join(map(str, stops))} | {rates} |")


if __name__ == "__main__":
    main()

"""Where the episodes of `bavo-eval` runs stop: how many end at each milestone depth, and the share that
go on from each milestone to the next, per condition.

Why: SR says how often a policy finishes, not where it fails. The write-ups in docs/results/ compare recipes
by where their episodes stop (the first grasp, the handoff, the place) and by the step from one milestone
to the next (of the episodes that reach M2, the share that reach M3). Several logs under one label (one
per training seed) are pooled: their counts add up.

    python scripts/milestone_stops.py --task cube_handoff \\
        --label 4x=outputs/eval/test_cube_mix400_b4x_s1000/episodes.jsonl \\
        --label 4x=outputs/eval/test_cube_mix400_b4x_s1001/episodes.jsonl
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


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--label", action="append", required=True, metavar="NAME=episodes.jsonl",
                        type=labelled_episode_log,
                        help="a label and one episode log (.jsonl or .jsonl.gz); repeat a label to pool logs")
    parser.add_argument("--task", help="only this task's episodes (default: all)")
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
        for condition in sorted({r["condition"] for r in records}):
            stops = stops_by_depth([r for r in records if r["condition"] == condition])
            rates = " | ".join("-" if x is None else f"{100 * x:.0f} %" for x in transition_rates(stops))
            print(f"| {name} | {condition} | {sum(stops)} | {' / '.join(map(str, stops))} | {rates} |")


if __name__ == "__main__":
    main()

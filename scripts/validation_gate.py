"""The Cube Handoff plans' validation gate (docs/results/learning_rate.md): a checkpoint's successes
on the validation seeds 1000-1039 (Clean, Stage, Random-time) and Stage on 1040-1119, read against the plan's
minimums.
Only validation seeds: the test seeds 2000-2039 never choose anything.

    python scripts/validation_gate.py outputs/eval/val_<name>/episodes.jsonl \
        outputs/eval/val2_<name>/episodes.jsonl --label gate_budget --clean-min 20 --random-min 10 \
        --stage-min 78
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from lerobot_bavo.eval.run import condition_successes as successes
from lerobot_bavo.eval.run import read_episode_records


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("first", type=Path, help="episode log of the run on validation seeds 1000-1039")
    parser.add_argument("more", type=Path, help="episode log of the Stage run on validation seeds 1040-1119")
    parser.add_argument("--stage-min", type=int, default=78, help="Stage successes of the 120 that pass (78)")
    parser.add_argument("--clean-min", type=int, default=None, help="Clean successes of 40 that pass (none)")
    parser.add_argument("--random-min", type=int, default=None, help="Random-time successes of 40 (none)")
    parser.add_argument("--label", default="validation_gate", help="the printed line's prefix")
    args = parser.parse_args(argv)
    first, more = read_episode_records(args.first), read_episode_records(args.more)
    minimums = {"clean": args.clean_min, "random": args.random_min}
    wanted = ["stage"] + [c for c, m in minimums.items() if m is not None]
    n = {c: successes(first, c) for c in wanted}
    more_stage = successes(more, "stage")
    if any(n[c][1] != 40 for c in wanted) or more_stage[1] != 80 or len(more) != 80:
        found = ", ".join(f"{c} {n[c][1]}" for c in wanted)
        sys.exit(f"expected 40 episodes per condition ({', '.join(wanted)}) in {args.first} and 80 Stage "
                 f"episodes in {args.more}; found {found} and {len(more)}")
    stage = n["stage"][0] + more_stage[0]
    passed = stage >= args.stage_min and all(n[c][0] >= m for c, m in minimums.items() if m is not None)
    named = {"clean": "Clean", "random": "Random-time"}
    parts = [f"{named[c]} {n[c][0]} / 40 (>= {minimums[c]})" for c in ("clean", "random") if c in n]
    print(f"[{args.label}] validation: {', '.join(parts + [''])}Stage {n['stage'][0]} / 40 and {stage} / 120 "
          f"with 1040-1119 (>= {args.stage_min}) -> {'passed' if passed else 'not passed'}")


if __name__ == "__main__":
    main()

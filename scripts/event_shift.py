"""How two collections of the same seeds differ in when their occlusion events start (issue 27, a data probe).

Why: `bavo-collect --events-outside-contacts` holds an event that falls due in one of the expert's contact
phases until the phase is over. Collected from the same seeds as a plain collection, the two share their
trigger schedules, so comparing each seed's event-start frames says how many events were held, for how long,
and how many merged with the next (docs/results/random_time.md).

    python scripts/event_shift.py --plain outputs/datasets/bavo_cube_handoff_dartsf512_random \\
        --held outputs/datasets/bavo_cube_handoff_dartsf512_randomoc
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

COLUMNS = ["annotation.event_start", "annotation.episode_seed", "frame_index"]


def event_starts(root: Path) -> dict[int, list[int]]:
    """Episode seed -> the frames (control steps) at which an occlusion event started, the reset's (0)
    included."""
    from lerobot_bavo.datasets.lerobot_format import read_frame_columns

    try:
        table = read_frame_columns(root, COLUMNS).to_pandas()
    except FileNotFoundError as e:
        raise SystemExit(f"{root}: {e} (a LeRobot dataset folder is expected)") from None
    starts: dict[int, list[int]] = {}
    for seed, episode in table.groupby("annotation.episode_seed"):
        started = episode["annotation.event_start"].to_numpy() > 0
        starts[int(seed)] = episode["frame_index"].to_numpy()[started].tolist()
    return starts


def compare(plain: list[int], held: list[int]) -> dict:
    """One seed's plain and held event starts (frames, increasing, 0 first). An event of the plain collection
    after reset counts as held when the held collection has no event at its frame; its delay is the gap to the
    held collection's next event start (None when there is none). `merged`: how many fewer events the held
    collection has."""
    at = set(held)
    delays: list[int | None] = []
    for frame in plain[1:]:
        if frame in at:
            continue
        later = [f for f in held if f > frame]
        delays.append(later[0] - frame if later else None)
    return {"events": len(plain) - 1, "held": len(delays), "delays": delays,
            "merged": max(0, len(plain) - len(held))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--plain", type=Path, required=True, help="the collection without the hold")
    ap.add_argument("--held", type=Path, required=True, help="the same seeds with --events-outside-contacts")
    args = ap.parse_args()
    plain, held = event_starts(args.plain), event_starts(args.held)
    seeds = sorted(set(plain) & set(held))
    rows = [compare(plain[s], held[s]) for s in seeds]
    events = sum(r["events"] for r in rows)
    n_held = sum(r["held"] for r in rows)
    delays = [d for r in rows for d in r["delays"] if d is not None]
    median = np.median(delays) if delays else "n/a"
    longest = max(delays) if delays else "n/a"
    print(f"seeds kept by both: {len(seeds)} (plain {len(plain)}, held {len(held)}); "
          f"events after reset {events}, held {n_held} ({n_held / max(events, 1):.1%}), "
          f"delay median {median} max {longest} steps, merged {sum(r['merged'] for r in rows)}")


if __name__ == "__main__":
    main()

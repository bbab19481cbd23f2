"""The command levels a dataset's binary action dimensions hold, for `--policy.binary_action_levels`.

Why: ManiFlow and A-FAR snap their sampled gripper commands to a few levels at inference
(`ManiFlowConfig.binary_action_dims`, `binary_action_levels`), by default the two ends of the range (closed,
open). An expert that holds a gripper part-open needs that level too: Drawer Stowing's straddles the handle
bar and lets go of it at 0.45 and releases the block at 0.7, and with two levels the 0.45 release is executed
as "closed". The levels are read from the demonstrations, not written per task: a level is a value the
command *holds* (runs of at least `min_run` equal frames, `min_share` of all frames or more), so the
one-frame values of a ramp between levels are not levels.

    python -m lerobot_bavo.datasets.action_levels --root outputs/datasets/bavo_drawer_stowing_dart_points
    # -> [-1.0,-0.1,0.4,1.0]   (MIN_MAX-normalised: a command g in [0, 1] is 2 g - 1)
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def held_levels(values: np.ndarray, episode_index: np.ndarray, min_run: int = 5, min_share: float = 0.02,
                decimals: int = 3) -> list[float]:
    """Values of one action dimension held for runs of >= `min_run` equal frames (after rounding to
    `decimals`; runs do not cross episodes), kept when such runs cover >= `min_share` of all frames.
    Sorted."""
    v = np.round(np.asarray(values, dtype=np.float64), decimals)
    ep = np.asarray(episode_index)
    if v.ndim != 1 or v.shape != ep.shape:
        raise ValueError(f"values and episode_index must be equal-length 1-D arrays; got {v.shape}, "
                         f"{ep.shape}")
    if len(v) == 0:
        return []
    starts = np.flatnonzero(np.r_[True, (v[1:] != v[:-1]) | (ep[1:] != ep[:-1])])
    lengths = np.diff(np.r_[starts, len(v)])
    held: dict[float, int] = {}
    for start, length in zip(starts, lengths, strict=True):
        if length >= min_run:
            held[float(v[start])] = held.get(float(v[start]), 0) + int(length)
    return sorted(level for level, frames in held.items() if frames >= min_share * len(v))


def normalised_levels(levels_per_dim: dict[int, list[float]], low: np.ndarray, high: np.ndarray,
                      decimals: int = 4) -> list[float]:
    """The union over dimensions of their held levels in MIN_MAX units (2 (x - low) / (high - low) - 1), with
    the range's ends (-1, +1) always in: what `--policy.binary_action_levels` takes. A dimension that is
    constant in the data adds nothing (it has no range to place a level in)."""
    out = {-1.0, 1.0}
    for dim, levels in levels_per_dim.items():
        span = float(high[dim]) - float(low[dim])
        if span <= 0:
            continue
        out.update(round(2.0 * (x - float(low[dim])) / span - 1.0, decimals) for x in levels)
    return sorted(min(1.0, max(-1.0, x)) for x in out)


def dataset_binary_action_levels(root: Path, dims: tuple[int, ...] | None = None) -> list[float]:
    """`normalised_levels` of the dataset at `root` (a LeRobot v3 folder; its `meta/stats.json` min / max, as
    the policy's MIN_MAX normaliser), for `dims` (default: BAVO's gripper commands)."""
    from lerobot_bavo.datasets.fast import column_array
    from lerobot_bavo.datasets.lerobot_format import read_frame_columns
    from lerobot_bavo.sim.constants import GRIPPER_INDICES

    dims = tuple(GRIPPER_INDICES if dims is None else dims)
    root = Path(root)
    stats = json.loads((root / "meta" / "stats.json").read_text())["action"]
    table = read_frame_columns(root, ["action", "episode_index"])
    action, episode = column_array(table.column("action")), column_array(table.column("episode_index"))
    per_dim = {d: held_levels(action[:, d], episode) for d in dims}
    return normalised_levels(per_dim, np.asarray(stats["min"]), np.asarray(stats["max"]))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--root", type=Path, required=True, help="a LeRobot dataset folder (a training view)")
    parser.add_argument("--dims", type=int, nargs="*", default=None,
                        help="action dimensions (default: BAVO's gripper commands, 6 and 13)")
    args = parser.parse_args(argv)
    try:
        levels = dataset_binary_action_levels(args.root, None if args.dims is None else tuple(args.dims))
    except (FileNotFoundError, ValueError, KeyError) as e:
        raise SystemExit(f"lerobot_bavo.datasets.action_levels: {args.root}: {e}") from None
    print("[" + ",".join(repr(x) for x in levels) + "]")


if __name__ == "__main__":
    main()

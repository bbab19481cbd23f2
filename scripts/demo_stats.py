"""What the demonstrations of a training view do, per group of episodes (issue 27, a probe of the data).

Why: adding Random-time demonstrations to Cube Handoff's Stage ones teaches the camera to restore the view
mid-episode but costs Stage SR, and the policies then stop more often at the right arm's lift and the
handoff (docs/results/random_time.md). One explanation would be behaviour that only the Random-time
demonstrations contain, such as the expert re-grasping after an event. This counts, per episode and then per
group of episodes (e.g. a joined view's Stage part and its Random-time part):

- gripper switches per arm: how often the commanded gripper crosses the midpoint between its lowest and
  highest level (one grasp and one release = 2; a re-grasp adds 2);
- the share of steps where both arms' commanded joints (12 joints, rad) move less than `--still` (the arms
  held while the camera moves);
- frames the teacher marks as recovering the view (`observation.teacher.recovering`), and episode length.

    python scripts/demo_stats.py --root outputs/datasets/bavo_cube_handoff_mixsr200sf_points \
        --group stage=0-99 --group random=100-199
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from lerobot_bavo.sim import constants as C

COLUMNS = ["action", "episode_index", "observation.teacher.recovering"]


def gripper_switches(levels: np.ndarray) -> int:
    """How often a gripper command series crosses the midpoint of its range (0 for a constant series)."""
    lo, hi = float(levels.min()), float(levels.max())
    if hi - lo < 1e-6:
        return 0
    closed = levels > (lo + hi) / 2
    return int(np.count_nonzero(closed[1:] != closed[:-1]))


def still_share(arm_commands: np.ndarray, still: float) -> float:
    """Share of steps whose largest joint change (rad) over `arm_commands` (T x joints) is below `still`."""
    if len(arm_commands) < 2:
        return 0.0
    moves = np.abs(np.diff(arm_commands, axis=0)).max(axis=1)
    return float(np.mean(moves < still))


def episode_stats(actions: np.ndarray, recovering: np.ndarray, still: float) -> dict:
    arms = np.r_[C.LEFT_ARM, C.RIGHT_ARM]
    return {
        "frames": len(actions),
        "left_switches": gripper_switches(actions[:, C.LEFT_GRIPPER]),
        "right_switches": gripper_switches(actions[:, C.RIGHT_GRIPPER]),
        "arms_still": still_share(actions[:, arms], still),
        "recovering": int(np.count_nonzero(recovering > 0.5)),
    }


def read_view(root: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    from lerobot_bavo.datasets.lerobot_format import read_frame_columns

    try:
        table = read_frame_columns(root, COLUMNS)
    except FileNotFoundError as e:
        raise SystemExit(f"{root}: {e} (a LeRobot v3 view is expected)") from None
    actions = np.stack(table["action"].to_numpy(zero_copy_only=False)).astype(np.float64)
    episodes = table["episode_index"].to_numpy()
    recovering = np.array([np.asarray(r).reshape(-1)[0] for r in table[COLUMNS[2]].to_pylist()], float)
    return actions, episodes, recovering


def parse_group(text: str) -> tuple[str, range]:
    try:
        name, span = text.split("=")
        first, last = (int(s) for s in span.split("-"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--group wants NAME=FIRST-LAST, not {text!r}") from None
    return name, range(first, last + 1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--root", type=Path, required=True, help="a training view (LeRobot v3 folder)")
    ap.add_argument("--group", type=parse_group, action="append", required=True,
                    help="NAME=FIRST-LAST episode indices; repeat")
    ap.add_argument("--still", type=float, default=1e-3, help="rad per step below which the arms are still")
    args = ap.parse_args()
    actions, episodes, recovering = read_view(args.root)
    for name, span in args.group:
        rows = [episode_stats(actions[episodes == e], recovering[episodes == e], args.still)
                for e in span if np.any(episodes == e)]
        if not rows:
            raise SystemExit(f"group {name}: none of episodes {span.start}-{span.stop - 1} is in {args.root}")
        mean = {k: float(np.mean([r[k] for r in rows])) for k in rows[0]}
        switch_counts = sorted({(r["left_switches"], r["right_switches"]) for r in rows})
        frames = [r["frames"] for r in rows]
        print(f"{name}: {len(rows)} episodes, frames {mean['frames']:.0f} (min {min(frames)}, "
              f"max {max(frames)}), gripper switches left/right {switch_counts} "
              f"(mean {mean['left_switches']:.2f} / {mean['right_switches']:.2f}), arms still "
              f"{100 * mean['arms_still']:.1f} % of steps, recovering frames {mean['recovering']:.0f}")


if __name__ == "__main__":
    main()

"""The `--policy.relative_action_dims` / `--policy.relative_action_scales` flags for a dataset.

Why: a policy that predicts its chunk relative to the current state (`lerobot_bavo.policies.relative`)
divides each step a_n[t + k] - s_n[t] (MIN_MAX units, the dataset's own action and state statistics) by a
scale that makes it about unit-sized, as the absolute targets are. The scale is read from the training data,
not chosen per task: the 0.99 quantile of |a_n[t + k] - s_n[t]| over every frame t and every offset k of the
chunk the policy predicts (k = 1 - n_obs_steps ... horizon - n_obs_steps: ManiFlow's chunk starts at the
oldest observation step). The dimensions default to BAVO's arm and camera-arm joints; the two gripper commands
stay absolute (a command against a finger position is no step).

    python -m lerobot_bavo.datasets.relative_actions \
        --root outputs/datasets/bavo_drawer_stowing_dartsf512_points
    # -> --policy.relative_action_dims=[0,1,...] --policy.relative_action_scales=[0.31,...]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def chunk_offsets(action_n: np.ndarray, state_n: np.ndarray, episode: np.ndarray, first: int,
                  horizon: int) -> np.ndarray:
    """|a_n[t + k] - s_n[t]| for every frame t and every chunk offset k = first ... first + horizon - 1,
    (frames * horizon, D): the residuals a policy trained on these frames predicts. Frames beyond an
    episode's ends take its first / last action, as LeRobot's chunk padding does (`action_is_pad`)."""
    action_n, state_n, episode = np.asarray(action_n), np.asarray(state_n), np.asarray(episode)
    if action_n.ndim != 2 or action_n.shape != state_n.shape or episode.shape != action_n.shape[:1]:
        raise ValueError(f"action {action_n.shape}, state {state_n.shape} and episode {episode.shape} "
                         "must be (T, D), (T, D) and (T,)")
    if horizon < 1:
        raise ValueError(f"horizon must be >= 1. Got {horizon}.")
    out = []
    for e in np.unique(episode):
        idx = np.flatnonzero(episode == e)
        a, s, n = action_n[idx], state_n[idx], len(idx)
        for k in range(first, first + horizon):
            j = np.clip(np.arange(n) + k, 0, n - 1)
            out.append(np.abs(a[j] - s))
    return np.concatenate(out) if out else np.zeros((0, action_n.shape[1]))


def relative_action_scales(action_n: np.ndarray, state_n: np.ndarray, episode: np.ndarray,
                           dims: tuple[int, ...], first: int, horizon: int, quantile: float = 0.99,
                           floor: float = 1e-3) -> list[float]:
    """Per dimension of `dims`, the `quantile` of |a_n[t + k] - s_n[t]| over the data's frames and chunk
    offsets (`chunk_offsets`), at least `floor` (a joint that never moves gets a finite scale)."""
    if not 0.0 < quantile <= 1.0:
        raise ValueError(f"quantile must be in (0, 1]. Got {quantile}.")
    if not dims:
        return []
    d = list(dims)
    offsets = chunk_offsets(np.asarray(action_n)[:, d], np.asarray(state_n)[:, d], episode, first, horizon)
    if len(offsets) == 0:
        raise ValueError("no frames to compute relative action scales from")
    q = np.quantile(offsets, quantile, axis=0)
    return [round(max(float(v), floor), 4) for v in q]


def minmax_normalised(x: np.ndarray, stats: dict) -> np.ndarray:
    """LeRobot's MIN_MAX normalisation, 2 (x - min) / (max - min) - 1, with its epsilon for a constant
    dimension."""
    low, high = np.asarray(stats["min"], dtype=np.float64), np.asarray(stats["max"], dtype=np.float64)
    return 2.0 * (np.asarray(x, dtype=np.float64) - low) / np.maximum(high - low, 1e-8) - 1.0


def default_relative_dims(action_dim: int) -> tuple[int, ...]:
    """BAVO's joints: every action dimension but the two gripper commands."""
    from lerobot_bavo.sim.constants import ACTION_DIM, GRIPPER_INDICES

    if action_dim != ACTION_DIM:
        raise ValueError(f"the action has {action_dim} dimensions, not BAVO's {ACTION_DIM}: name the joints "
                         "with --dims")
    return tuple(d for d in range(action_dim) if d not in GRIPPER_INDICES)


def dataset_relative_flags(root: Path, dims: tuple[int, ...] | None = None, n_obs_steps: int = 2,
                           horizon: int = 16, quantile: float = 0.99) -> tuple[tuple[int, ...], list[float]]:
    """(dims, scales) for the dataset at `root` (a LeRobot v3 folder: `meta/stats.json` and its frames)."""
    from lerobot_bavo.datasets.fast import column_array
    from lerobot_bavo.datasets.lerobot_format import read_frame_columns

    if n_obs_steps < 1:
        raise ValueError(f"n_obs_steps must be >= 1. Got {n_obs_steps}.")
    root = Path(root)
    stats = json.loads((root / "meta" / "stats.json").read_text())
    table = read_frame_columns(root, ["action", "observation.state", "episode_index"])
    action = column_array(table.column("action"))
    state = column_array(table.column("observation.state"))
    dims = default_relative_dims(action.shape[1]) if dims is None else tuple(dims)
    if any(not 0 <= d < min(action.shape[1], state.shape[1]) for d in dims):
        raise ValueError(f"dims {list(dims)} must index both the {action.shape[1]}-dim action and the "
                         f"{state.shape[1]}-dim state")
    scales = relative_action_scales(minmax_normalised(action, stats["action"]),
                                    minmax_normalised(state, stats["observation.state"]),
                                    column_array(table.column("episode_index")), dims, first=1 - n_obs_steps,
                                    horizon=horizon, quantile=quantile)
    return dims, scales


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--root", type=Path, required=True, help="a LeRobot dataset folder (a training view)")
    parser.add_argument("--dims", type=int, nargs="*", default=None,
                        help="action dimensions made relative (default: BAVO's joints, all but 6 and 13)")
    parser.add_argument("--n-obs-steps", type=int, default=2, help="the policy's n_obs_steps (default 2)")
    parser.add_argument("--horizon", type=int, default=16, help="the policy's horizon (default 16)")
    parser.add_argument("--quantile", type=float, default=0.99,
                        help="quantile of |a_n - s_n| taken as each dimension's scale (default 0.99)")
    args = parser.parse_args(argv)
    try:
        dims, scales = dataset_relative_flags(args.root, None if args.dims is None else tuple(args.dims),
                                              args.n_obs_steps, args.horizon, args.quantile)
    except (FileNotFoundError, ValueError, KeyError) as e:
        raise SystemExit(f"lerobot_bavo.datasets.relative_actions: {args.root}: {e}") from None
    print(f"--policy.relative_action_dims=[{','.join(map(str, dims))}] "
          f"--policy.relative_action_scales=[{','.join(repr(v) for v in scales)}]")


if __name__ == "__main__":
    main()

"""Occlusion conditions: intervention schedules (and, later, occluder placement). Appendix A.

Import-light (numpy only). Every random draw takes an explicit ``np.random.Generator`` so that a
seeded ``reset`` reproduces the schedule.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "RANDOM_TRIGGER_WINDOWS",
    "MIN_TRIGGER_GAP",
    "sample_random_triggers",
]

# --- schedules ---

# Random-time Occlusion (Appendix A): besides the occlusion at reset, one trigger step per window,
# bounds inclusive, in control steps.
RANDOM_TRIGGER_WINDOWS: tuple[tuple[int, int], ...] = (
    (60, 130),
    (130, 200),
    (200, 270),
    (270, 340),
    (340, 410),
    (410, 480),
)
# Consecutive triggers are separated by MORE than this many steps (t_k - t_{k-1} > MIN_TRIGGER_GAP),
# so the H = 60 CVG windows of consecutive events never overlap.
MIN_TRIGGER_GAP = 60
_BATCH = 256  # candidate schedules drawn per round of rejection sampling
_MAX_ROUNDS = 400


def sample_random_triggers(
    rng: np.random.Generator,
    windows: tuple[tuple[int, int], ...] = RANDOM_TRIGGER_WINDOWS,
    min_gap: int = MIN_TRIGGER_GAP,
) -> list[int]:
    """Sample the Random-time trigger steps: one per window, consecutive gaps > min_gap.

    Distribution: uniform over all feasible schedules, i.e. one integer drawn uniformly from each
    window independently, conditioned on every consecutive gap exceeding `min_gap` (rejection
    sampling). This is the plain reading of App. A ("one trigger step is sampled ... from each of
    six windows, subject to consecutive triggers being separated by more than 60 steps") and,
    unlike sampling window by window, it does not push later triggers towards the ends of their
    windows (exact means with the defaults: about 77, 155, 232, 308, 385, 463). About 2% of
    independent draws are feasible with the defaults, so candidates are drawn in batches.
    The occlusion at reset (step 0) is not a sampled trigger and is not part of the gap rule.

    Args:
        rng: the episode's generator; the result is a deterministic function of its state.
        windows: (lo, hi) integer bounds, inclusive, in time order.
        min_gap: consecutive triggers satisfy t_k - t_{k-1} > min_gap.

    Returns:
        len(windows) increasing trigger steps.

    Raises:
        ValueError: for an empty window, or when no feasible schedule is found (windows that are
            infeasible or nearly so).
    """
    for lo, hi in windows:
        if lo > hi:
            raise ValueError(f"empty trigger window ({lo}, {hi})")
    lows = np.array([lo for lo, _ in windows])
    highs = np.array([hi for _, hi in windows])
    for _ in range(_MAX_ROUNDS):
        candidates = rng.integers(lows, highs, size=(_BATCH, len(windows)), endpoint=True)
        ok = np.all(np.diff(candidates, axis=1) > min_gap, axis=1)
        if ok.any():
            return [int(t) for t in candidates[np.argmax(ok)]]
    raise ValueError(
        f"could not sample triggers in windows {windows} with gaps > {min_gap} after "
        f"{_MAX_ROUNDS * _BATCH} candidates; the windows are (nearly) infeasible"
    )

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
_MAX_SCHEDULE_TRIES = 100


def sample_random_triggers(
    rng: np.random.Generator,
    windows: tuple[tuple[int, int], ...] = RANDOM_TRIGGER_WINDOWS,
    min_gap: int = MIN_TRIGGER_GAP,
) -> list[int]:
    """Sample the Random-time trigger steps: one per window, consecutive gaps > min_gap.

    Distribution: sequential. The first trigger is uniform on its window [lo_1, hi_1]; trigger k is
    uniform on the integers of the feasible part of window k given trigger k-1,
    [max(lo_k, t_{k-1} + min_gap + 1), hi_k]. This is not uniform over the joint feasible set: a
    late t_{k-1} cuts window k from below, so later triggers drift towards the ends of their
    windows (exact means with the defaults: 95, 178, 255, 328, 399, 470; about 57% of the last
    triggers fall in [471, 480]). The occlusion at reset (step 0) is not a sampled trigger and is
    not part of the gap constraint.

    With the default windows the feasible part is never empty (t_{k-1} <= hi_{k-1} = lo_k, and
    lo_k + 61 <= hi_k). For other windows, if it is empty the whole schedule is resampled with the
    same rng, up to a bounded number of tries, and then a ValueError is raised.

    Args:
        rng: the episode's generator; the result is a deterministic function of its state.
        windows: (lo, hi) integer bounds, inclusive, in time order.
        min_gap: consecutive triggers satisfy t_k - t_{k-1} > min_gap.

    Returns:
        len(windows) increasing trigger steps.
    """
    for lo, hi in windows:
        if lo > hi:
            raise ValueError(f"empty trigger window ({lo}, {hi})")
    for _ in range(_MAX_SCHEDULE_TRIES):
        triggers: list[int] = []
        for lo, hi in windows:
            low = lo if not triggers else max(lo, triggers[-1] + min_gap + 1)
            if low > hi:
                break  # infeasible given the earlier draws: resample the schedule
            triggers.append(int(rng.integers(low, hi, endpoint=True)))
        else:
            return triggers
    raise ValueError(
        f"could not sample triggers in windows {windows} with gaps > {min_gap} "
        f"after {_MAX_SCHEDULE_TRIES} tries; the windows are (nearly) infeasible"
    )

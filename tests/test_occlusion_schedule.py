"""Random-time Occlusion trigger schedule (Appendix A)."""

from __future__ import annotations

import numpy as np
import pytest

from lerobot_bavo.envs.occlusion import MIN_TRIGGER_GAP, RANDOM_TRIGGER_WINDOWS, sample_random_triggers

N_SEEDS = 2000


@pytest.fixture(scope="module")
def schedules() -> np.ndarray:
    return np.array([sample_random_triggers(np.random.default_rng(seed)) for seed in range(N_SEEDS)])


def test_constants_match_paper():
    assert RANDOM_TRIGGER_WINDOWS == ((60, 130), (130, 200), (200, 270), (270, 340), (340, 410), (410, 480))
    assert MIN_TRIGGER_GAP == 60


def test_triggers_in_windows_with_gaps(schedules):
    assert schedules.shape == (N_SEEDS, 6)
    assert np.issubdtype(schedules.dtype, np.integer)
    for k, (lo, hi) in enumerate(RANDOM_TRIGGER_WINDOWS):
        assert (schedules[:, k] >= lo).all() and (schedules[:, k] <= hi).all()
    assert (np.diff(schedules, axis=1) > MIN_TRIGGER_GAP).all()


def test_deterministic_per_seed_and_varies_across_seeds(schedules):
    for seed in (0, 1, 123, 1999):
        assert sample_random_triggers(np.random.default_rng(seed)) == schedules[seed].tolist()
    assert len({tuple(s) for s in schedules.tolist()}) > N_SEEDS // 2
    assert (schedules[0] != schedules[1]).any()


def _exact_uniform_marginals(windows, min_gap):
    """P(t_k = t) under the uniform distribution over feasible schedules, by counting paths."""
    n = len(windows)
    ranges = [range(lo, hi + 1) for lo, hi in windows]
    fwd = [dict.fromkeys(ranges[0], 1)]  # number of feasible prefixes ending at t
    for k in range(1, n):
        fwd.append({t: sum(c for p, c in fwd[-1].items() if t - p > min_gap) for t in ranges[k]})
    bwd = [None] * n  # number of feasible suffixes starting at t
    bwd[-1] = dict.fromkeys(ranges[-1], 1)
    for k in range(n - 2, -1, -1):
        bwd[k] = {t: sum(c for q, c in bwd[k + 1].items() if q - t > min_gap) for t in ranges[k]}
    total = sum(fwd[-1].values())
    return [{t: fwd[k][t] * bwd[k][t] / total for t in ranges[k]} for k in range(n)]


def test_triggers_cover_feasible_range(schedules):
    """Empirical marginals match the exact marginals of the uniform-over-feasible-schedules law."""
    exact = _exact_uniform_marginals(RANDOM_TRIGGER_WINDOWS, MIN_TRIGGER_GAP)
    for k, (lo, hi) in enumerate(RANDOM_TRIGGER_WINDOWS):
        p = exact[k]
        assert sum(p.values()) == pytest.approx(1.0)
        col = schedules[:, k]
        mean = sum(t * m for t, m in p.items())
        assert abs(col.mean() - mean) < 1.5, (k, col.mean(), mean)
        empirical = np.bincount(col - lo, minlength=hi - lo + 1) / len(col)
        tv = 0.5 * np.abs(empirical - np.array([p[t] for t in range(lo, hi + 1)])).sum()
        assert tv < 0.12, (k, tv)
        feasible = [t for t, m in p.items() if m > 0]
        assert col.min() <= min(feasible) + 5 and col.max() >= max(feasible) - 5


def test_later_triggers_do_not_drift_late(schedules):
    """The last trigger is not squeezed into the end of its window (sequential sampling did that)."""
    exact = _exact_uniform_marginals(RANDOM_TRIGGER_WINDOWS, MIN_TRIGGER_GAP)[5]
    p_late = sum(m for t, m in exact.items() if t > 470)
    assert p_late < 0.4  # the sequential scheme put about 0.57 here
    assert abs(np.mean(schedules[:, 5] > 470) - p_late) < 0.04
    assert abs(schedules[:, 5].mean() - 463) < 3


def test_infeasible_windows_raise_and_resample():
    with pytest.raises(ValueError, match="could not sample"):
        sample_random_triggers(np.random.default_rng(0), windows=((0, 10), (5, 20)), min_gap=60)
    with pytest.raises(ValueError, match="empty"):
        sample_random_triggers(np.random.default_rng(0), windows=((10, 5),))
    # Feasible only when the first trigger is early: rejection finds it and respects the gap.
    for seed in range(50):
        t = sample_random_triggers(np.random.default_rng(seed), windows=((0, 10), (12, 14)), min_gap=10)
        assert 0 <= t[0] <= 3 and 12 <= t[1] <= 14 and t[1] - t[0] > 10

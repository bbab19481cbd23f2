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


def _exact_sequential_marginals(windows, min_gap):
    """P(t_k = t) of the documented sequential scheme (no resampling is ever needed for `windows`)."""
    lo, hi = windows[0]
    marginals = [{t: 1.0 / (hi - lo + 1) for t in range(lo, hi + 1)}]
    for lo, hi in windows[1:]:
        p: dict[int, float] = {}
        for prev, mass in marginals[-1].items():
            low = max(lo, prev + min_gap + 1)
            assert low <= hi
            for t in range(low, hi + 1):
                p[t] = p.get(t, 0.0) + mass / (hi - low + 1)
        marginals.append(p)
    return marginals


def test_triggers_cover_feasible_range(schedules):
    """Every step of every window is reachable; each window's observed range spans its likely range.

    Sequential sampling pushes later triggers towards the end of their windows (a late t_{k-1}
    truncates window k from below), so the low end of later windows has little mass. The empirical
    marginals must match the exact marginals of the documented scheme.
    """
    exact = _exact_sequential_marginals(RANDOM_TRIGGER_WINDOWS, MIN_TRIGGER_GAP)
    for k, (lo, hi) in enumerate(RANDOM_TRIGGER_WINDOWS):
        p = exact[k]
        assert sorted(p) == list(range(lo, hi + 1))  # the whole window is feasible
        assert sum(p.values()) == pytest.approx(1.0)
        col = schedules[:, k]
        assert col.max() == hi
        if k == 0:
            assert col.min() == lo
        observed = set(col.tolist())
        likely = {t for t, m in p.items() if m >= 0.01}
        assert likely <= observed, (k, sorted(likely - observed))
        cdf = np.cumsum([p[t] for t in range(lo, hi + 1)])
        q01 = lo + int(np.searchsorted(cdf, 0.01))
        assert col.min() <= q01, (k, col.min(), q01)
        empirical = np.bincount(col - lo, minlength=hi - lo + 1) / len(col)
        tv = 0.5 * np.abs(empirical - np.array([p[t] for t in range(lo, hi + 1)])).sum()
        assert tv < 0.12, (k, tv)


def test_first_window_roughly_uniform(schedules):
    counts = np.bincount(schedules[:, 0] - 60, minlength=71)
    assert counts.min() > 0
    assert abs(schedules[:, 0].mean() - 95.0) < 2.0


def test_infeasible_windows_raise_and_resample():
    with pytest.raises(ValueError, match="could not sample"):
        sample_random_triggers(np.random.default_rng(0), windows=((0, 10), (5, 20)), min_gap=60)
    with pytest.raises(ValueError, match="empty"):
        sample_random_triggers(np.random.default_rng(0), windows=((10, 5),))
    # Feasible only when the first trigger is early: resampling finds it and respects the gap.
    for seed in range(50):
        t = sample_random_triggers(np.random.default_rng(seed), windows=((0, 10), (12, 14)), min_gap=10)
        assert 0 <= t[0] <= 3 and 12 <= t[1] <= 14 and t[1] - t[0] > 10

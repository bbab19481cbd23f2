"""`schema.channel_stats` (the exact per-channel point-cloud statistics `bavo-collect` writes at the end)
equals numpy's own min / max / mean / std / quantile along axis 0 of the float64 array, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from lerobot_bavo.datasets import schema as S


def numpy_channel_stats(
    values: np.ndarray, quantiles=(0.01, 0.10, 0.50, 0.90, 0.99)
) -> dict[str, np.ndarray]:
    """The straightforward whole-array version (what `channel_stats` computed before issue 11's speed-up)."""
    flat = np.asarray(values, dtype=np.float64).reshape(-1, values.shape[-1])
    stats = {"min": flat.min(0), "max": flat.max(0), "mean": flat.mean(0), "std": flat.std(0),
             "count": np.array([flat.shape[0]])}
    for q in quantiles:
        stats[f"q{int(round(q * 100)):02d}"] = np.quantile(flat, q, axis=0)
    return stats


def assert_identical(ours: dict, theirs: dict) -> None:
    assert list(ours) == list(theirs)
    for key, expected in theirs.items():
        assert ours[key].dtype == expected.dtype and ours[key].shape == expected.shape, key
        assert ours[key].tobytes() == expected.tobytes(), (key, ours[key], expected)


@pytest.mark.parametrize("rows", [1, 2, 7, (1 << 18) - 1, (1 << 18) + 5, 3 * (1 << 18) + 11])
def test_equals_numpy_across_block_boundaries(rows):
    rng = np.random.default_rng(rows)
    values = rng.normal(0.3, 2.0, size=(rows, 6)).astype(np.float32)
    values[:, 3] = np.round(values[:, 3])  # heavy ties
    values[:, 4] = 0.7  # constant channel: std exactly 0
    values[:, 5] *= 1e5  # wide range
    assert_identical(S.channel_stats(values), numpy_channel_stats(values))


def test_point_cloud_layout_and_a_hand_computed_case():
    # (frames, points, channels) as the dataset stores them, unflattened
    # channel 0: 0,2,..,10; channel 1: 1,3,..,11
    values = np.arange(2 * 3 * 2, dtype=np.float32).reshape(2, 3, 2)
    stats = S.channel_stats(values)
    assert_identical(stats, numpy_channel_stats(values))
    np.testing.assert_array_equal(stats["mean"], [5.0, 6.0])
    np.testing.assert_array_equal(stats["min"], [0.0, 1.0])
    np.testing.assert_allclose(stats["std"], [np.sqrt(70.0 / 6.0)] * 2)  # population std of 0, 2, ..., 10
    np.testing.assert_array_equal(stats["q50"], [5.0, 6.0])
    with pytest.raises(ValueError, match="at least one"):
        S.channel_stats(np.zeros((0, 6), np.float32))

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


def test_channel_subsets_give_the_same_bits_as_all_channels(tmp_path):
    """`bavo-collect` splits the end-of-run point-cloud statistics between its workers by channel
    (`hub.point_cloud_channel_stats(root, channels)`, `merge_channel_stats`): the merged statistics are those
    of all channels at once, bit for bit, across block boundaries and from a dataset's data files."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from lerobot_bavo.datasets.hub import merge_channel_stats, point_cloud_channel_stats

    rng = np.random.default_rng(5)
    points = (rng.normal(size=((1 << 18) + 1232, S.POINT_CHANNELS)) * [1, 2, 3, 40, 50, 60]
              ).astype(np.float32)
    whole = S.channel_stats(points)
    for parts in ([[0, 1, 2], [3, 4, 5]], [[0, 1], [2, 3], [4, 5]], [[0], [1, 2, 3, 4, 5]]):
        assert_identical(merge_channel_stats([S.channel_stats(points, channels=p) for p in parts]), whole)
    flat = points.reshape(-1, 8 * S.POINT_CHANNELS)  # frames of 8 points, as the data files store them
    for i, rows in enumerate(np.array_split(flat, 3)):  # three data files
        path = tmp_path / "data" / "chunk-000" / f"file-{i:03d}.parquet"
        path.parent.mkdir(parents=True, exist_ok=True)
        column = pa.FixedSizeListArray.from_arrays(pa.array(rows.reshape(-1)), flat.shape[1])
        pq.write_table(pa.table({S.OBS_POINT_CLOUD: column}), path)
    merged = merge_channel_stats([point_cloud_channel_stats(tmp_path, [0, 1, 2]),
                                  point_cloud_channel_stats(tmp_path, [3, 4, 5])])
    assert_identical(merged, whole)
    assert_identical(point_cloud_channel_stats(tmp_path), whole)

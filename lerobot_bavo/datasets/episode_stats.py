"""Per-episode statistics of numeric features, equal bit for bit to LeRobot 0.6.1's, without its histograms.

Why: when `save_episode` runs, LeRobot's `compute_episode_stats` gives every dimension of every numeric
feature its own 5000-bin histogram (`RunningQuantileStats`, one `np.histogram` call per dimension) and
then scans each histogram's cumulative sum once per quantile (q01, q10, q50, q90, q99). BAVO's flat
features are wide (point cloud 256 x 6, point pixels 256 x 2, teacher targets), so on 2 cores this was
the largest share of the collection writer's CPU (measured in docs/results/costs.md).

A quantile of LeRobot's histogram only needs the histogram's cumulative count at two bins, and the
cumulative count up to bin k is the number of values below bin edge k + 1. `vector_stats` counts those
directly in the sorted column (vectorised binary searches), using the same bin edges (the same
`np.linspace` call per dimension) and the same arithmetic and dtypes as LeRobot for the result, so its
output equals `lerobot.datasets.compute_stats.get_feature_stats(x, axis=0, keepdims=x.ndim == 1)`:
same keys in the same order, same shapes, same dtypes, same bits (`tests/test_episode_stats.py` checks
it on real episodes and on adversarial columns: constant, signed zeros, integers, 1-D, huge ranges).

`compute_episode_stats` is LeRobot's function with this fast path for numeric features of two or fewer
axes and at least two frames; everything else (images, videos, strings, one-frame episodes) goes to
LeRobot's own code. `lerobot_private.exact_fast_episode_stats` installs it in LeRobot's writer.
"""

from __future__ import annotations

import math

import numpy as np

QUANTILE_BINS = 5000  # RunningQuantileStats' num_quantile_bins default
QUANTILES = (0.01, 0.10, 0.50, 0.90, 0.99)  # lerobot.datasets.compute_stats.DEFAULT_QUANTILES
QUANTILE_KEYS = tuple(f"q{int(q * 100):02d}" for q in QUANTILES)


def _count_right(sorted_rows: np.ndarray, values: np.ndarray, strict: bool) -> np.ndarray:
    """Per row r of `sorted_rows` (R, M), non-decreasing: the number of entries < values[r] (`strict`) or
    <= values[r]; `np.searchsorted(row, v, side="left" if strict else "right")` for every row at once."""
    rows = np.arange(sorted_rows.shape[0])
    lo = np.zeros(sorted_rows.shape[0], dtype=np.int64)
    hi = np.full(sorted_rows.shape[0], sorted_rows.shape[1], dtype=np.int64)
    while True:
        active = lo < hi
        if not active.any():
            return lo
        mid = (lo + hi) // 2
        entry = sorted_rows[rows, np.minimum(mid, sorted_rows.shape[1] - 1)]
        below = (entry < values) if strict else (entry <= values)
        go_right = active & below
        lo = np.where(go_right, mid + 1, lo)
        hi = np.where(active & ~below, mid, hi)


def vector_stats(array: np.ndarray) -> dict[str, np.ndarray]:
    """LeRobot's `get_feature_stats(array, axis=0, keepdims=array.ndim == 1)` for a numeric (T,) or (T, D)
    array with T >= 2: min, max, mean, std, count and the quantiles q01 ... q99 per dimension."""
    array = np.asarray(array)
    if array.ndim not in (1, 2) or array.shape[0] < 2:
        raise ValueError(f"vector_stats needs a (T,) or (T, D) array with T >= 2, got shape {array.shape}")
    keepdims = array.ndim == 1
    batch = array.reshape(-1, 1) if array.ndim == 1 else array
    batch = batch.astype(np.result_type(batch.dtype, np.float32), copy=False)
    n, dims = batch.shape

    # RunningQuantileStats.update on a fresh instance, operation for operation
    mean = np.mean(batch, axis=0)
    mean_sq = np.mean(batch**2, axis=0)
    lo = np.min(batch, axis=0)
    hi = np.max(batch, axis=0)
    edges = np.stack([np.linspace(lo[i] - 1e-10, hi[i] + 1e-10, QUANTILE_BINS + 1) for i in range(dims)])
    # LeRobot then adds (batch mean - running mean) * (n / n): the batch mean is the same array again, so the
    # difference is mean - mean. Kept because it is not a no-op: -0.0 becomes +0.0 and inf becomes nan.
    mean += (mean - mean) * (n / n)
    mean_sq += (mean_sq - mean_sq) * (n / n)

    # get_statistics
    variance = mean_sq - mean**2
    stats = {"min": lo.copy(), "max": hi.copy(), "mean": mean.copy(), "std": np.sqrt(np.maximum(0, variance)),
             "count": np.array([n])}
    columns = np.sort(batch, axis=0).T  # (D, n), each row sorted
    rows = np.arange(dims)
    last = QUANTILE_BINS - 1
    for key, q in zip(QUANTILE_KEYS, QUANTILES, strict=True):
        target = q * n
        # idx = searchsorted(cumsum(hist), target): the first bin whose cumulative count reaches target.
        # cumsum[k] = #(x < edges[k + 1]) for k < last (edges[0] <= min), cumsum[last] = n (edges[-1] >= max),
        # so it is the number of edges[1:] <= the m-th smallest value, m = ceil(target), capped at `last`.
        m = math.ceil(target)
        if m <= 0:
            idx = np.zeros(dims, dtype=np.int64)
        else:
            idx = np.minimum(_count_right(edges, columns[:, m - 1], strict=False) - 1, last)

        def cumulative(k: np.ndarray) -> np.ndarray:  # cumsum[k] of LeRobot's float64 histogram
            below = _count_right(columns, edges[rows, np.minimum(k + 1, QUANTILE_BINS)], strict=True)
            return np.where(k >= last, n, below).astype(np.float64)

        count_before = cumulative(np.maximum(idx - 1, 0))
        count_in_bin = cumulative(idx) - count_before
        edge = edges[rows, idx]
        interpolate = (idx > 0) & (count_in_bin != 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            fraction = (target - count_before) / count_in_bin
        step = edges[rows, np.minimum(idx + 1, QUANTILE_BINS)] - edge
        value = np.where(interpolate, edge + fraction * step, edge)
        # np.array over the per-dimension scalars: float64 where any was interpolated, else the edges' dtype
        stats[key] = value if interpolate.any() else value.astype(edges.dtype)
    if keepdims:  # _reshape_for_vector_stats
        stats = {k: v if k == "count" else v.reshape(1) for k, v in stats.items()}
    return stats


def writer_stats_inputs(columns: dict[str, np.ndarray]) -> tuple[dict[str, np.ndarray], dict[str, dict]]:
    """(episode data, features) as LeRobot's writer hands an episode's numeric columns (frame-leading arrays)
    to `compute_episode_stats`: (T, 1) columns as (T,), features with dtype and per-frame shape. For comparing
    this module with LeRobot's function on real episodes (test and benchmark)."""
    data = {k: (v.reshape(-1) if v.ndim == 2 and v.shape[1] == 1 else v) for k, v in columns.items()}
    features = {k: {"dtype": str(v.dtype), "shape": v.shape[1:] or (1,)} for k, v in data.items()}
    return data, features


def compute_episode_stats(
    episode_data: dict, features: dict, quantile_list: list[float] | None = None, known: dict | None = None
) -> dict:
    """`lerobot.datasets.compute_stats.compute_episode_stats` with `vector_stats` for numeric features.

    `known`: statistics already computed for some features (by the worker that recorded the episode, with
    `vector_stats` on the same arrays: `episode_payload.column_stats`); they are used as they are, in the
    order of `episode_data`, so the result is the same dict. LeRobot (and PyTorch) is imported only for what
    goes to its own code (images, videos, other quantiles, one-frame episodes), which a `bavo-collect`
    episode never has."""
    if quantile_list is not None and tuple(quantile_list) != QUANTILES:
        from lerobot.datasets import compute_stats as lerobot_stats

        return lerobot_stats.compute_episode_stats(episode_data, features, quantile_list)
    known = known or {}
    stats = {}
    for key, data in episode_data.items():
        dtype = features[key]["dtype"]
        if dtype in {"string", "language"}:
            continue
        if key in known and dtype not in ("image", "video"):
            stats[key] = known[key]
            continue
        if dtype in ("image", "video") or not isinstance(data, np.ndarray) or data.ndim not in (1, 2) \
                or data.shape[0] < 2 or not (np.issubdtype(data.dtype, np.number) or data.dtype == bool):
            from lerobot.datasets import compute_stats as lerobot_stats

            stats.update(
                lerobot_stats.compute_episode_stats({key: data}, {key: features[key]}, quantile_list)
            )
        else:
            stats[key] = vector_stats(data)
    return stats

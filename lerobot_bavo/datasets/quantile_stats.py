"""LeRobot 0.6.1's `compute_stats.RunningQuantileStats`, copied so that it can run without PyTorch.

Why (issue 30): LeRobot's statistics module imports `lerobot.processor`, hence PyTorch (~2.8 s of CPU in a
fresh process). `bavo-collect`'s writing process finishes each episode's image statistics with this class
(`video_stats.stats_from_reductions`) and must not import PyTorch, so the class is copied here, statement for
statement (numpy only). `tests/test_video_stats.py` compares it and its subclass `DeferredFrameStats` with
LeRobot's class bit for bit, so a LeRobot upgrade that changes the statistics fails there.

Copyright 2024 The HuggingFace Inc. team; Apache License 2.0 (the source:
`lerobot/datasets/compute_stats.py`).
"""

from __future__ import annotations

import numpy as np

DEFAULT_QUANTILES = [0.01, 0.10, 0.50, 0.90, 0.99]  # lerobot.datasets.compute_stats.DEFAULT_QUANTILES


class RunningQuantileStats:
    """Running mean, standard deviation, min, max and histogram quantiles per dimension of batches of vectors
    (LeRobot's class of the same name, see the module docstring)."""

    def __init__(self, quantile_list: list[float] | None = None, num_quantile_bins: int = 5000):
        self._count = 0
        self._mean = None
        self._mean_of_squares = None
        self._min = None
        self._max = None
        self._histograms = None
        self._bin_edges = None
        self._num_quantile_bins = num_quantile_bins
        self._quantile_list = DEFAULT_QUANTILES if quantile_list is None else quantile_list
        self._quantile_keys = [f"q{int(q * 100):02d}" for q in self._quantile_list]

    def start(self, mean: np.ndarray, mean_of_squares: np.ndarray, minimum: np.ndarray,
              maximum: np.ndarray) -> None:
        """The state after the first batch (LeRobot's first-update branch): its per-dimension mean, mean of
        squares and range, and empty histograms whose bins span that range."""
        self._mean, self._mean_of_squares, self._min, self._max = mean, mean_of_squares, minimum, maximum
        self._histograms = [np.zeros(self._num_quantile_bins) for _ in range(mean.size)]
        self._bin_edges = [
            np.linspace(self._min[i] - 1e-10, self._max[i] + 1e-10, self._num_quantile_bins + 1)
            for i in range(mean.size)
        ]

    def update(self, batch: np.ndarray) -> None:
        """Update the statistics with a batch of vectors (every axis but the last is a batch axis)."""
        batch = batch.reshape(-1, batch.shape[-1])
        batch = batch.astype(np.result_type(batch.dtype, np.float32), copy=False)
        num_elements, vector_length = batch.shape
        if self._count == 0:
            self.start(np.mean(batch, axis=0), np.mean(batch**2, axis=0), np.min(batch, axis=0),
                       np.max(batch, axis=0))
        else:
            if vector_length != self._mean.size:
                raise ValueError("The length of new vectors does not match the initialized vector length.")
            new_max = np.max(batch, axis=0)
            new_min = np.min(batch, axis=0)
            max_changed = np.any(new_max > self._max)
            min_changed = np.any(new_min < self._min)
            self._max = np.maximum(self._max, new_max)
            self._min = np.minimum(self._min, new_min)
            if max_changed or min_changed:
                self._adjust_histograms()
        self._count += num_elements
        batch_mean = np.mean(batch, axis=0)
        batch_mean_of_squares = np.mean(batch**2, axis=0)
        self._mean += (batch_mean - self._mean) * (num_elements / self._count)
        self._mean_of_squares += (batch_mean_of_squares - self._mean_of_squares) * (
            num_elements / self._count
        )
        self._update_histograms(batch)

    def get_statistics(self) -> dict[str, np.ndarray]:
        """min, max, mean, std, count and the quantiles of the vectors so far (at least 2)."""
        if self._count < 2:
            raise ValueError("Cannot compute statistics for less than 2 vectors.")
        variance = self._mean_of_squares - self._mean**2
        stddev = np.sqrt(np.maximum(0, variance))
        stats = {
            "min": self._min.copy(),
            "max": self._max.copy(),
            "mean": self._mean.copy(),
            "std": stddev,
            "count": np.array([self._count]),
        }
        for key, values in zip(self._quantile_keys, self._compute_quantiles(), strict=True):
            stats[key] = values
        return stats

    def _adjust_histograms(self) -> None:
        """Re-bin the histograms over the widened range (each old bin's count goes to the new bin holding its
        centre)."""
        for i in range(len(self._histograms)):
            old_edges = self._bin_edges[i]
            old_hist = self._histograms[i]
            padding = (self._max[i] - self._min[i]) * 1e-10
            new_edges = np.linspace(
                self._min[i] - padding, self._max[i] + padding, self._num_quantile_bins + 1
            )
            old_centers = (old_edges[:-1] + old_edges[1:]) / 2
            new_hist = np.zeros(self._num_quantile_bins)
            for old_center, count in zip(old_centers, old_hist, strict=False):
                if count > 0:
                    bin_idx = np.searchsorted(new_edges, old_center) - 1
                    bin_idx = max(0, min(bin_idx, self._num_quantile_bins - 1))
                    new_hist[bin_idx] += count
            self._histograms[i] = new_hist
            self._bin_edges[i] = new_edges

    def _update_histograms(self, batch: np.ndarray) -> None:
        for i in range(batch.shape[1]):
            hist, _ = np.histogram(batch[:, i], bins=self._bin_edges[i])
            self._histograms[i] += hist

    def _compute_quantiles(self) -> list[np.ndarray]:
        results = []
        for q in self._quantile_list:
            target_count = q * self._count
            q_values = [self._compute_single_quantile(hist, edges, target_count)
                        for hist, edges in zip(self._histograms, self._bin_edges, strict=True)]
            results.append(np.array(q_values))
        return results

    def _compute_single_quantile(self, hist: np.ndarray, edges: np.ndarray, target_count: float) -> float:
        cumsum = np.cumsum(hist)
        idx = np.searchsorted(cumsum, target_count)
        if idx == 0:
            return edges[0]
        if idx >= len(cumsum):
            return edges[-1]
        count_before = cumsum[idx - 1]
        count_in_bin = cumsum[idx] - count_before
        if count_in_bin == 0:
            return edges[idx]
        fraction = (target_count - count_before) / count_in_bin
        return edges[idx] + fraction * (edges[idx + 1] - edges[idx])

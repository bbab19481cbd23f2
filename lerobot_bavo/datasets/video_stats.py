"""LeRobot 0.6.1's streaming image statistics, bit for bit, with the per-frame work done once per episode.

Why: with `streaming_encoding=True` LeRobot's encoder thread (`video_utils._CameraEncoderThread`) feeds
every frame of a video feature to a `compute_stats.RunningQuantileStats`: it converts the (down-sampled,
here 120 x 160) frame to float32, takes per-channel means, means of squares, minima and maxima along
axis 0 of an (H * W, 3) array (a reduction whose inner loop runs over 3 channels) and a 5000-bin
`np.histogram` per channel: a noticeable part of the collection writer's CPU (docs/results/costs.md), for
statistics of uint8 pixels.

`DeferredFrameStats` is a `RunningQuantileStats` that, for uint8 frames, only keeps each frame in
`update` and replays the same sequence of updates in `get_statistics` with whole-episode array
operations. Why the replay gives the same bits:

- min / max: exact whatever the order; the per-frame values are taken in one `min` / `max` over frames.
- A frame's mean and mean of squares: `np.mean(batch, axis=0)` of a C-contiguous (N, C) float32 batch
  sums in float32 row after row (numpy sums pairwise only along the contiguous axis; over the outer axis
  it adds whole rows), then divides by `np.intp(N)`. The replay lays a chunk of frames side by side as
  lanes, (N, frames x C), and reduces over axis 0: the same row-after-row float32 sum for every frame at
  once, divided by the same call. Squares of uint8 values are exact in float32 (<= 65025 < 2**24).
- The running mean / mean of squares, the count and the range: the original statements, per frame, on
  (C,) vectors, in frame order.
- Histograms: a bin's count is the number of values inside its edges, so frames histogrammed with the
  same edges add up to one histogram of all of them; the values are integers 0..255, so that histogram
  is a weighted histogram of the 256 values (integer weights: exact in float64). Whenever a frame widens
  the range, the frames before it are histogrammed with the old edges first and then LeRobot's own
  `_adjust_histograms` redistributes them, exactly as the per-frame updates would.

Anything that is not a uint8 batch (float frames, depth maps) goes to LeRobot's own `update` after the
kept frames are replayed, so the order of updates is always the original one. `tests/test_video_stats.py`
compares every statistic bit for bit with LeRobot's class on real episode frames and adversarial ones
(constant frames, ranges that widen mid-episode, one channel, mixed dtypes).
`lerobot_private.deferred_video_frame_stats` installs it in LeRobot's writer sessions (`bavo-teleop`,
datasets without video). It derives from `quantile_stats.RunningQuantileStats`, the copy of LeRobot's class
that needs no PyTorch, so `bavo-collect`'s writing process (`direct_writer.py`) finishes image statistics
without importing LeRobot; the tests compare both with LeRobot's own class.
"""

from __future__ import annotations

import numpy as np

from lerobot_bavo.datasets.frame_reductions import FrameReductions, reduce_frames, reducible
from lerobot_bavo.datasets.quantile_stats import RunningQuantileStats

# every value a uint8 pixel can take, as the float32 batch holds it
_VALUES = np.arange(256, dtype=np.float32)


class DeferredFrameStats(RunningQuantileStats):
    """`RunningQuantileStats` with uint8 updates deferred to `get_statistics` (same statistics, bit for
    bit). `add_reductions` takes frames already reduced elsewhere (`frame_reductions.reduce_frames`, in a
    `bavo-collect` worker)."""

    def __init__(self, quantile_list: list[float] | None = None, num_quantile_bins: int = 5000):
        super().__init__(quantile_list, num_quantile_bins)
        self._pending: list[np.ndarray] = []  # kept uint8 frames, (N, C) C-contiguous each, all one shape

    def update(self, batch: np.ndarray) -> None:
        batch = np.asarray(batch)
        rows = batch.reshape(-1, batch.shape[-1])
        if not reducible(rows):
            self._replay()  # keep the original order of updates
            super().update(batch)
            return
        if self._pending and rows.shape != self._pending[0].shape:
            self._replay()  # a uint8 frame of another size starts a new run
        self._pending.append(np.array(rows, order="C", copy=True))  # the caller may reuse its buffer

    def get_statistics(self) -> dict[str, np.ndarray]:
        self._replay()
        return super().get_statistics()

    def _replay(self) -> None:
        """Apply the kept frames' updates in order, as LeRobot's `update` would have one frame at a time."""
        if not self._pending:
            return
        frames = np.stack(self._pending)  # (F, N, C) uint8
        self._pending = []
        self.add_reductions(reduce_frames(frames))

    def add_reductions(self, red: FrameReductions) -> None:
        """LeRobot's `update` of each reduced frame, in order (after any kept frames): the running mean, mean
        of squares, count and range per frame; the histograms of each run of frames between range changes
        at once, from the frames' value counts."""
        self._replay()
        n_frames, channels = red.frame_mean.shape
        n = red.pixels
        run_start = 0  # first frame not yet added to the histograms
        for f in range(n_frames):
            if self._count == 0:
                self.start(red.frame_mean[f].copy(), red.frame_mean_sq[f].copy(), red.frame_min[f].copy(),
                           red.frame_max[f].copy())
            else:
                if channels != self._mean.size:
                    raise ValueError(
                        "The length of new vectors does not match the initialized vector length."
                    )
                new_max, new_min = red.frame_max[f], red.frame_min[f]
                max_changed = np.any(new_max > self._max)
                min_changed = np.any(new_min < self._min)
                self._max = np.maximum(self._max, new_max)
                self._min = np.minimum(self._min, new_min)
                if max_changed or min_changed:
                    self._add_to_histograms(red.frame_counts[run_start:f])
                    run_start = f
                    self._adjust_histograms()
            self._count += n
            self._mean += (red.frame_mean[f] - self._mean) * (n / self._count)
            self._mean_of_squares += (red.frame_mean_sq[f] - self._mean_of_squares) * (n / self._count)
        self._add_to_histograms(red.frame_counts[run_start:])

    def _add_to_histograms(self, frame_counts: np.ndarray) -> None:
        """Add frames to the histograms with the current edges, from their (F, C, 256) value counts (one
        weighted histogram of the 256 values per channel)."""
        if frame_counts.shape[0] == 0:
            return
        totals = frame_counts.sum(axis=0)
        for i in range(totals.shape[0]):
            hist, _ = np.histogram(_VALUES, bins=self._bin_edges[i], weights=totals[i].astype(np.float64))
            self._histograms[i] += hist


def stats_from_reductions(red: FrameReductions) -> dict[str, np.ndarray]:
    """LeRobot's statistics of frames reduced elsewhere (`frame_reductions.episode_frame_reductions`): what
    its streaming encoder thread reports for them. Imports neither LeRobot nor PyTorch."""
    tracker = DeferredFrameStats()
    tracker.add_reductions(red)
    return tracker.get_statistics()

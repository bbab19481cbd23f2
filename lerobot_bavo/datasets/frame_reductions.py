"""The per-frame part of LeRobot's streaming image statistics, in numpy only (no LeRobot, no PyTorch).

Why a module of its own (issue 30): a `bavo-collect` worker computes its episode's image statistics, but
LeRobot's statistics class (`compute_stats.RunningQuantileStats`) lives in a module that imports PyTorch,
~2.8 s of CPU per worker process that an expert episode otherwise never needs. LeRobot's statistics of an
episode's frames split into two parts:

- per frame, over its (pixels, channels) values: minimum, maximum, mean and mean of squares (float32), and,
  for the histograms, how many pixels of each channel take each of the 256 uint8 values. This is nearly all
  of the work (57,600 values per 240 x 320 frame after LeRobot's down-sampling), and it is what
  `reduce_frames` computes, here, in the worker;
- the running update of LeRobot's class, frame after frame, from those per-frame numbers (a few operations
  on (channels,) vectors, and a histogram of 256 weighted values whenever the range grows), then its
  quantiles: `video_stats.DeferredFrameStats.add_reductions` in the process that has LeRobot loaded.

`video_stats.py` explains why the split gives LeRobot's statistics bit for bit (`tests/test_video_stats.py`,
`tests/test_episode_payload.py` compare them with LeRobot's own class).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# frames reduced at a time (bounds the buffers: 32 frames x 57,600 values x 5 bytes)
FRAME_CHUNK = 32
# LeRobot's down-sampling for statistics (`compute_stats.auto_downsample_height_width`): frames whose larger
# side is at least this many pixels are strided so that it becomes about `DOWNSAMPLE_TARGET`
DOWNSAMPLE_THRESHOLD, DOWNSAMPLE_TARGET = 300, 150
FIELDS = ("frame_min", "frame_max", "frame_mean", "frame_mean_sq", "frame_counts", "pixels")


def downsample(chw: np.ndarray) -> np.ndarray:
    """A (C, H, W) frame as LeRobot's `auto_downsample_height_width` hands it to its statistics: unchanged
    below the threshold, else every k-th row and column, k = int(larger side / target)."""
    _, height, width = chw.shape
    if max(height, width) < DOWNSAMPLE_THRESHOLD:
        return chw
    step = int(width / DOWNSAMPLE_TARGET) if width > height else int(height / DOWNSAMPLE_TARGET)
    return chw[:, ::step, ::step]


def reducible(rows: np.ndarray) -> bool:
    """Rows whose reductions give LeRobot's bits: uint8 (N, C) with C >= 2. With one channel numpy's mean
    runs along the contiguous axis, which it sums pairwise, not row after row."""
    return rows.dtype == np.uint8 and rows.ndim == 2 and rows.shape[0] > 0 and rows.shape[1] >= 2


@dataclass
class FrameReductions:
    """Per-frame reductions of F frames of N pixels x C channels: `frame_min`, `frame_max`, `frame_mean`,
    `frame_mean_sq` (F, C) float32 (as LeRobot's `np.mean` / `np.min` / `np.max` of the frame's float32
    rows give them), `frame_counts` (F, C, 256) int64 (pixels per uint8 value) and `pixels` (N)."""

    frame_min: np.ndarray
    frame_max: np.ndarray
    frame_mean: np.ndarray
    frame_mean_sq: np.ndarray
    frame_counts: np.ndarray
    pixels: int

    def to_arrays(self) -> dict[str, np.ndarray]:
        return {name: np.asarray(getattr(self, name)) for name in FIELDS}

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray]) -> FrameReductions:
        return cls(**{name: arrays[name] for name in FIELDS[:-1]}, pixels=int(np.asarray(arrays["pixels"])))


def reduce_frames(frames: np.ndarray) -> FrameReductions:
    """The reductions of (F, N, C) uint8 frames (`reducible` rows each). Frames are laid side by side as
    lanes, (N, frames x C), so that one reduction over axis 0 is, for every frame at once, the row-after-row
    float32 sum numpy does over one (N, C) frame; then divided by the same `np.intp(N)` as `np.mean`."""
    n_frames, n, channels = frames.shape
    out = {k: np.empty((n_frames, channels), dtype=np.float32) for k in FIELDS[:4]}
    counts = np.empty((n_frames, channels, 256), dtype=np.int64)
    # one bincount per chunk: value v of channel c in the chunk's frame f counts at (f * C + c) * 256 + v
    slots = (np.arange(FRAME_CHUNK * channels, dtype=np.int64) * 256).reshape(FRAME_CHUNK, 1, channels)
    lanes_u8 = np.empty((n, FRAME_CHUNK * channels), dtype=np.uint8)
    lanes = np.empty((n, FRAME_CHUNK * channels), dtype=np.float32)
    for start in range(0, n_frames, FRAME_CHUNK):
        k = min(FRAME_CHUNK, n_frames - start)
        u8 = lanes_u8[:, :k * channels]
        f32 = lanes[:, :k * channels]
        np.copyto(u8.reshape(n, k, channels), frames[start:start + k].transpose(1, 0, 2))
        np.copyto(f32, u8)
        done = slice(start, start + k)
        out["frame_min"][done] = u8.min(axis=0).reshape(k, channels)
        out["frame_max"][done] = u8.max(axis=0).reshape(k, channels)
        out["frame_mean"][done] = np.add.reduce(f32, axis=0).reshape(k, channels)
        np.multiply(f32, f32, out=f32)
        out["frame_mean_sq"][done] = np.add.reduce(f32, axis=0).reshape(k, channels)
        values = (frames[start:start + k] + slots[:k]).ravel()
        counts[done] = np.bincount(values, minlength=k * channels * 256).reshape(k, channels, 256)
    count = np.intp(n)  # what np.mean divides by
    np.true_divide(out["frame_mean"], count, out=out["frame_mean"], casting="unsafe")
    np.true_divide(out["frame_mean_sq"], count, out=out["frame_mean_sq"], casting="unsafe")
    return FrameReductions(**out, frame_counts=counts, pixels=n)


def episode_frame_reductions(frames: np.ndarray) -> FrameReductions | None:
    """The reductions LeRobot's streaming encoder's statistics need for an episode's (T, H, W, C) uint8 frames
    (each down-sampled as LeRobot does), or None where this path does not give LeRobot's bits (fewer than 2
    frames: LeRobot reports no statistics; not uint8 with at least 2 channels)."""
    if frames.shape[0] < 2:
        return None
    small = np.stack([downsample(frame.transpose(2, 0, 1)) for frame in frames])  # (T, C, h, w)
    rows = small.transpose(0, 2, 3, 1).reshape(frames.shape[0], -1, small.shape[1])  # (T, h * w, C)
    if not reducible(rows[0]):
        return None
    return reduce_frames(np.ascontiguousarray(rows))

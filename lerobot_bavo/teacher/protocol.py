"""The 4D-teacher protocol: point-aligned queries q = (u, v, t_src, t_tgt, t_cam) on an episode clip.

D4RT (arXiv 2512.08924) maps a video clip to a scene representation and answers independent
queries q = (u, v, t_src, t_tgt, t_cam): "where is the surface point seen at pixel (u, v) of
frame t_src at time t_tgt, expressed in the camera frame of frame t_cam". A-FAR (paper Sec. 4.2,
Appendix B) asks it, for every point of the current cloud, at
    q0 = (u, v, 16, 16, 16)  and  qF = (u, v, 16, 31, 31)
on a 32-frame clip whose anchor (current) frame is clip index 16 and whose future frame is
clip index 31 (Delta t = 15 control steps = 0.6 s at 25 Hz).

A teacher is anything with `feature_dim` and `answer(clip, queries) -> (Q, feature_dim)`.

Query layout (`queries`, (Q, 5) float64; `QUERY_FIELDS`):
    u, v     source pixel in frame t_src: u = column, v = row, pixel-centre integer indices of
             the clip's full-resolution image (the env's `point_pixels`); `normalized_uv` gives
             D4RT's [0, 1]^2 convention.
    t_src, t_tgt, t_cam   clip-local frame indices in [0, T).

Clip construction (`make_clip`, Appendix B): for anchor frame t of an episode of T_ep frames,
the clip holds episode frames t - 16 ... t + 15 (clip index i <-> episode frame t - 16 + i),
clamped at the episode boundaries: clip frames before the episode start repeat frame 0 and
clip frames after its end repeat the last frame T_ep - 1. `EpisodeClip.valid_future` tells
whether the future frame (index 31) is a real frame (t + 15 <= T_ep - 1); cached targets carry
it as `observation.teacher.valid`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

QUERY_FIELDS = ("u", "v", "t_src", "t_tgt", "t_cam")
CLIP_LENGTH = 32
ANCHOR_INDEX = 16
FUTURE_INDEX = 31  # ANCHOR_INDEX + 15


@dataclass(frozen=True)
class EpisodeClip:
    """The frames of one episode a teacher may use, seen through a clip window.

    The arrays are the *episode's* (leading axis = episode frame, length T_ep) and are shared, not
    copied, between the clips of an episode; `frames[i]` is the episode frame of clip index i.
    The properties `rgb`, `depth`, `camera_poses`, ... materialise the clip's own (T, ...) arrays
    (e.g. for a learned teacher); `at(name, clip_index)` reads without copying whole clips.

    Fields:
        frames: (T,) int64 episode frame of every clip index (clamped, see the module docstring).
        K: (3, 3) pinhole intrinsics of the full-resolution image (pixels).
        episode_rgb: (T_ep, H, W, 3) uint8 RGB images.
        episode_camera_poses: (T_ep, 4, 4) float64 T_B<-C, OpenCV camera axes.
        episode_depth: (T_ep, H, W) float32 z-depth (m), or None.
        Privileged, simulator only (None for a real-data clip):
        episode_body_xpos: (T_ep, n_body, 3) float64 body positions in the base frame (m).
        episode_body_xmat: (T_ep, n_body, 3, 3) float64 body rotations R_B<-body.
        episode_body_seg: (T_ep, H, W) int16 id of the body seen at each pixel (-1: none), from
            the same render pass as `episode_depth`.
        anchor_index: clip index of the current frame (16).
        episode_length: T_ep.
    """

    frames: np.ndarray
    K: np.ndarray
    episode_rgb: np.ndarray
    episode_camera_poses: np.ndarray
    episode_depth: np.ndarray | None = None
    episode_body_xpos: np.ndarray | None = None
    episode_body_xmat: np.ndarray | None = None
    episode_body_seg: np.ndarray | None = None
    anchor_index: int = ANCHOR_INDEX
    episode_length: int = field(default=-1)

    def __post_init__(self):
        if self.episode_length < 0:
            object.__setattr__(self, "episode_length", int(self.episode_rgb.shape[0]))
        frames = np.asarray(self.frames, dtype=np.int64)
        if frames.ndim != 1 or frames.size == 0:
            raise ValueError(f"frames must be a non-empty (T,) index array, got shape {frames.shape}")
        if frames.min() < 0 or frames.max() >= self.episode_length:
            raise ValueError(
                f"clip frames must lie in [0, {self.episode_length}), got {frames.min()}..{frames.max()}"
            )
        object.__setattr__(self, "frames", frames)

    # -- sizes
    @property
    def length(self) -> int:
        return int(self.frames.shape[0])

    @property
    def image_size(self) -> tuple[int, int]:
        return int(self.episode_rgb.shape[1]), int(self.episode_rgb.shape[2])

    @property
    def has_privileged_state(self) -> bool:
        return (self.episode_body_xpos is not None and self.episode_body_xmat is not None
                and self.episode_body_seg is not None and self.episode_depth is not None)

    def valid_future(self, future_index: int = FUTURE_INDEX) -> bool:
        """Whether clip index `future_index` is a real frame, not a repeat of the episode's last one."""
        anchor_frame = int(self.frames[self.anchor_index])
        return anchor_frame + (future_index - self.anchor_index) <= self.episode_length - 1

    # -- materialised clip arrays (T, ...)
    def _clip(self, array):
        return None if array is None else array[self.frames]

    @property
    def rgb(self) -> np.ndarray:
        return self._clip(self.episode_rgb)

    @property
    def depth(self) -> np.ndarray | None:
        return self._clip(self.episode_depth)

    @property
    def camera_poses(self) -> np.ndarray:
        return self._clip(self.episode_camera_poses)

    @property
    def body_xpos(self) -> np.ndarray | None:
        return self._clip(self.episode_body_xpos)

    @property
    def body_xmat(self) -> np.ndarray | None:
        return self._clip(self.episode_body_xmat)

    @property
    def body_seg(self) -> np.ndarray | None:
        return self._clip(self.episode_body_seg)

    def episode_frames(self, clip_indices) -> np.ndarray:
        """Episode frame of each clip index (vectorised), with a range check."""
        idx = np.asarray(clip_indices, dtype=np.int64)
        if idx.size and (idx.min() < 0 or idx.max() >= self.length):
            raise ValueError(
                f"clip frame indices must lie in [0, {self.length}), got {idx.min()}..{idx.max()}"
            )
        return self.frames[idx]


def clip_frames(anchor: int, episode_length: int, clip_length: int = CLIP_LENGTH,
                anchor_index: int = ANCHOR_INDEX) -> np.ndarray:
    """Episode frames of the clip around `anchor`: anchor - anchor_index + i, clamped to [0, T_ep - 1]."""
    if not 0 <= anchor < episode_length:
        raise ValueError(f"anchor {anchor} outside the episode [0, {episode_length})")
    if not 0 <= anchor_index < clip_length:
        raise ValueError(f"anchor_index {anchor_index} outside the clip [0, {clip_length})")
    return np.clip(anchor - anchor_index + np.arange(clip_length), 0, episode_length - 1).astype(np.int64)


def make_clip(
    episode, anchor: int, clip_length: int = CLIP_LENGTH, anchor_index: int = ANCHOR_INDEX
) -> EpisodeClip:
    """The clip of `episode` around `anchor` (paper, App. B: 32 frames, anchor at index 16).

    `episode` is any object with the attributes `rgb`, `camera_pose`, `K` and optionally `depth`,
    `body_xpos`, `body_xmat`, `body_seg` (per-frame arrays, leading axis = episode frame), e.g.
    `lerobot_bavo.datasets.recording.EpisodeRecord`.
    """
    n = int(episode.rgb.shape[0])
    return EpisodeClip(
        frames=clip_frames(anchor, n, clip_length, anchor_index),
        K=np.asarray(episode.K, dtype=np.float64),
        episode_rgb=episode.rgb,
        episode_camera_poses=episode.camera_pose,
        episode_depth=getattr(episode, "depth", None),
        episode_body_xpos=getattr(episode, "body_xpos", None),
        episode_body_xmat=getattr(episode, "body_xmat", None),
        episode_body_seg=getattr(episode, "body_seg", None),
        anchor_index=anchor_index,
        episode_length=n,
    )


def point_queries(pixels: np.ndarray, t_src: int, t_tgt: int, t_cam: int) -> np.ndarray:
    """(N, 5) queries (u, v, t_src, t_tgt, t_cam) for source pixels (N, 2) (u, v)."""
    pixels = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    q = np.empty((pixels.shape[0], 5), dtype=np.float64)
    q[:, :2] = pixels
    q[:, 2], q[:, 3], q[:, 4] = t_src, t_tgt, t_cam
    return q


def normalized_uv(queries: np.ndarray, height: int, width: int) -> np.ndarray:
    """D4RT's (u, v) in [0, 1]^2 (pixel centres: (u + 0.5) / W, (v + 0.5) / H) from pixel queries."""
    q = np.asarray(queries, dtype=np.float64)
    return np.stack([(q[:, 0] + 0.5) / width, (q[:, 1] + 0.5) / height], axis=1)


def check_queries(queries: np.ndarray, clip: EpisodeClip) -> np.ndarray:
    """Validate a (Q, 5) query array against a clip; returns it as float64."""
    q = np.asarray(queries, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != 5:
        raise ValueError(f"queries must be (Q, 5) = {QUERY_FIELDS}, got shape {q.shape}")
    t = q[:, 2:]
    if np.any(t != np.round(t)) or (t.size and (t.min() < 0 or t.max() >= clip.length)):
        raise ValueError(f"query times must be integer clip indices in [0, {clip.length})")
    return q


@runtime_checkable
class Teacher(Protocol):
    """A 4D teacher: answers point-aligned queries on a clip with per-query features.

    `feature_dim` is d_T. `answer(clip, queries)` takes a (Q, 5) query array (see the module
    docstring) and returns (Q, feature_dim) float32, row i answering query i. Answers must not
    depend on the other queries in the batch (D4RT decodes queries independently).
    """

    feature_dim: int

    def answer(self, clip: EpisodeClip, queries: np.ndarray) -> np.ndarray: ...

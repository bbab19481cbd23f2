"""The default 4D teacher: exact answers to D4RT's queries from simulator state.

D4RT is trained to predict, for a query q = (u, v, t_src, t_tgt, t_cam), the 3D position at time
t_tgt of the surface point seen at pixel (u, v) of frame t_src, in the camera frame of t_cam.
In simulation that target is known exactly, so the stand-in teacher computes it:

1. P = T_B<-C(t_src) K^-1 [u, v, 1]^T depth_src(v, u): the seen point in the base frame B.
2. b = the body seen at (v, u) at t_src (segmentation of the same render pass); its pose
   (x_b, R_b) at t_src gives the body-local point p = R_b(t_src)^T (P - x_b(t_src)).
3. The point moves rigidly with its body: P' = R_b(t_tgt) p + x_b(t_tgt). Static world geometry
   (body 0, the table) stays put; the occluder is a mocap body that stays put between events and
   jumps when it is re-placed, exactly like any other body.
4. Expressed in the camera frame of t_cam: X = T_B<-C(t_cam)^-1 P' (metres, OpenCV axes).

Feature: X (3 numbers, metres). With `with_visibility=True` a 4th column tells whether the point
is the first surface along its ray at t_tgt, seen from the camera of t_tgt: it projects inside the
image, in front of the camera, and |z - depth_tgt(projected pixel)| < `visibility_tol` (1 cm).
Relations (paper Eq. 4) are computed on the xyz part only: a 0/1 bit measured in the same units
as metres would distort the pairwise distances, so the cache stores visibility separately
(`observation.teacher.visible`). Invalid source pixels (u or v < 0: the view was empty) answer 0
(and visibility 0).
"""

from __future__ import annotations

import numpy as np

from lerobot_bavo.teacher.protocol import (
    ANCHOR_INDEX,
    CLIP_LENGTH,
    EpisodeClip,
    check_queries,
    clip_frames,
    make_clip,
    point_queries,
)

__all__ = ["SimulatorTeacher", "teacher_targets"]


class SimulatorTeacher:
    """Simulator-exact 4D teacher (see the module docstring).

    Args:
        with_visibility: append the visibility bit at t_tgt (feature_dim 4 instead of 3).
        visibility_tol: depth agreement (m) for a point to count as the first surface.
    """

    name = "simulator-exact"

    def __init__(self, with_visibility: bool = False, visibility_tol: float = 0.01):
        self.with_visibility = bool(with_visibility)
        self.visibility_tol = float(visibility_tol)
        self.feature_dim = 4 if self.with_visibility else 3

    def answer(self, clip: EpisodeClip, queries: np.ndarray) -> np.ndarray:
        _require_privileged_state(clip)
        q = check_queries(queries, clip)
        f_src, f_tgt, f_cam = (clip.episode_frames(q[:, i]) for i in (2, 3, 4))
        return self.answer_frames(clip, q[:, 0], q[:, 1], f_src, f_tgt, f_cam)

    def answer_frames(self, episode: EpisodeClip, u, v, f_src, f_tgt, f_cam) -> np.ndarray:
        """`answer` for queries given by *episode* frame indices (Q,) (not clip indices) and pixel coordinates
        u, v (Q,); only `episode`'s per-episode arrays and K are used. Each row is answered independently, so
        `teacher_targets` answers a whole episode's queries in one call with the same numbers as frame by
        frame.
        """
        _require_privileged_state(episode)
        out = np.zeros((len(u), self.feature_dim), dtype=np.float32)
        if len(u) == 0:
            return out
        H, W = episode.image_size
        u = np.asarray(u, dtype=np.float64).round().astype(np.int64)
        v = np.asarray(v, dtype=np.float64).round().astype(np.int64)
        ok = (u >= 0) & (u < W) & (v >= 0) & (v < H)
        if not ok.any():
            return out
        u, v = u[ok], v[ok]
        f_src, f_tgt, f_cam = f_src[ok], f_tgt[ok], f_cam[ok]
        K = episode.K

        # 1. back-project the source pixels into the base frame.
        z = episode.episode_depth[f_src, v, u].astype(np.float64)
        pc = np.stack([(u - K[0, 2]) * z / K[0, 0], (v - K[1, 2]) * z / K[1, 1], z], axis=1)  # (Q, 3) in C
        T_src = episode.episode_camera_poses[f_src]  # (Q, 4, 4)
        P = np.einsum("qij,qj->qi", T_src[:, :3, :3], pc) + T_src[:, :3, 3]

        # 2-3. rigid motion of the body seen at the pixel, from t_src to t_tgt.
        body = episode.episode_body_seg[f_src, v, u].astype(np.int64)
        moving = body > 0  # body 0 (world) and -1 (nothing seen) stay put
        P_tgt = P.copy()
        if moving.any():
            b = body[moving]
            fs, ft = f_src[moving], f_tgt[moving]
            x_s, R_s = episode.episode_body_xpos[fs, b], episode.episode_body_xmat[fs, b]
            x_t, R_t = episode.episode_body_xpos[ft, b], episode.episode_body_xmat[ft, b]
            local = np.einsum("qji,qj->qi", R_s, P[moving] - x_s)  # R_s^T (P - x_s)
            P_tgt[moving] = np.einsum("qij,qj->qi", R_t, local) + x_t

        # 4. into the camera frame of t_cam.
        out[ok, :3] = _to_camera(episode.episode_camera_poses[f_cam], P_tgt)
        if self.with_visibility:
            out[ok, 3] = self._visible(episode, f_tgt, P_tgt)
        return out

    def _visible(self, episode: EpisodeClip, f_tgt: np.ndarray, P: np.ndarray) -> np.ndarray:
        H, W = episode.image_size
        K = episode.K
        X = _to_camera(episode.episode_camera_poses[f_tgt], P)
        z = X[:, 2]
        in_front = z > 1e-6
        zs = np.where(in_front, z, 1.0)
        u = np.round(K[0, 0] * X[:, 0] / zs + K[0, 2]).astype(np.int64)
        v = np.round(K[1, 1] * X[:, 1] / zs + K[1, 2]).astype(np.int64)
        inside = in_front & (u >= 0) & (u < W) & (v >= 0) & (v < H)
        d = episode.episode_depth[f_tgt, np.clip(v, 0, H - 1), np.clip(u, 0, W - 1)]
        return (inside & (np.abs(z - d) < self.visibility_tol)).astype(np.float32)


def _require_privileged_state(clip: EpisodeClip) -> None:
    if not clip.has_privileged_state:
        raise ValueError(
            "SimulatorTeacher needs the clip's privileged simulator state (depth, body_seg, body_xpos, "
            "body_xmat); this clip has none. Use a learned teacher for real data."
        )


def _to_camera(T_b_c: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Points P (Q, 3) in B -> camera frames given per-query T_B<-C (Q, 4, 4): R^T (P - t)."""
    return np.einsum("qji,qj->qi", T_b_c[:, :3, :3], P - T_b_c[:, :3, 3])


def teacher_targets(episode, teacher=None, n_future: int = 15, clip_length: int = CLIP_LENGTH,
                    anchor_index: int = ANCHOR_INDEX) -> dict[str, np.ndarray]:
    """Cached A-FAR teacher targets for every frame of an episode (paper Sec. 4.2, App. B).

    For anchor frame t (clip of `make_clip`, anchor at `anchor_index`, future at
    anchor_index + n_future) and the source pixels of frame t's point cloud:
        z0[t] = teacher(q0 = (u, v, a, a, a)),   zF[t] = teacher(qF = (u, v, a, a + n_future, a + n_future))
    with a = anchor_index. valid[t] = 1 iff t + n_future <= T_ep - 1; otherwise the future clip
    frame is the episode's last frame repeated (clamped), zF answers for that frame, and valid = 0.

    Args:
        episode: per-frame arrays (see `make_clip`) plus `point_pixels` (T_ep, N, 2).
        teacher: a `Teacher`; default `SimulatorTeacher(with_visibility=True)`. Its first 3 columns
            are stored as z0 / zF; a 4th column of the future answer (visibility) as `visible`.

    Returns:
        dict with z0 (T_ep, N, d) float32, zf (T_ep, N, d) float32 (d = 3 for the simulator
        teacher, feature_dim otherwise), visible (T_ep, N) float32 (all 1 when the teacher has no
        visibility output), valid (T_ep,) float32.
    """
    teacher = teacher if teacher is not None else SimulatorTeacher(with_visibility=True)
    future = anchor_index + n_future
    if not (n_future > 0 and future < clip_length):
        raise ValueError(f"anchor_index + n_future = {future} must lie in the clip [0, {clip_length})")
    pixels = np.asarray(episode.point_pixels)
    T, N = pixels.shape[:2]
    vis_col = isinstance(teacher, SimulatorTeacher) and teacher.with_visibility
    d = 3 if vis_col else teacher.feature_dim
    z0 = np.zeros((T, N, d), dtype=np.float32)
    zf = np.zeros((T, N, d), dtype=np.float32)
    visible = np.ones((T, N), dtype=np.float32)
    valid = np.zeros(T, dtype=np.float32)
    if isinstance(teacher, SimulatorTeacher):
        # The whole episode at once (less CPU than 2 T calls of `answer`). Frame t's queries are
        # answered on the clip anchored at t, so their clip indices map to these episode frames.
        clip = make_clip(episode, 0, clip_length, anchor_index)  # only its per-episode arrays are used
        frames = np.arange(T)
        f_future = np.array([clip_frames(t, T, clip_length, anchor_index)[future] for t in frames])
        src = np.repeat(frames, N)
        a0 = teacher.answer_frames(clip, pixels[..., 0].ravel(), pixels[..., 1].ravel(), src, src, src)
        tgt = np.repeat(f_future, N)
        af = teacher.answer_frames(clip, pixels[..., 0].ravel(), pixels[..., 1].ravel(), src, tgt, tgt)
        z0[:], zf[:] = a0[:, :d].reshape(T, N, d), af[:, :d].reshape(T, N, d)
        if vis_col:
            visible[:] = af[:, 3].reshape(T, N)
        valid[:] = (frames + n_future <= T - 1).astype(np.float32)
        return {"z0": z0, "zf": zf, "visible": visible, "valid": valid}
    for t in range(T):
        clip = make_clip(episode, t, clip_length, anchor_index)
        a0 = teacher.answer(clip, point_queries(pixels[t], anchor_index, anchor_index, anchor_index))
        af = teacher.answer(clip, point_queries(pixels[t], anchor_index, future, future))
        z0[t], zf[t] = a0[:, :d], af[:, :d]
        if vis_col:
            visible[t] = af[:, 3]
        valid[t] = float(clip.valid_future(future))
    return {"z0": z0, "zf": zf, "visible": visible, "valid": valid}

"""RGB-D to coloured point cloud, in the robot base frame (DESIGN.md, "Observation").

Pure numpy functions, no state. Units are metres; pixel coordinates are integer indices
(u = column, v = row) whose centres sit at integer values, so the image centre of a W x H
image is ((W - 1) / 2, (H - 1) / 2).

Frames:
    B  robot base frame. In lerobot-bavo it is the MuJoCo world frame (origin on the table
       top, +z up); see `lerobot_bavo/sim/constants.py`.
    C  camera frame, OpenCV convention: x right, y down, z forward along the optical axis.
    Cm MuJoCo's camera frame: x right, y up, looking along -z. Only used when reading a pose
       from MuJoCo; `camera_pose_from_mujoco` converts it to C.

Paper convention: T_B<-C = T_B<-E(q) T_E<-C. MuJoCo already composes the kinematic chain,
so `data.cam_xpos` / `data.cam_xmat` of a camera mounted on the camera arm give T_B<-C
directly once the axes are converted (`camera_pose_from_mujoco`).

The pipeline (`build_point_cloud`) is: stride-subsample pixels, drop invalid depth (and, with a
self-filter, the robot's own pixels: `robot_pixel_mask`), back-project, transform to B, crop to the
workspace box in B, farthest-point sample in B, and return xyz in the requested frame plus rgb in [0, 1]
and each point's source pixel.
"""

from __future__ import annotations

import math

import fpsample
import numpy as np

from lerobot_bavo.features import POINT_FRAMES

# Rotation R_Cm<-C taking OpenCV camera axes (x right, y down, z forward) to MuJoCo camera
# axes (x right, y up, z backward). It is its own inverse.
MUJOCO_TO_OPENCV = np.diag([1.0, -1.0, -1.0])
MUJOCO_TO_OPENCV.setflags(write=False)


# Default pixel step before FPS. At 240x320 -> 256 points, stride 3 keeps <= 80 x 107 = 8560
# candidate pixels and the whole `build_point_cloud` call takes ~1 ms on one core (stride 2:
# ~2-2.5 ms; stride 1: ~6-12 ms, dominated by FPS). Candidate spacing is 3 px, far finer than
# 256 FPS samples resolve.
DEFAULT_STRIDE = 3

# Below this many points, FPS uses fpsample's vanilla O(N n) sampler (exact, starts at index 0);
# above it, the exact bucket/KD-line sampler ("QuickFPS"), ~5-10x faster for thousands of points.
# fpsample 1.0.2's bucket samplers build their KD tree by reordering the points in place and then
# read `start_idx` from the reordered array, so their first sample is not index 0 but a
# deterministic function of the input. The rest is exact FPS from that first sample (identical
# to vanilla FPS started there), which is all we rely on.
_VANILLA_FPS_MAX_POINTS = 2048
_MAX_KDLINE_HEIGHT = 7


def intrinsics_from_fovy(fovy_deg: float, height: int, width: int) -> np.ndarray:
    """Pinhole intrinsics of a MuJoCo camera, square pixels, no skew.

    Args:
        fovy_deg: vertical field of view in degrees (MuJoCo `cam_fovy`), edge to edge of the
            image, in (0, 180).
        height: image height H in pixels.
        width: image width W in pixels.

    Returns:
        K (3, 3) float64: [[f, 0, cx], [0, f, cy], [0, 0, 1]] with f = 0.5 H / tan(fovy / 2)
        in pixels and (cx, cy) = ((W - 1) / 2, (H - 1) / 2), the image centre in pixel-centre
        indices.
    """
    if not 0.0 < fovy_deg < 180.0:
        raise ValueError(f"fovy_deg must be in (0, 180), got {fovy_deg}")
    if height <= 0 or width <= 0:
        raise ValueError(f"height and width must be positive, got height={height}, width={width}")
    f = 0.5 * height / math.tan(math.radians(fovy_deg) / 2.0)
    return np.array(
        [[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0.0, 0.0, 1.0]],
        dtype=np.float64,
    )


def camera_pose_from_mujoco(cam_xpos: np.ndarray, cam_xmat: np.ndarray) -> np.ndarray:
    """T_B<-C of a MuJoCo camera, with C in the OpenCV convention.

    Args:
        cam_xpos: (3,) camera position in B (metres), e.g. `data.cam_xpos[i]`.
        cam_xmat: (9,) row-major or (3, 3) rotation R_B<-Cm, e.g. `data.cam_xmat[i]`; its
            columns are MuJoCo's camera axes (x right, y up, z backward) expressed in B.

    Returns:
        (4, 4) float64 homogeneous transform T_B<-C. The columns of its rotation block are
        the OpenCV camera axes (x right, y down, z forward) expressed in B; its translation is
        the optical centre in B.
    """
    R_b_cm = np.asarray(cam_xmat, dtype=np.float64).reshape(3, 3)
    T = np.eye(4)
    T[:3, :3] = R_b_cm @ MUJOCO_TO_OPENCV
    T[:3, 3] = np.asarray(cam_xpos, dtype=np.float64).reshape(3)
    return T


def _backproject_pixels(u: np.ndarray, v: np.ndarray, z: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Back-project pixels (u, v) with z-depth z (metres) to (N, 3) points in C (OpenCV)."""
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    points = np.empty((z.shape[0], 3), dtype=np.result_type(z.dtype, np.float32))
    points[:, 0] = (u - cx) * (z / fx)
    points[:, 1] = (v - cy) * (z / fy)
    points[:, 2] = z
    return points


def backproject_depth(depth: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Back-project every pixel of a z-depth image into the OpenCV camera frame C.

    Args:
        depth: (H, W) depth in metres, measured along the optical axis (z-depth, as MuJoCo's
            depth renderer returns), not along the ray. Invalid values are passed through.
        K: (3, 3) pinhole intrinsics (pixels), e.g. from `intrinsics_from_fovy`.

    Returns:
        points: (H * W, 3) xyz in C (metres), row-major pixel order (v outer, u inner); same
            float dtype as `depth` (at least float32).
        pixels: (H * W, 2) int64 source pixel (u = column, v = row) of each point.
    """
    depth = np.asarray(depth)
    if depth.ndim != 2:
        raise ValueError(f"depth must be (H, W), got shape {depth.shape}")
    H, W = depth.shape
    v, u = np.divmod(np.arange(H * W, dtype=np.int64), W)
    points = _backproject_pixels(u, v, depth.reshape(-1), np.asarray(K, dtype=np.float64))
    return points, np.stack([u, v], axis=1)


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a homogeneous transform T_A<-F (4, 4) to (N, 3) points in F; returns (N, 3) in A.

    The output dtype follows `points` (float32 stays float32).
    """
    points = np.asarray(points)
    T = np.asarray(T)
    R = T[:3, :3].astype(points.dtype, copy=False)
    t = T[:3, 3].astype(points.dtype, copy=False)
    return points @ R.T + t


def invert_transform(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid transform T_A<-F (4, 4): T_F<-A = [[R^T, -R^T t], [0, 1]]."""
    T = np.asarray(T, dtype=np.float64)
    R_t = T[:3, :3].T
    T_inv = np.eye(4)
    T_inv[:3, :3] = R_t
    T_inv[:3, 3] = -R_t @ T[:3, 3]
    return T_inv


def workspace_mask(points_base: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """Boolean (N,) mask of points inside the axis-aligned box low <= p <= high (inclusive).

    Args:
        points_base: (N, 3) points in B (metres).
        low: (3,) lower corner in B (metres).
        high: (3,) upper corner in B (metres).
    """
    points_base = np.asarray(points_base)
    low = np.asarray(low, dtype=np.float64).reshape(3)
    high = np.asarray(high, dtype=np.float64).reshape(3)
    mask = np.ones(points_base.shape[0], dtype=bool)
    for axis in range(3):  # per-axis column tests: ~2x faster than np.all(..., axis=1)
        column = points_base[:, axis]
        mask &= column >= low[axis]
        mask &= column <= high[axis]
    return mask


def _kdline_height(n_pts: int) -> int:
    """KD-line tree height for fpsample's bucket sampler: ~log2(N) - 9, clipped to [1, 7]."""
    return int(min(_MAX_KDLINE_HEIGHT, max(1, n_pts.bit_length() - 1 - 9)))


def _fps_unique(xyz: np.ndarray, n: int) -> np.ndarray:
    """Exact FPS of n <= N points, as unique int64 indices in sampling order.

    Starts at index 0 for N <= _VANILLA_FPS_MAX_POINTS, else at the KD-line sampler's
    deterministic start (see the note at _VANILLA_FPS_MAX_POINTS).
    """
    n_pts = xyz.shape[0]
    if n_pts <= _VANILLA_FPS_MAX_POINTS:
        idx = fpsample.fps_sampling(xyz, n, start_idx=0)
    else:
        idx = fpsample.bucket_fps_kdline_sampling(xyz, n, h=_kdline_height(n_pts), start_idx=0)
    idx = idx.astype(np.int64)
    # Duplicate coordinates make FPS repeat an index once every distinct position is taken
    # (all remaining distances are 0). Keep the first occurrences in FPS order and fill the
    # rest with the lowest unused indices, so the result is unique and still deterministic.
    uniq, first = np.unique(idx, return_index=True)
    if uniq.shape[0] < n:
        kept = idx[np.sort(first)]
        unused = np.setdiff1d(np.arange(n_pts, dtype=np.int64), kept, assume_unique=True)
        idx = np.concatenate([kept, unused[: n - kept.shape[0]]])
    return idx


def farthest_point_sample(xyz: np.ndarray, n: int) -> np.ndarray:
    """Deterministic farthest-point sampling.

    Uses fpsample's exact samplers: vanilla FPS started at index 0 for N <= 2048, the bucket
    KD-line "QuickFPS" sampler otherwise, whose first sample is a deterministic function of
    the input (fpsample 1.0.2 ignores the requested start; see `_VANILLA_FPS_MAX_POINTS`).
    Either way each later sample is the point farthest from those already taken, and
    identical input gives identical output (no RNG is used).

    Args:
        xyz: (N, 3) points (metres, any frame); computed in float32.
        n: number of indices to return, >= 1.

    Returns:
        (n,) int64 indices into `xyz`, in sampling order. If N >= n they are unique. If N < n,
        all N indices come first (in FPS order) and the sequence is then repeated cyclically
        to length n, i.e. out[i] = order[i % N].

    Raises:
        ValueError: if N == 0 or n < 1.
    """
    xyz = np.asarray(xyz)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise ValueError(f"xyz must be (N, 3), got shape {xyz.shape}")
    if n < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    n_pts = xyz.shape[0]
    if n_pts == 0:
        raise ValueError("farthest_point_sample got an empty point set (N == 0)")
    xyz = np.ascontiguousarray(xyz, dtype=np.float32)
    if n_pts >= n:
        return _fps_unique(xyz, n)
    order = _fps_unique(xyz, n_pts)
    return np.resize(order, n)


def robot_pixel_mask(depth: np.ndarray, robot_depth: np.ndarray, tolerance: float) -> np.ndarray:
    """Pixels whose measured surface is the robot's own body: a robot self-filter, as real robots do it.

    `robot_depth` is a depth render of the robot model alone (its links at the measured joint state, seen from
    the calibrated camera pose), so it needs nothing a real robot does not know. A pixel belongs to the robot
    where that render shows the robot (finite depth) and the measured surface is not in front of it by more
    than `tolerance`; something between the camera and the robot (an object held, the occluder) is kept.

    Args:
        depth: (H, W) measured z-depth, metres.
        robot_depth: (H, W) z-depth of the robot-only render, metres; +inf where it shows no robot.
        tolerance: metres; a measured surface this much nearer than the robot's still counts as the robot.

    Returns:
        (H, W) bool, True on the robot's own pixels.
    """
    depth = np.asarray(depth)
    robot_depth = np.asarray(robot_depth)
    if depth.shape != robot_depth.shape or depth.ndim != 2:
        raise ValueError(f"expected two (H, W) depth images, got {depth.shape} and {robot_depth.shape}")
    if not tolerance >= 0:
        raise ValueError(f"tolerance must be >= 0 metres, got {tolerance}")
    return np.isfinite(robot_depth) & (depth >= robot_depth - tolerance)


def build_point_cloud(
    rgb: np.ndarray,
    depth: np.ndarray,
    K: np.ndarray,
    T_base_cam: np.ndarray,
    n_points: int,
    frame: str = "base",
    workspace_low: np.ndarray | None = None,
    workspace_high: np.ndarray | None = None,
    max_depth: float = 3.0,
    stride: int = DEFAULT_STRIDE,
    drop_pixels: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Coloured, cropped, farthest-point-sampled point cloud from one RGB-D view.

    Steps: keep pixels with u % stride == 0 and v % stride == 0 (stride 1 keeps all), drop
    invalid depth (non-finite, <= 0 or >= max_depth), back-project to C, transform to B with
    T_B<-C, crop to the workspace box in B (always in B, whatever `frame` is), run FPS on the
    B-frame xyz, then express xyz in `frame`.

    Args:
        rgb: (H, W, 3) uint8 image.
        depth: (H, W) z-depth in metres (along the optical axis).
        K: (3, 3) intrinsics of the (full-resolution) image, pixels.
        T_base_cam: (4, 4) T_B<-C, C in the OpenCV convention (`camera_pose_from_mujoco`).
        n_points: number of output points N, >= 1.
        frame: "base" (xyz in B, the default) or "camera" (xyz in C; ablation).
        workspace_low: (3,) lower corner of the crop box in B (metres); None = unbounded.
        workspace_high: (3,) upper corner of the crop box in B (metres); None = unbounded.
        max_depth: depths >= this (metres) are dropped, e.g. background / far plane.
        stride: pixel subsampling step in both axes before FPS, >= 1; 1 keeps every pixel.
            It bounds the FPS cost, the dominant one (see `DEFAULT_STRIDE`). The kept grid
            starts at pixel (0, 0); no randomness is involved.
        drop_pixels: (H, W) bool, pixels never sampled (e.g. `robot_pixel_mask`: the robot's own body);
            None keeps every pixel. Dropped before FPS, so the points go to the rest of the view.

    Returns:
        cloud: (n_points, 6) float32, [x, y, z] in `frame` (metres) and [r, g, b] in [0, 1].
        pixels: (n_points, 2) int32 source pixel (u = column, v = row) of each point, in the
            full-resolution image.
        If fewer than n_points points survive, they are repeated cyclically (see
        `farthest_point_sample`). If none survive (empty view, everything cropped), the cloud
        is all zeros and every pixel is (-1, -1); this never raises, so the env keeps running.

    Raises:
        ValueError: if `frame` is not "base" or "camera", or shapes/arguments are invalid.
    """
    if frame not in POINT_FRAMES:
        raise ValueError(f"frame must be one of {POINT_FRAMES}, got {frame!r}")
    if n_points < 1:
        raise ValueError(f"n_points must be >= 1, got {n_points}")
    if stride < 1:
        raise ValueError(f"stride must be >= 1, got {stride}")
    depth = np.asarray(depth)
    rgb = np.asarray(rgb)
    if depth.ndim != 2 or rgb.shape != (*depth.shape, 3):
        raise ValueError(f"expected rgb (H, W, 3) and depth (H, W), got {rgb.shape} and {depth.shape}")
    K = np.asarray(K, dtype=np.float64)
    T_base_cam = np.asarray(T_base_cam, dtype=np.float64)

    # Stride subsampling and validity, without materialising the full-resolution cloud.
    d = depth[::stride, ::stride]
    d_width = d.shape[1]
    valid = np.isfinite(d) & (d > 0) & (d < max_depth)
    if drop_pixels is not None:
        if np.shape(drop_pixels) != depth.shape:
            raise ValueError(f"drop_pixels must be (H, W) = {depth.shape}, got {np.shape(drop_pixels)}")
        valid &= ~np.asarray(drop_pixels, dtype=bool)[::stride, ::stride]
    flat = np.flatnonzero(valid)  # row-major, strided grid
    z = d.reshape(-1)[flat].astype(np.float32, copy=False)
    v, u = np.divmod(flat, d_width)
    pts_cam = _backproject_pixels(u * stride, v * stride, z, K)  # (M, 3) in C
    pts_base = transform_points(T_base_cam, pts_cam)  # (M, 3) in B

    if workspace_low is not None or workspace_high is not None:
        low = np.full(3, -np.inf) if workspace_low is None else workspace_low
        high = np.full(3, np.inf) if workspace_high is None else workspace_high
        keep = workspace_mask(pts_base, low, high)
        pts_base, flat = pts_base[keep], flat[keep]

    cloud = np.zeros((n_points, 6), dtype=np.float32)
    pixels = np.full((n_points, 2), -1, dtype=np.int32)
    if flat.shape[0] == 0:
        return cloud, pixels

    idx = farthest_point_sample(pts_base, n_points)
    v, u = np.divmod(flat[idx], d_width)
    u, v = u * stride, v * stride  # full-resolution pixel indices
    if frame == "base":
        cloud[:, :3] = pts_base[idx]
    else:  # only the sampled points are needed in C: back-project them again
        cloud[:, :3] = _backproject_pixels(u, v, depth[v, u].astype(np.float32, copy=False), K)
    cloud[:, 3:] = rgb[v, u].astype(np.float32) * np.float32(1.0 / 255.0)
    pixels[:, 0] = u
    pixels[:, 1] = v
    return cloud, pixels

"""Tests for lerobot_bavo.envs.pointcloud, with hand-computed expectations."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lerobot_bavo.envs.pointcloud import (
    MUJOCO_TO_OPENCV,
    backproject_depth,
    build_point_cloud,
    camera_pose_from_mujoco,
    farthest_point_sample,
    intrinsics_from_fovy,
    invert_transform,
    transform_points,
    workspace_mask,
)
from lerobot_bavo.sim.transforms import rot_z


def _rot_x(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


# ---------------------------------------------------------------------------------------------
# Intrinsics and back-projection
# ---------------------------------------------------------------------------------------------
def test_intrinsics_from_fovy_hand_values():
    # fovy 90 deg: tan(45) = 1, so f = 0.5 * 240 = 120 px; centre ((320-1)/2, (240-1)/2).
    K = intrinsics_from_fovy(90.0, 240, 320)
    expected = np.array([[120.0, 0.0, 159.5], [0.0, 120.0, 119.5], [0.0, 0.0, 1.0]])
    assert K.dtype == np.float64
    np.testing.assert_allclose(K, expected)
    # fovy 60 deg, H=4: f = 2 / tan(30 deg) = 2 sqrt(3).
    K = intrinsics_from_fovy(60.0, 4, 6)
    np.testing.assert_allclose(K[0, 0], 2.0 * math.sqrt(3.0))
    np.testing.assert_allclose(K[1, 1], 2.0 * math.sqrt(3.0))
    np.testing.assert_allclose(K[:2, 2], [2.5, 1.5])


def test_intrinsics_reject_bad_fovy():
    with pytest.raises(ValueError, match="fovy"):
        intrinsics_from_fovy(0.0, 4, 4)


def test_backproject_principal_point_and_offset_pixel():
    # 5x7 image, fovy 90: f = 2.5, principal point exactly on pixel (u=3, v=2).
    K = intrinsics_from_fovy(90.0, 5, 7)
    np.testing.assert_allclose(K[:2, 2], [3.0, 2.0])
    depth = np.full((5, 7), 2.0)
    points, pixels = backproject_depth(depth, K)
    assert points.shape == (35, 3) and pixels.shape == (35, 2)
    # Row-major: index = v * W + u.
    np.testing.assert_array_equal(pixels[2 * 7 + 3], [3, 2])
    np.testing.assert_allclose(points[2 * 7 + 3], [0.0, 0.0, 2.0])
    # Pixel (u=5, v=0): x = (5 - 3) * 2 / 2.5 = 1.6, y = (0 - 2) * 2 / 2.5 = -1.6 (y down).
    np.testing.assert_array_equal(pixels[5], [5, 0])
    np.testing.assert_allclose(points[5], [1.6, -1.6, 2.0])
    # Depth is z-depth: every point keeps z = 2.
    np.testing.assert_allclose(points[:, 2], 2.0)


# ---------------------------------------------------------------------------------------------
# Frames
# ---------------------------------------------------------------------------------------------
def test_mujoco_to_opencv_constant():
    np.testing.assert_array_equal(MUJOCO_TO_OPENCV, np.diag([1.0, -1.0, -1.0]))


def test_camera_pose_from_mujoco_looking_down():
    # Identity xmat: MuJoCo camera looks along -z_world with its up (+y) along +y_world.
    T = camera_pose_from_mujoco(np.array([0.1, 0.2, 1.0]), np.eye(3).reshape(9))
    # OpenCV axes in world: x right = +x_w, y down = -y_w, z forward = -z_w.
    np.testing.assert_allclose(T[:3, :3], np.diag([1.0, -1.0, -1.0]))
    np.testing.assert_allclose(T[:3, 3], [0.1, 0.2, 1.0])
    np.testing.assert_allclose(T[3], [0.0, 0.0, 0.0, 1.0])
    # A point 1 m straight ahead lands on the floor below the camera.
    np.testing.assert_allclose(transform_points(T, np.array([[0.0, 0.0, 1.0]])), [[0.1, 0.2, 0.0]])


def test_camera_pose_from_mujoco_looking_along_y():
    # MuJoCo camera looking along +y_world with up +z_world: its z axis (backward) is -y_w,
    # its y axis (up) is +z_w, its x axis (right) is y x z = +x_w. xmat columns are these axes.
    xmat = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    T = camera_pose_from_mujoco(np.array([0.0, -0.5, 0.3]), xmat)
    np.testing.assert_allclose(T[:3, 0], [1.0, 0.0, 0.0])  # x right
    np.testing.assert_allclose(T[:3, 1], [0.0, 0.0, -1.0])  # y down
    np.testing.assert_allclose(T[:3, 2], [0.0, 1.0, 0.0])  # z forward
    assert np.isclose(np.linalg.det(T[:3, :3]), 1.0)
    # Principal-ray point at depth 2 and a point below the image centre (v > cy).
    pts = transform_points(T, np.array([[0.0, 0.0, 2.0], [0.0, 0.5, 2.0]]))
    np.testing.assert_allclose(pts, [[0.0, 1.5, 0.3], [0.0, 1.5, -0.2]])


def test_transform_and_invert_round_trip():
    T = np.eye(4)
    T[:3, :3] = rot_z(math.pi / 2)
    T[:3, 3] = [1.0, 2.0, 3.0]
    # Hand value: Rz(90) maps x to y, so (1, 0, 0) -> (0, 1, 0) + (1, 2, 3).
    np.testing.assert_allclose(transform_points(T, np.array([[1.0, 0.0, 0.0]])), [[1.0, 3.0, 3.0]])
    T_inv = invert_transform(T)
    np.testing.assert_allclose(T_inv @ T, np.eye(4), atol=1e-12)
    np.testing.assert_allclose(T @ T_inv, np.eye(4), atol=1e-12)
    T2 = np.eye(4)
    T2[:3, :3] = _rot_x(0.3) @ rot_z(-1.1)
    T2[:3, 3] = [-0.2, 0.5, 0.9]
    pts = np.random.default_rng(0).normal(size=(20, 3))
    np.testing.assert_allclose(transform_points(invert_transform(T2), transform_points(T2, pts)), pts)
    # float32 stays float32.
    assert transform_points(T2, pts.astype(np.float32)).dtype == np.float32


def test_workspace_mask_inclusive_box():
    pts = np.array(
        [
            [0.5, 0.5, 0.5],  # inside
            [1.0, 1.0, 1.0],  # on the upper corner: inside (inclusive)
            [0.0, 0.0, 0.0],  # on the lower corner: inside
            [1.01, 0.5, 0.5],  # x too large
            [0.5, -0.1, 0.5],  # y too small
            [0.5, 0.5, 2.0],  # z too large
        ]
    )
    mask = workspace_mask(pts, np.zeros(3), np.ones(3))
    assert mask.dtype == bool
    np.testing.assert_array_equal(mask, [True, True, True, False, False, False])


# ---------------------------------------------------------------------------------------------
# Farthest-point sampling
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("n_pts", [300, 6000])  # vanilla path and bucket KD-line path
def test_fps_unique_and_deterministic(n_pts):
    xyz = np.random.default_rng(1).uniform(-1, 1, size=(n_pts, 3))
    idx = farthest_point_sample(xyz, 128)
    assert idx.shape == (128,) and idx.dtype == np.int64
    assert len(np.unique(idx)) == 128
    np.testing.assert_array_equal(idx, farthest_point_sample(xyz.copy(), 128))
    # Exact FPS: each sample maximises the distance to the samples before it.
    d_min = np.full(n_pts, np.inf)
    for k in range(1, 128):
        d_min = np.minimum(d_min, np.linalg.norm(xyz - xyz[idx[k - 1]], axis=1))
        assert np.isclose(d_min[idx[k]], d_min.max(), rtol=1e-5)
    if n_pts <= 2048:
        assert idx[0] == 0  # vanilla path starts at index 0


def test_fps_line_ends_are_chosen():
    # Index 0 is one end: with n = 2 the other end is the farthest point.
    xs = np.linspace(0.0, 1.0, 50)
    rng = np.random.default_rng(2)
    order = np.concatenate([[0], 1 + rng.permutation(49)])
    xyz = np.stack([xs[order], np.zeros(50), np.zeros(50)], axis=1)
    idx = farthest_point_sample(xyz, 2)
    assert set(xyz[idx, 0]) == {0.0, 1.0}
    # Index 0 in the middle (x = 0.5): n = 3 takes both ends.
    xyz[:, 0] = np.roll(xs, -25)
    assert xyz[0, 0] == xs[25]
    idx = farthest_point_sample(xyz, 3)
    assert {0.0, 1.0} <= set(xyz[idx, 0])
    # Long line (KD-line path, any deterministic start): the sample after the start is an end.
    xs = np.linspace(0.0, 1.0, 4001)
    xyz = np.zeros((4001, 3))
    xyz[:, 0] = np.random.default_rng(4).permutation(xs)
    idx = farthest_point_sample(xyz, 8)
    assert xyz[idx[1], 0] in (0.0, 1.0)


def test_fps_pads_cyclically_when_too_few_points():
    xyz = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.2, 0.0, 0.0]])
    idx = farthest_point_sample(xyz, 7)
    assert idx.shape == (7,)
    assert sorted(idx[:3]) == [0, 1, 2]
    np.testing.assert_array_equal(idx, idx[np.arange(7) % 3])
    np.testing.assert_array_equal(idx[:3], [0, 1, 2])  # FPS order: 0, then far end, then 0.2


def test_fps_unique_with_duplicate_points():
    # 100 distinct positions, each repeated 3 times: FPS alone would repeat indices.
    xyz = np.repeat(np.random.default_rng(3).uniform(size=(100, 3)), 3, axis=0)
    idx = farthest_point_sample(xyz, 150)
    assert len(np.unique(idx)) == 150


def test_fps_rejects_empty_and_bad_n():
    with pytest.raises(ValueError, match="empty"):
        farthest_point_sample(np.zeros((0, 3)), 4)
    with pytest.raises(ValueError, match="n must be"):
        farthest_point_sample(np.zeros((4, 3)), 0)


# ---------------------------------------------------------------------------------------------
# build_point_cloud
# ---------------------------------------------------------------------------------------------
H, W = 60, 80
PLANE_Z = 0.05


def _tilted_camera() -> np.ndarray:
    """T_B<-C of a MuJoCo camera 0.8 m up, looking down and pitched 30 deg about x."""
    xmat = _rot_x(math.radians(30.0))  # rotate the downward-looking camera toward +y
    return camera_pose_from_mujoco(np.array([0.1, -0.2, 0.8]), xmat.reshape(9))


def _plane_depth(K: np.ndarray, T: np.ndarray) -> np.ndarray:
    """z-depth of the plane z = PLANE_Z seen by camera T: solve t_z + d * (R ray)_z = PLANE_Z."""
    v, u = np.mgrid[0:H, 0:W]
    ray = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones((H, W))], axis=-1)
    ray_z = ray @ T[2, :3]
    return (PLANE_Z - T[2, 3]) / ray_z


def _rgb() -> np.ndarray:
    v, u = np.mgrid[0:H, 0:W]
    return np.stack([u * 3, v * 4, np.full((H, W), 255)], axis=-1).astype(np.uint8)


@pytest.mark.parametrize("stride", [1, 3])
def test_build_point_cloud_flat_plane(stride):
    K = intrinsics_from_fovy(60.0, H, W)
    T = _tilted_camera()
    depth = _plane_depth(K, T)
    assert np.all(depth > 0)
    rgb = _rgb()
    cloud, pixels = build_point_cloud(rgb, depth, K, T, 64, stride=stride)
    assert cloud.shape == (64, 6) and cloud.dtype == np.float32
    assert pixels.shape == (64, 2) and pixels.dtype == np.int32
    np.testing.assert_allclose(cloud[:, 2], PLANE_Z, atol=1e-5)
    assert np.all((pixels[:, 0] >= 0) & (pixels[:, 0] < W) & (pixels[:, 1] >= 0) & (pixels[:, 1] < H))
    assert np.all(pixels % stride == 0)
    assert len({tuple(p) for p in pixels}) == 64
    u, v = pixels[:, 0], pixels[:, 1]
    np.testing.assert_allclose(cloud[:, 3], u * 3 / 255.0, atol=1e-6)
    np.testing.assert_allclose(cloud[:, 4], v * 4 / 255.0, atol=1e-6)
    np.testing.assert_allclose(cloud[:, 5], 1.0)
    assert cloud[:, 3:].min() >= 0.0 and cloud[:, 3:].max() <= 1.0

    # Camera-frame output: same points and pixels, related by exactly T_B<-C.
    cloud_cam, pixels_cam = build_point_cloud(rgb, depth, K, T, 64, frame="camera", stride=stride)
    np.testing.assert_array_equal(pixels_cam, pixels)
    np.testing.assert_array_equal(cloud_cam[:, 3:], cloud[:, 3:])
    np.testing.assert_allclose(transform_points(T, cloud_cam[:, :3]), cloud[:, :3], atol=1e-5)
    np.testing.assert_allclose(cloud_cam[:, 2], depth[v, u], rtol=1e-6)
    assert not np.allclose(cloud_cam[:, :3], cloud[:, :3])


def test_build_point_cloud_crops_in_base_frame_and_drops_invalid_depth():
    K = intrinsics_from_fovy(60.0, H, W)
    T = _tilted_camera()
    depth = _plane_depth(K, T)
    depth[:, :10] = np.nan
    depth[:, 10:20] = 0.0
    depth[:, 20:30] = np.inf
    depth[:, 30:40] = 5.0  # beyond max_depth
    low, high = np.array([-1.0, 0.0, -1.0]), np.array([1.0, 1.0, 1.0])
    for frame in ("base", "camera"):
        cloud, pixels = build_point_cloud(
            _rgb(), depth, K, T, 32, frame=frame, workspace_low=low, workspace_high=high, stride=1
        )
        assert np.all(pixels[:, 0] >= 40)
        xyz_base = cloud[:, :3] if frame == "base" else transform_points(T, cloud[:, :3])
        assert np.all(xyz_base[:, 1] >= -1e-6)  # the crop (y >= 0) was applied in B
    # Only the lower bound given: the upper side is unbounded.
    cloud, _ = build_point_cloud(_rgb(), depth, K, T, 32, workspace_low=low, stride=2)
    assert np.all(cloud[:, 1] >= -1e-6)


def test_build_point_cloud_empty_view_returns_zeros():
    K = intrinsics_from_fovy(60.0, H, W)
    T = _tilted_camera()
    depth = _plane_depth(K, T)
    cloud, pixels = build_point_cloud(
        _rgb(), depth, K, T, 16, workspace_low=np.full(3, 5.0), workspace_high=np.full(3, 6.0)
    )
    np.testing.assert_array_equal(cloud, np.zeros((16, 6), np.float32))
    np.testing.assert_array_equal(pixels, np.full((16, 2), -1, np.int32))
    cloud, pixels = build_point_cloud(_rgb(), np.zeros((H, W)), K, T, 16)
    assert not cloud.any() and np.all(pixels == -1)


def test_build_point_cloud_pads_when_few_points():
    K = intrinsics_from_fovy(60.0, H, W)
    T = _tilted_camera()
    depth = np.full((H, W), np.nan)
    depth[5, 7] = depth[30, 40] = 0.9
    cloud, pixels = build_point_cloud(_rgb(), depth, K, T, 6, stride=1)
    assert {tuple(p) for p in pixels} == {(7, 5), (40, 30)}
    np.testing.assert_array_equal(cloud[:2], cloud[2:4])


def test_build_point_cloud_bad_frame_raises():
    K = intrinsics_from_fovy(60.0, H, W)
    with pytest.raises(ValueError, match="'world'"):
        build_point_cloud(_rgb(), np.ones((H, W)), K, np.eye(4), 8, frame="world")

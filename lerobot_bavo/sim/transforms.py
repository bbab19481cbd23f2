"""Rotations used across the simulator, the tasks and the experts, each defined once.

Frames: base (world) frame, +z up, metres and radians. Rotation matrices map a frame's axes to
base-frame columns. Quaternions are MuJoCo's (w, x, y, z). A MuJoCo camera looks along its -z with
+y up. The gripper site frame has x = approach direction (out of the gripper), y = finger closing
direction, z = x cross y, so a top-down grasp has x = (0, 0, -1).
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

DOWN = (0.0, 0.0, -1.0)


def rot_z(angle: float) -> np.ndarray:
    """Rotation by `angle` about +z."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rot_from_axes(x_axis, y_axis) -> np.ndarray:
    """Right-handed rotation matrix whose columns are x, y (re-orthogonalised) and x cross y."""
    x = np.asarray(x_axis, float)
    x = x / np.linalg.norm(x)
    y = np.asarray(y_axis, float)
    y = y - x * (x @ y)
    y = y / np.linalg.norm(y)
    return np.column_stack([x, y, np.cross(x, y)])


def yaw_of(rot: np.ndarray) -> float:
    """Heading of a rotation's x axis about +z, in (-pi, pi]."""
    return float(np.arctan2(rot[1, 0], rot[0, 0]))


def face_yaw(rot: np.ndarray) -> float:
    """Yaw of the face normal of a box (cube, block) closest to the world x axis, wrapped to
    [-pi/4, pi/4]: a box's four side faces are 90 degrees apart, so this is the smallest turn
    that aligns a gripper with one of them."""
    yaw = np.arctan2(rot[1, 0], rot[0, 0])
    return (yaw + np.pi / 4) % (np.pi / 2) - np.pi / 4


def topdown_rot(closing_axis, yaw: float | None = None) -> np.ndarray:
    """Gripper pointing straight down, fingers closing along the horizontal `closing_axis`, first
    turned by `yaw` about +z when given."""
    closing = np.asarray(closing_axis, float)
    if yaw is not None:
        closing = rot_z(yaw) @ closing
    return rot_from_axes(DOWN, closing)


def closing_yaw(rot: np.ndarray) -> float:
    """Yaw (rad, about world +z) of a top-down gripper's closing axis, column 1 of its rotation `rot`; 0 =
    fingers closing along world -y. The inverse of `topdown_rot([0, -1, 0], yaw)` for yaw in (-pi, pi]."""
    y = rot[:, 1]
    return float(np.arctan2(y[0], -y[1]))


def slerp_matrix(R0: np.ndarray, R1: np.ndarray, alpha: float) -> np.ndarray:
    """Spherical interpolation between two rotations (shortest arc), alpha in [0, 1]."""
    q0 = np.zeros(4)
    q1 = np.zeros(4)
    mujoco.mju_mat2Quat(q0, R0.reshape(9))
    mujoco.mju_mat2Quat(q1, R1.reshape(9))
    if q0 @ q1 < 0:
        q1 = -q1
    dot = float(np.clip(q0 @ q1, -1.0, 1.0))
    theta = np.arccos(dot)
    if theta < 1e-6:
        q = q1
    else:
        q = (np.sin((1 - alpha) * theta) * q0 + np.sin(alpha * theta) * q1) / np.sin(theta)
    q /= np.linalg.norm(q)
    out = np.zeros(9)
    mujoco.mju_quat2Mat(out, q)
    return out.reshape(3, 3)


def yaw_quat(yaw: float) -> np.ndarray:
    """Quaternion (w, x, y, z) of a rotation by `yaw` about +z."""
    return np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])


def quat_from_axis_angle(axis, angle: float) -> np.ndarray:
    """Quaternion (w, x, y, z) of a rotation by `angle` about `axis`."""
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    half = 0.5 * angle
    return np.array([math.cos(half), *(math.sin(half) * axis)])


def quat_from_matrix(mat: np.ndarray) -> np.ndarray:
    """Quaternion (w, x, y, z) of a rotation matrix."""
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.asarray(mat, dtype=np.float64).reshape(9))
    return quat


def look_at_matrix(pos, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Rotation of a MuJoCo camera at `pos` looking at `target` (it looks along its -z), image up
    as close to `up` as possible: columns right, up, -forward."""
    fwd = np.asarray(target, float) - np.asarray(pos, float)
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, up)
    right /= np.linalg.norm(right)
    cam_up = np.cross(right, fwd)
    return np.column_stack([right, cam_up, -fwd])


def look_at_quat(pos, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Quaternion of `look_at_matrix`."""
    return quat_from_matrix(look_at_matrix(pos, target, up))


def matrices_from_quats(quats: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of unit wxyz quaternions (..., 4), vectorised (MuJoCo's `mju_quat2Mat`
    takes one at a time; a dataset's per-frame poses are tens of thousands)."""
    w, x, y, z = np.moveaxis(np.asarray(quats, dtype=np.float64), -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)

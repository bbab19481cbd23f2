"""Forward kinematics against a hand-written chain, IK round trips, and rendered depth/segmentation
against analytic ray-plane intersections.

The hand-written FK composes the documented offsets and joint axes (constants.py, from AV-ALOHA)
with plain numpy rotations, independently of MuJoCo's kinematics.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from lerobot_bavo.sim import constants as C
from lerobot_bavo.sim.kinematics import ArmKinematics, make_arm_kinematics, rotation_error
from lerobot_bavo.sim.rendering import SceneRenderer
from lerobot_bavo.sim.scene import build_base_spec

CAM_JOINTS = ("waist", "shoulder", "elbow", "forearm_roll", "wrist_1", "wrist_2", "wrist_3")
MANIP_HOME = np.array(C.MANIPULATOR_HOME)
CAM_HOME = np.array([0.0, -0.6, 0.5, 0.0, 0.5, 0.0, 0.0])  # AV-ALOHA MIDDLE_POSE
AV_ALOHA_CAMERA_AT_HOME = np.array([0.0, -0.204, 0.472])


def _rx(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]], float)


def _ry(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]], float)


def _rz(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]], float)


def _chain(base_pos, base_yaw, links, tip):
    """links: [(offset, rotation_fn, angle)], each offset in the previous joint's frame."""
    p = np.asarray(base_pos, float)
    R = _rz(base_yaw)
    for offset, rot, angle in links:
        p = p + R @ np.asarray(offset, float)
        R = R @ rot(angle)
    return p + R @ np.asarray(tip, float), R


def hand_fk_manipulator(mount_pos, mount_yaw, q):
    links = [
        ((0, 0, 0.079), _rz, q[0]),  # waist
        ((0, 0, 0.04805), _ry, q[1]),  # shoulder
        ((0.05955, 0, 0.3), _ry, q[2]),  # elbow
        ((0.2, 0, 0), _rx, q[3]),  # forearm roll
        ((0.1, 0, 0), _ry, q[4]),  # wrist angle
        ((0.069744, 0, 0), _rx, q[5]),  # wrist rotate
    ]
    return _chain(mount_pos, mount_yaw, links, (0.12, 0, 0))  # gripper centre


def hand_fk_camera(q):
    links = [
        ((0, 0, 0.079), _rz, q[0]),
        ((0, 0, 0.04805), _ry, q[1]),
        ((0.05955, 0, 0.3), _ry, q[2]),
        ((0.2, 0, 0), _rx, q[3]),
        ((0.1, 0, 0), _ry, q[4]),  # wrist_1 (pitch)
        ((0.07, 0.000161, 0), _rx, q[5]),  # wrist_2 (roll)
        ((0.04125, 0, 0.02475), _rz, q[6]),  # wrist_3 (yaw)
    ]
    return _chain((0.0, -0.513, 0.02), math.pi / 2, links, (0, 0, 0.04325))  # camera centre


@pytest.fixture(scope="module")
def model():
    return build_base_spec().compile()


@pytest.fixture(scope="module")
def kins(model):
    return make_arm_kinematics(model)


def _joint_limits(model, names):
    ids = [model.joint(n).id for n in names]
    return model.jnt_range[ids, 0].copy(), model.jnt_range[ids, 1].copy()


# --------------------------------------------------------------------------------------------
# forward kinematics
# --------------------------------------------------------------------------------------------
def test_home_camera_position_matches_av_aloha(kins):
    pos, rot = kins["camera"].fk(CAM_HOME)
    assert np.linalg.norm(pos - AV_ALOHA_CAMERA_AT_HOME) < 0.015, pos
    np.testing.assert_allclose(rot.T @ rot, np.eye(3), atol=1e-9)
    # It looks at the workspace: forward (MuJoCo camera -z) points down and away from the operator.
    fwd = -rot[:, 2]
    assert fwd[1] > 0.3 and fwd[2] < -0.5, fwd
    # The optical axis hits the table well inside it, in front of the arms' line.
    t = -pos[2] / fwd[2]
    hit = pos + t * fwd
    assert abs(hit[0]) < 0.05 and -0.2 < hit[1] < 0.3, hit


def test_home_grippers_symmetric_about_x0(kins):
    pl, rl = kins["left"].fk(MANIP_HOME)
    pr, rr = kins["right"].fk(MANIP_HOME)
    np.testing.assert_allclose([pl[0], pl[1], pl[2]], [-pr[0], pr[1], pr[2]], atol=1e-9)
    assert pl[0] < 0 < pr[0] and pl[2] > 0
    # Mirror about the x = 0 plane: the approach axes are mirror images.
    M = np.diag([-1.0, 1.0, 1.0])
    np.testing.assert_allclose(rl[:, 0], M @ rr[:, 0], atol=1e-9)


def test_fk_matches_hand_chain_at_random_configurations(model, kins):
    g = np.random.default_rng(0)
    for side, mount in (("left", C.LEFT_MOUNT), ("right", C.RIGHT_MOUNT)):
        lo, hi = _joint_limits(model, [f"{side}_{j}" for j in C.MANIPULATOR_JOINTS])
        for _ in range(20):
            q = g.uniform(lo, hi)
            pos, rot = kins[side].fk(q)
            hp, hR = hand_fk_manipulator(mount.pos, mount.yaw, q)
            np.testing.assert_allclose(pos, hp, atol=1e-9)
            # The gripper site's x axis is the approach direction (the last link's x axis).
            np.testing.assert_allclose(rot[:, 0], hR[:, 0], atol=1e-9)
    lo, hi = _joint_limits(model, [f"cam_{j}" for j in CAM_JOINTS])
    for _ in range(20):
        q = g.uniform(lo, hi)
        pos, _ = kins["camera"].fk(q)
        np.testing.assert_allclose(pos, hand_fk_camera(q)[0], atol=1e-9)
    np.testing.assert_allclose(hand_fk_camera(CAM_HOME)[0], kins["camera"].fk(CAM_HOME)[0], atol=1e-9)


def test_fk_does_not_touch_live_state(model, kins):
    data = mujoco.MjData(model)
    before = data.qpos.copy()
    kins["left"].fk(MANIP_HOME + 0.3)
    kins["camera"].ik(*kins["camera"].fk(CAM_HOME + 0.1))
    np.testing.assert_array_equal(data.qpos, before)


# --------------------------------------------------------------------------------------------
# IK round trips
# --------------------------------------------------------------------------------------------
def _round_trip_fraction(kin: ArmKinematics, home, lo, hi, n, seed, spread):
    """FK -> IK (from home) -> FK; fraction recovered within 2 mm and 0.02 rad."""
    g = np.random.default_rng(seed)
    lo_s, hi_s = np.maximum(lo, home - spread), np.minimum(hi, home + spread)
    ok = 0
    errors = []
    for _ in range(n):
        q = g.uniform(lo_s, hi_s)
        pos, rot = kin.fk(q)
        res = kin.ik(pos, rot)
        pos2, rot2 = kin.fk(res.qpos)
        e_p = np.linalg.norm(pos2 - pos)
        e_r = np.linalg.norm(rotation_error(rot, rot2))
        errors.append((e_p, e_r))
        ok += bool(e_p < 0.002 and e_r < 0.02)
        assert np.all(res.qpos >= lo - 1e-12) and np.all(res.qpos <= hi + 1e-12)
    return ok / n, np.array(errors)


@pytest.mark.parametrize("spread", [0.5, np.inf], ids=["near_home", "full_range"])
def test_camera_arm_ik_round_trip(model, kins, spread):
    lo, hi = _joint_limits(model, [f"cam_{j}" for j in CAM_JOINTS])
    frac, errors = _round_trip_fraction(kins["camera"], CAM_HOME, lo, hi, 40, 1, spread)
    print(f"camera arm IK round trip ({spread=}): {frac:.2f} within 2 mm / 0.02 rad")
    # Near home the 7-DoF arm always recovers the pose; over the full joint range a local
    # solver from home still succeeds in most cases.
    assert frac >= (0.95 if spread < 1 else 0.5), (frac, np.median(errors, axis=0))


def test_manipulator_ik_round_trip_without_posture_weights(model):
    """The DLS solver itself recovers reachable poses near home (posture regularisation off)."""
    for side in ("left", "right"):
        names = [f"{side}_{j}" for j in C.MANIPULATOR_JOINTS]
        kin = ArmKinematics(model, names, f"{side}_gripper_center", MANIP_HOME)
        lo, hi = _joint_limits(model, names)
        frac, errors = _round_trip_fraction(kin, MANIP_HOME, lo, hi, 30, 2, 0.5)
        print(f"{side} manipulator IK round trip (no posture weights): {frac:.2f}")
        assert frac >= 0.9, (frac, np.median(errors, axis=0))


def test_manipulator_ik_round_trip(model, kins):
    """The arms' configured IK (as the experts use it) recovers reachable poses near home."""
    for side in ("left", "right"):
        lo, hi = _joint_limits(model, [f"{side}_{j}" for j in C.MANIPULATOR_JOINTS])
        frac, errors = _round_trip_fraction(kins[side], MANIP_HOME, lo, hi, 30, 2, 0.5)
        print(f"{side} manipulator IK round trip: {frac:.2f}")
        assert frac >= 0.9, (frac, np.median(errors, axis=0))


def test_manipulator_ik_small_perturbation_converges(kins):
    q = MANIP_HOME + 0.1
    pos, rot = kins["left"].fk(q)
    res = kins["left"].ik(pos, rot)
    assert res.converged and res.position_error < 1e-3


def test_ik_position_only_and_joint_limits(model, kins):
    # A target far out of reach: the solver stays within the joint limits and reports failure.
    res = kins["left"].ik([2.0, 0.0, 0.3])
    lo, hi = _joint_limits(model, [f"left_{j}" for j in C.MANIPULATOR_JOINTS])
    assert not res.converged
    assert np.all(res.qpos >= lo) and np.all(res.qpos <= hi)
    # Position-only target reached from home.
    target = kins["camera"].fk(CAM_HOME)[0] + [0.03, 0.02, -0.02]
    res = kins["camera"].ik(target)
    assert res.converged and np.linalg.norm(kins["camera"].fk(res.qpos)[0] - target) < 2e-3


# --------------------------------------------------------------------------------------------
# rendering: depth and segmentation against analytic ray-plane intersections
# --------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def render_setup(model):
    data = mujoco.MjData(model)
    for side in ("left", "right"):
        for j, v in zip(C.MANIPULATOR_JOINTS, MANIP_HOME):
            data.qpos[model.jnt_qposadr[model.joint(f"{side}_{j}").id]] = v
    H, W = 121, 161  # odd sizes: the centre pixel (60, 80) lies exactly on the optical axis
    renderer = SceneRenderer(model, H, W)
    yield model, data, renderer, H, W
    renderer.close()


def _camera_poses():
    g = np.random.default_rng(3)
    yield CAM_HOME
    for _ in range(7):
        yield CAM_HOME + g.uniform(-0.4, 0.4, 7)


def test_rendered_depth_and_segmentation_match_table_plane(render_setup):
    model, data, renderer, H, W = render_setup
    cam = model.camera(C.ACTIVE_CAMERA).id
    table = model.geom("table").id
    tg_pos, tg_size = model.geom_pos[table], model.geom_size[table]
    top = tg_pos[2] + tg_size[2]  # the table's top plane, from the model
    f = 0.5 * H / math.tan(math.radians(model.cam_fovy[cam]) / 2)
    adr = [model.jnt_qposadr[model.joint(f"cam_{j}").id] for j in CAM_JOINTS]
    checked = 0
    for q in _camera_poses():
        data.qpos[adr] = q
        mujoco.mj_forward(model, data)
        p = data.cam_xpos[cam].copy()
        R = data.cam_xmat[cam].reshape(3, 3).copy()
        fwd = -R[:, 2]
        _, depth = renderer.render_rgbd(data, cam)
        seg = renderer.render_segmentation(data, cam)
        assert depth.shape == (H, W) and seg.shape == (H, W)

        # Centre ray: distance along the optical axis to the table plane.
        if fwd[2] < -1e-3:
            t = (top - p[2]) / fwd[2]
            hit = p + t * fwd
            inside = (
                abs(hit[0] - tg_pos[0]) < tg_size[0] - 0.02 and abs(hit[1] - tg_pos[1]) < tg_size[1] - 0.02
            )
            if inside and seg[60, 80] == table:
                assert abs(depth[60, 80] - t) < 0.005, (q, depth[60, 80], t)
                checked += 1

        # Every table pixel: z-depth of the pixel's ray hitting the table plane. MuJoCo camera
        # frame: x right, y up, looking along -z; image row 0 is the top.
        v, u = np.mgrid[0:H, 0:W]
        d_cam = np.stack([(u - (W - 1) / 2) / f, -(v - (H - 1) / 2) / f, -np.ones((H, W))], axis=-1)
        d_world = d_cam @ R.T  # ray direction with unit z-depth
        with np.errstate(divide="ignore"):
            z_depth = (top - p[2]) / d_world[..., 2]
        mask = (seg == table) & (z_depth > 0)
        if mask.sum() > 100:
            err = np.abs(depth[mask] - z_depth[mask])
            # Interior pixels match tightly; pixels on the table's silhouette edge may mix.
            assert np.percentile(err, 99) < 5e-4, np.percentile(err, [50, 99, 100])
    assert checked >= 4


def test_home_view_centre_is_table(render_setup):
    model, data, renderer, H, W = render_setup
    cam = model.camera(C.ACTIVE_CAMERA).id
    adr = [model.jnt_qposadr[model.joint(f"cam_{j}").id] for j in CAM_JOINTS]
    data.qpos[adr] = CAM_HOME
    mujoco.mj_forward(model, data)
    seg = renderer.render_segmentation(data, cam)
    assert seg[60, 80] == model.geom("table").id
    rgb = renderer.render_rgb(data, cam)
    assert rgb.shape == (H, W, 3) and rgb.dtype == np.uint8
    # Segmentation ids are valid geom ids or -1.
    assert seg.min() >= -1 and seg.max() < model.ngeom


def test_camera_pose_override_does_not_touch_data(render_setup):
    model, data, renderer, H, W = render_setup
    cam = model.camera(C.ACTIVE_CAMERA).id
    adr = [model.jnt_qposadr[model.joint(f"cam_{j}").id] for j in CAM_JOINTS]
    data.qpos[adr] = CAM_HOME
    mujoco.mj_forward(model, data)
    saved = (data.cam_xpos.copy(), data.cam_xmat.copy(), data.qpos.copy())
    _, d0 = renderer.render_rgbd(data, cam)
    # Render from 10 cm higher with the same orientation: the table is farther along the axis.
    pos = data.cam_xpos[cam] + [0, 0, 0.1]
    _, d1 = renderer.render_rgbd(data, cam, pose=(pos, data.cam_xmat[cam]))
    np.testing.assert_array_equal(data.cam_xpos, saved[0])
    np.testing.assert_array_equal(data.cam_xmat, saved[1])
    np.testing.assert_array_equal(data.qpos, saved[2])
    fwd = -data.cam_xmat[cam].reshape(3, 3)[:, 2]
    expected_shift = 0.1 / abs(fwd[2])  # 10 cm up, along a ray that descends at fwd_z
    assert abs((d1[60, 80] - d0[60, 80]) - expected_shift) < 0.005
    _, d2 = renderer.render_rgbd(data, cam)
    np.testing.assert_array_equal(d0, d2)

"""4D-teacher protocol and the simulator-exact teacher (paper Sec. 4.2, Appendix B)."""

from __future__ import annotations

from types import SimpleNamespace

import mujoco
import numpy as np
import pytest

from lerobot_bavo.envs.bavo_env import BavoEnv
from lerobot_bavo.envs.pointcloud import intrinsics_from_fovy
from lerobot_bavo.sim import constants as C
from lerobot_bavo.sim.rendering import SceneRenderer
from lerobot_bavo.sim.transforms import yaw_quat
from lerobot_bavo.teacher import (
    EpisodeClip,
    SimulatorTeacher,
    Teacher,
    clip_frames,
    make_clip,
    normalized_uv,
    point_queries,
    teacher_targets,
)

H, W = 96, 128


@pytest.fixture(scope="module")
def scene_episode():
    """A 3-frame 'episode' made by placing bodies directly (no dynamics):
    frame 0: reset layout; frame 1: the cube translated and turned; frame 2: as 1, camera arm moved."""
    env = BavoEnv(task="cube_handoff", condition="clean", image_height=H, image_width=W, n_points=64,
                  render_mode=None)
    env.reset(seed=0)
    model, data = env.model, env.data
    renderer = SceneRenderer(model, H, W)
    cam = model.camera(C.ACTIVE_CAMERA).id
    cube_body = model.body("cube").id
    adr = model.jnt_qposadr[model.joint("cube_joint").id]
    cam_qadr = [model.jnt_qposadr[model.actuator_trnid[i, 0]] for i in range(14, 21)]
    geom_body = np.append(model.geom_bodyid, -1)
    frames = []
    cube_poses = []

    def snap():
        mujoco.mj_forward(model, data)
        rgb, _ = renderer.render_rgbd(data, cam)
        seg, depth = renderer.render_segmentation(data, cam, with_depth=True)
        frames.append(
            dict(
                rgb=rgb,
                depth=depth,
                body_seg=geom_body[seg].astype(np.int16),
                camera_pose=env.camera_pose(),
                body_xpos=data.xpos.copy(),
                body_xmat=data.xmat.reshape(-1, 3, 3).copy(),
            )
        )
        cube_poses.append((data.xpos[cube_body].copy(), data.xmat[cube_body].reshape(3, 3).copy()))

    snap()
    data.qpos[adr:adr + 3] += [0.04, -0.03, 0.06]
    data.qpos[adr + 3:adr + 7] = yaw_quat(0.6)
    snap()
    for a, dq in zip(cam_qadr[:3], (0.25, 0.1, -0.1)):
        data.qpos[a] += dq
    snap()
    renderer.close()
    env.close()
    ep = SimpleNamespace(**{k: np.stack([f[k] for f in frames]) for k in frames[0]},
                         K=intrinsics_from_fovy(C.ACTIVE_CAMERA_FOVY, H, W))
    return ep, cube_body, cube_poses


def _pixel_of(ep, body, frame=0):
    vs, us = np.nonzero(ep.body_seg[frame] == body)
    assert vs.size > 20, "the body must be in view"
    i = len(vs) // 2
    return int(us[i]), int(vs[i])


def _to_base(ep, X, t_cam):
    T = ep.camera_pose[t_cam]
    return T[:3, :3] @ X + T[:3, 3]


def test_simulator_teacher_is_a_teacher():
    assert isinstance(SimulatorTeacher(), Teacher)
    assert SimulatorTeacher().feature_dim == 3 and SimulatorTeacher(with_visibility=True).feature_dim == 4


def test_moving_point_moves_with_its_object_and_static_point_stays(scene_episode):
    ep, cube_body, cube_poses = scene_episode
    clip = make_clip(ep, anchor=0, clip_length=3, anchor_index=0)
    teacher = SimulatorTeacher(with_visibility=True)
    u_c, v_c = _pixel_of(ep, cube_body)
    u_t, v_t = _pixel_of(ep, 0)  # static world geometry (the table)
    q = np.array(
        [[u_c, v_c, 0, t, t] for t in range(3)] + [[u_t, v_t, 0, t, t] for t in range(3)], dtype=float
    )
    ans = teacher.answer(clip, q)
    assert ans.shape == (6, 4) and ans.dtype == np.float32

    # The cube point at t_src = 0 in the base frame, from depth and intrinsics (independently of the teacher).
    K = ep.K
    z = ep.depth[0, v_c, u_c]
    P0 = _to_base(ep, np.array([(u_c - K[0, 2]) * z / K[0, 0], (v_c - K[1, 2]) * z / K[1, 1], z]), 0)
    np.testing.assert_allclose(_to_base(ep, ans[0, :3].astype(float), 0), P0, atol=1e-5)
    (x0, R0), (x1, R1) = cube_poses[0], cube_poses[1]
    P1 = R1 @ R0.T @ (P0 - x0) + x1  # rigid motion of the cube from frame 0 to frame 1
    for t in (1, 2):
        np.testing.assert_allclose(_to_base(ep, ans[t, :3].astype(float), t), P1, atol=1e-5)
    assert np.linalg.norm(P1 - P0) > 0.05  # it really moved
    # ... and the moved point lies on the cube's surface at frame 1: the cube's own depth there.
    X1 = ans[1, :3].astype(float)
    u1 = int(round(K[0, 0] * X1[0] / X1[2] + K[0, 2]))
    v1 = int(round(K[1, 1] * X1[1] / X1[2] + K[1, 2]))
    assert ans[1, 3] == 1.0
    assert ep.body_seg[1, v1, u1] == cube_body
    assert abs(ep.depth[1, v1, u1] - X1[2]) < 0.01
    # Every cube pixel of frame 0 that the teacher calls visible at frame 1 lands on the cube there.
    vs, us = np.nonzero(ep.body_seg[0] == cube_body)
    qa = np.column_stack([us, vs, np.zeros_like(us), np.ones_like(us), np.ones_like(us)]).astype(float)
    a = teacher.answer(clip, qa)
    vis = a[:, 3] == 1.0
    assert 0.2 < vis.mean() < 1.0  # the turned cube shows some new faces and hides some old ones
    Xv = a[vis, :3].astype(float)
    uv = np.round(Xv[:, :2] / Xv[:, 2:] * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]).astype(int)
    assert (ep.body_seg[1, uv[:, 1], uv[:, 0]] == cube_body).all()

    # The static point stays put in the base frame for every t_tgt, whatever camera expresses it.
    Pt = _to_base(ep, ans[3, :3].astype(float), 0)
    for t in (1, 2):
        np.testing.assert_allclose(_to_base(ep, ans[3 + t, :3].astype(float), t), Pt, atol=1e-5)
    # In camera coordinates it does move when the camera moves (frame 2), not when only the cube does.
    np.testing.assert_allclose(ans[4, :3], ans[3, :3], atol=1e-5)
    assert np.linalg.norm(ans[5, :3] - ans[3, :3]) > 0.01
    # q0 = (u, v, t, t, t): the point is where the pixel sees it, so it is visible.
    assert ans[0, 3] == 1.0 and ans[3, 3] == 1.0


def test_answers_are_independent_of_the_other_queries(scene_episode):
    ep, cube_body, _ = scene_episode
    clip = make_clip(ep, anchor=1, clip_length=3, anchor_index=1)
    rng = np.random.default_rng(0)
    q = np.column_stack([rng.integers(0, W, 50), rng.integers(0, H, 50), rng.integers(0, 3, (50, 3))]).astype(
        float
    )
    teacher = SimulatorTeacher(with_visibility=True)
    full = teacher.answer(clip, q)
    for i in (0, 17, 49):
        np.testing.assert_array_equal(teacher.answer(clip, q[i:i + 1])[0], full[i])
    # An invalid source pixel (empty view) answers zeros.
    assert not teacher.answer(clip, np.array([[-1, -1, 0, 1, 1.0]])).any()
    with pytest.raises(ValueError, match="query times"):
        teacher.answer(clip, np.array([[1, 1, 0, 3, 0.0]]))
    with pytest.raises(ValueError, match="privileged"):
        teacher.answer(
            EpisodeClip(frames=[0, 1], K=ep.K, episode_rgb=ep.rgb, episode_camera_poses=ep.camera_pose), q[:2]
        )


def test_clip_construction_clamps_at_the_episode_boundaries():
    np.testing.assert_array_equal(clip_frames(20, 100), np.arange(4, 36))
    # frames before the start repeat frame 0
    np.testing.assert_array_equal(clip_frames(3, 100)[:14], np.zeros(14))
    assert clip_frames(3, 100)[16] == 3 and clip_frames(3, 100)[31] == 18
    late = clip_frames(90, 100)  # t + 15 = 105 > 99
    assert late[16] == 90 and late[25] == 99 and late[31] == 99
    ep = SimpleNamespace(
        rgb=np.zeros((100, 4, 4, 3), np.uint8), camera_pose=np.tile(np.eye(4), (100, 1, 1)), K=np.eye(3)
    )
    assert make_clip(ep, 84).valid_future() and not make_clip(ep, 85).valid_future()
    assert make_clip(ep, 50).rgb.shape == (32, 4, 4, 3)


def test_query_helpers():
    q = point_queries(np.array([[3, 4], [0, 7]]), 16, 31, 31)
    np.testing.assert_array_equal(q, [[3, 4, 16, 31, 31], [0, 7, 16, 31, 31]])
    np.testing.assert_allclose(normalized_uv(q, height=8, width=4), [[0.875, 0.5625], [0.125, 0.9375]])


def test_teacher_targets_on_a_recorded_rollout():
    """Real expert rollout (short): z0 is the camera-frame point cloud; valid marks t + 15 <= T - 1."""
    from lerobot_bavo.datasets.recording import EpisodeRecorder
    from lerobot_bavo.features import ObservationSettings

    rec = EpisodeRecorder("cube_handoff", "stage", ObservationSettings(48, 64, 32), episode_length=24)
    try:
        record = rec.record(seed=5)
    finally:
        rec.close()
    assert record.length == 24 and record.depth.shape == (24, 48, 64)
    out = teacher_targets(record)
    P = record.point_cloud[..., :3].astype(np.float64)
    T = record.camera_pose
    cam = np.einsum("tji,tnj->tni", T[:, :3, :3], P - T[:, None, :3, 3])
    np.testing.assert_allclose(out["z0"], cam, atol=1e-4)
    np.testing.assert_array_equal(out["valid"], (np.arange(24) + 15 <= 23).astype(np.float32))
    assert out["zf"].shape == (24, 32, 3) and out["visible"].shape == (24, 32)
    # The camera arm moves during the first recovery: future camera-frame answers differ from current ones.
    assert np.abs(out["zf"] - out["z0"]).max() > 0.01
    # Deterministic.
    np.testing.assert_array_equal(teacher_targets(record)["zf"], out["zf"])


def test_whole_episode_targets_equal_the_frame_by_frame_answers():
    """`teacher_targets` answers a whole episode in one call (issue 11); the numbers are exactly those of
    answering each anchor frame's two query sets on its own clip (the definition, paper App. B)."""
    from lerobot_bavo.datasets.recording import EpisodeRecorder
    from lerobot_bavo.features import ObservationSettings

    rec = EpisodeRecorder("block_stacking", "stage", ObservationSettings(120, 160, 64), episode_length=60)
    try:
        record = rec.record(seed=2)
    finally:
        rec.close()
    out = teacher_targets(record)
    teacher = SimulatorTeacher(with_visibility=True)
    T = record.length
    for t in range(T):
        clip = make_clip(record, t)
        a0 = teacher.answer(clip, point_queries(record.point_pixels[t], 16, 16, 16))
        af = teacher.answer(clip, point_queries(record.point_pixels[t], 16, 31, 31))
        np.testing.assert_array_equal(out["z0"][t], a0[:, :3])
        np.testing.assert_array_equal(out["zf"][t], af[:, :3])
        np.testing.assert_array_equal(out["visible"][t], af[:, 3])
        assert out["valid"][t] == float(clip.valid_future(31))
    assert 0 < out["visible"].mean() < 1 and out["valid"].sum() == T - 15

"""BavoEnv: spaces, observation copies, determinism, point-cloud geometry, milestones, bad input.

Expectations are computed independently of the code under test: joint limits are read from the
compiled model by joint name, intrinsics from the model's fovy, chamfer distances and pinhole
projections with plain numpy in this file.
"""

from __future__ import annotations

import copy
import math

import mujoco
import numpy as np
import pytest

from lerobot_bavo.envs.bavo_env import BavoEnv
from lerobot_bavo.experts import make_expert
from lerobot_bavo.sim.constants import MANIPULATOR_JOINTS
from lerobot_bavo.sim.rendering import SceneRenderer

SMALL = dict(image_height=96, image_width=128, n_points=64, render_mode=None)

CAM_JOINTS = ("waist", "shoulder", "elbow", "forearm_roll", "wrist_1", "wrist_2", "wrist_3")
# 21-dim layout: left 6 + gripper, right 6 + gripper, camera arm 7.
JOINT_NAMES = (
    [f"left_{j}" for j in MANIPULATOR_JOINTS] + [None]
    + [f"right_{j}" for j in MANIPULATOR_JOINTS] + [None]
    + [f"cam_{j}" for j in CAM_JOINTS]
)
HOME = np.array(
    [0, -0.082, 1.06, 0, -0.953, 0, 1.0, 0, -0.082, 1.06, 0, -0.953, 0, 1.0, 0, -0.6, 0.5, 0, 0.5, 0, 0],
    dtype=np.float64,
)


# --------------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def small_env():
    env = BavoEnv(**SMALL)
    yield env
    env.close()


def _flatten(obs: dict) -> dict[str, np.ndarray]:
    return {
        "agent_pos": obs["agent_pos"],
        "pixels/active": obs["pixels"]["active"],
        "point_cloud": obs["point_cloud"],
        "point_pixels": obs["point_pixels"],
    }


def _assert_obs_identical(a: dict, b: dict) -> None:
    fa, fb = _flatten(a), _flatten(b)
    for key in fa:
        assert fa[key].dtype == fb[key].dtype, key
        assert np.array_equal(fa[key], fb[key]), f"observation {key!r} differs"


def _assert_info_identical(a: dict, b: dict) -> None:
    assert a["progress"] == b["progress"]
    assert np.array_equal(a["camera_pose"], b["camera_pose"])
    assert a["object_poses"].keys() == b["object_poses"].keys()
    for name in a["object_poses"]:
        assert np.array_equal(a["object_poses"][name], b["object_poses"][name]), name


def _chamfer(a: np.ndarray, b: np.ndarray) -> float:
    """Symmetric chamfer distance: mean of the two mean nearest-neighbour distances (metres)."""
    d = np.linalg.norm(a[:, None, :].astype(np.float64) - b[None, :, :].astype(np.float64), axis=-1)
    return 0.5 * (d.min(axis=1).mean() + d.min(axis=0).mean())


def _focal(env: BavoEnv) -> float:
    fovy = float(env.model.cam_fovy[env.model.camera("cam_active").id])
    return 0.5 * env.obs_settings.image_height / math.tan(math.radians(fovy) / 2)


def _project(points_base: np.ndarray, T_base_cam: np.ndarray, f: float, H: int, W: int):
    """Pinhole projection (OpenCV camera: x right, y down, z forward) -> u, v, z."""
    R, t = T_base_cam[:3, :3], T_base_cam[:3, 3]
    pc = (points_base.astype(np.float64) - t) @ R  # R^T (p - t), row-wise
    z = pc[:, 2]
    u = f * pc[:, 0] / z + (W - 1) / 2
    v = f * pc[:, 1] / z + (H - 1) / 2
    return u, v, z


def _assert_rigid(T: np.ndarray) -> None:
    assert T.shape == (4, 4)
    R = T[:3, :3]
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-9)
    assert abs(np.linalg.det(R) - 1.0) < 1e-9
    np.testing.assert_array_equal(T[3], [0, 0, 0, 1])


# --------------------------------------------------------------------------------------------
# spaces, shapes, dtypes
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "kwargs, H, W, N",
    [(dict(render_mode=None), 240, 320, 256), (SMALL, 96, 128, 64)],
    ids=["default", "small"],
)
def test_observation_shapes_dtypes_and_space_membership(kwargs, H, W, N):
    env = BavoEnv(**kwargs)
    try:
        obs, info = env.reset(seed=0)
        assert set(obs) == {"agent_pos", "pixels", "point_cloud", "point_pixels"}
        assert set(obs["pixels"]) == {"active"}
        assert obs["agent_pos"].shape == (21,) and obs["agent_pos"].dtype == np.float32
        assert obs["pixels"]["active"].shape == (H, W, 3) and obs["pixels"]["active"].dtype == np.uint8
        assert obs["point_cloud"].shape == (N, 6) and obs["point_cloud"].dtype == np.float32
        assert obs["point_pixels"].shape == (N, 2) and obs["point_pixels"].dtype == np.int32
        assert env.observation_space.contains(obs)
        # The declared sub-spaces carry the same shapes and dtypes.
        space = env.observation_space
        assert space["agent_pos"].shape == (21,) and space["agent_pos"].dtype == np.float32
        assert space["pixels"]["active"].shape == (H, W, 3) and space["pixels"]["active"].dtype == np.uint8
        assert space["point_cloud"].shape == (N, 6) and space["point_cloud"].dtype == np.float32
        assert space["point_pixels"].shape == (N, 2) and space["point_pixels"].dtype == np.int32
        # The state at reset is the home pose (grippers open = 1).
        np.testing.assert_allclose(obs["agent_pos"], HOME, atol=1e-5)
        # rgb in [0, 1], the image is not blank.
        assert obs["point_cloud"][:, 3:].min() >= 0.0 and obs["point_cloud"][:, 3:].max() <= 1.0
        assert obs["pixels"]["active"].std() > 5

        obs, reward, terminated, truncated, info = env.step(HOME)
        assert env.observation_space.contains(obs)
        assert isinstance(reward, float)
        assert isinstance(terminated, bool) and isinstance(truncated, bool)
        assert info["progress"] == 0 and info["is_success"] is False
        assert set(info["milestones"]) == {"m1", "m2", "m3", "m4", "m5"}
        assert info["camera_pose"].shape == (4, 4)
        for name in ("cube", "plate"):
            pose = info["object_poses"][name]
            assert pose.shape == (7,)
            assert abs(np.linalg.norm(pose[3:]) - 1) < 1e-6
    finally:
        env.close()


def test_action_space_bounds_equal_model_joint_limits(small_env):
    env = small_env
    space = env.action_space
    assert space.shape == (21,) and space.dtype == np.float32
    expected_lo = np.empty(21)
    expected_hi = np.empty(21)
    for i, name in enumerate(JOINT_NAMES):
        if name is None:  # grippers: normalised opening
            expected_lo[i], expected_hi[i] = 0.0, 1.0
        else:
            jid = mujoco.mj_name2id(env.model, mujoco.mjtObj.mjOBJ_JOINT, name)
            assert jid >= 0, name
            assert env.model.jnt_limited[jid], name
            expected_lo[i], expected_hi[i] = env.model.jnt_range[jid]
    np.testing.assert_array_equal(space.low, expected_lo.astype(np.float32))
    np.testing.assert_array_equal(space.high, expected_hi.astype(np.float32))
    assert np.all(space.low < space.high)
    assert space.contains(HOME.astype(np.float32))


def test_out_of_range_action_is_clipped_to_joint_limits(small_env):
    env = small_env
    env.reset(seed=0)
    a = HOME.copy()
    a[14] = 10.0  # camera waist, far beyond +3.14158
    a[6] = 5.0  # left gripper beyond fully open
    env.step(a)
    cam_waist = env.model.actuator("cam_waist").id
    assert env.data.ctrl[cam_waist] <= env.model.jnt_range[env.model.joint("cam_waist").id, 1] + 1e-6
    grip = env.model.actuator("left_gripper").id
    assert env.data.ctrl[grip] <= env.model.actuator_ctrlrange[grip, 1] + 1e-9


def test_render_returns_third_person_and_active_panels():
    env = BavoEnv(image_height=48, image_width=64, n_points=16, render_height=60)
    try:
        env.reset(seed=0)
        frame = env.render()
        assert frame.shape == (60, 160, 3) and frame.dtype == np.uint8
        assert frame[:, :80].std() > 5 and frame[:, 80:].std() > 5
    finally:
        env.close()


def test_camera_pose_is_forward_kinematics_of_the_observed_state(small_env):
    env = small_env
    env.reset(seed=0)
    a = HOME.copy()
    a[14] += 0.5  # camera waist: a fast move
    a[15] += 0.2
    for _ in range(3):
        obs, _, _, _, info = env.step(a)
        q_cam = env.joint_state()[14:]
        pos, rot = env.kinematics["camera"].fk(q_cam)
        # MuJoCo camera (x right, y up, back) -> OpenCV (x right, y down, forward)
        expected = rot @ np.diag([1.0, -1.0, -1.0])
        np.testing.assert_allclose(info["camera_pose"][:3, 3], pos, atol=1e-5)
        np.testing.assert_allclose(info["camera_pose"][:3, :3], expected, atol=1e-5)
        np.testing.assert_allclose(obs["agent_pos"][14:], q_cam, atol=1e-6)


# --------------------------------------------------------------------------------------------
# observations are copies
# --------------------------------------------------------------------------------------------
def test_observations_and_info_are_copies(small_env):
    env = small_env
    obs, info = env.reset(seed=3)
    saved_obs, saved_info = copy.deepcopy(obs), copy.deepcopy(info)
    for arr in _flatten(obs).values():
        for live in (env.data.qpos, env.data.qvel, env.data.xpos, env.data.cam_xpos, env.data.cam_xmat):
            assert not np.shares_memory(arr, live)

    # Stepping (the robot and the camera move) does not alter previously returned objects.
    a = HOME.copy()
    a[14] += 0.2
    a[1] += 0.2
    for _ in range(3):
        env.step(a)
    _assert_obs_identical(obs, saved_obs)
    _assert_info_identical(info, saved_info)

    # Mutating what was returned does not alter the simulator.
    obs2, _, _, _, info2 = env.step(a)
    q_before = env.joint_state()
    pose_before = env.camera_pose()
    cube_before = env.data.body("cube").xpos.copy()
    obs2["agent_pos"][:] = 123.0
    obs2["point_cloud"][:] = -7.0
    obs2["pixels"]["active"][:] = 0
    info2["camera_pose"][:] = 0.0
    for pose in info2["object_poses"].values():
        pose[:] = 9.0
    np.testing.assert_array_equal(env.joint_state(), q_before)
    np.testing.assert_array_equal(env.camera_pose(), pose_before)
    np.testing.assert_array_equal(env.data.body("cube").xpos, cube_before)


# --------------------------------------------------------------------------------------------
# determinism
# --------------------------------------------------------------------------------------------
def _actions(n: int) -> list[np.ndarray]:
    g = np.random.default_rng(1234)
    return [
        HOME + np.concatenate([g.normal(0, 0.03, 6), [0], g.normal(0, 0.03, 6), [0], g.normal(0, 0.03, 7)])
        for _ in range(n)
    ]


def _rollout(env: BavoEnv, seed: int, actions) -> list[tuple[dict, dict]]:
    out = [env.reset(seed=seed)]
    for a in actions:
        obs, _, _, _, info = env.step(a)
        out.append((obs, info))
    return out


def test_same_seed_gives_identical_observations_and_info(small_env):
    actions = _actions(4)
    first = _rollout(small_env, 7, actions)
    # Another episode in between, and the global numpy RNG reseeded and consumed.
    small_env.reset(seed=99)
    np.random.seed(4321)
    np.random.rand(1000)
    second = _rollout(small_env, 7, actions)
    for (o1, i1), (o2, i2) in zip(first, second):
        _assert_obs_identical(o1, o2)
        _assert_info_identical(i1, i2)
    # A fresh env instance (its own renderer / GL context) gives the same episode.
    other = BavoEnv(**SMALL)
    try:
        third = _rollout(other, 7, actions)
    finally:
        other.close()
    for (o1, i1), (o3, i3) in zip(first, third):
        _assert_obs_identical(o1, o3)
        _assert_info_identical(i1, i3)


def test_global_numpy_rng_does_not_affect_layout(small_env):
    np.random.seed(0)
    _, info_a = small_env.reset(seed=11)
    np.random.seed(1)
    np.random.standard_normal(17)
    _, info_b = small_env.reset(seed=11)
    _assert_info_identical(info_a, info_b)


def test_different_seeds_give_different_layouts(small_env):
    poses = []
    for seed in range(5):
        _, info = small_env.reset(seed=seed)
        poses.append(np.concatenate([info["object_poses"]["cube"], info["object_poses"]["plate"]]))
    for i in range(len(poses)):
        for j in range(i + 1, len(poses)):
            assert np.abs(poses[i] - poses[j]).max() > 1e-3, (i, j)
    # Unseeded resets continue the env's own stream: no repeat of the seeded layout.
    _, info0 = small_env.reset(seed=0)
    _, info_next = small_env.reset()
    assert not np.allclose(info0["object_poses"]["cube"], info_next["object_poses"]["cube"])


# --------------------------------------------------------------------------------------------
# point clouds
# --------------------------------------------------------------------------------------------
def _two_camera_poses(point_frame: str, seed: int = 0):
    """Observations from two camera-arm poses of one static scene (manipulators held still)."""
    env = BavoEnv(n_points=512, point_frame=point_frame, render_mode=None)
    try:
        obs, info = env.reset(seed=seed)
        hold = env.joint_state()
        for _ in range(3):
            obs, _, _, _, info = env.step(hold)
        first = (obs, info, env.joint_state())
        moved = hold.copy()
        moved[14] += 0.3  # cam waist
        moved[18] += 0.15  # cam wrist_1
        moved[20] += 0.1  # cam wrist_3
        for _ in range(40):
            obs, _, _, _, info = env.step(moved)
        second = (obs, info, env.joint_state())
        return first, second, moved, _focal(env), env.obs_settings.image_height, env.obs_settings.image_width
    finally:
        env.close()


@pytest.fixture(scope="module")
def two_views():
    return {frame: _two_camera_poses(frame) for frame in ("base", "camera")}


def test_base_frame_clouds_agree_across_camera_poses(two_views):
    (o1, i1, q1), (o2, i2, q2), moved, f, H, W = two_views["base"]
    # Only the camera arm moved, and it reached its target; the objects stayed put.
    np.testing.assert_allclose(q2[:14], q1[:14], atol=1e-4)
    np.testing.assert_allclose(q2[14:], moved[14:], atol=0.01)
    for name in ("cube", "plate"):
        np.testing.assert_allclose(i2["object_poses"][name], i1["object_poses"][name], atol=1e-4)

    T1, T2 = i1["camera_pose"], i2["camera_pose"]
    _assert_rigid(T1)
    _assert_rigid(T2)
    moved_by = np.linalg.norm(T1[:3, 3] - T2[:3, 3])
    turned_by = math.acos(np.clip((np.trace(T1[:3, :3].T @ T2[:3, :3]) - 1) / 2, -1, 1))
    assert moved_by > 0.05 and turned_by > 0.2, (moved_by, turned_by)

    # Compare static geometry seen by both cameras: low points (table region, below 0.15 m)
    # that project inside the *other* camera's image.
    def common(p, T_other):
        u, v, z = _project(p, T_other, f, H, W)
        m = 10
        return (z > 0) & (u >= m) & (u <= W - 1 - m) & (v >= m) & (v <= H - 1 - m) & (p[:, 2] < 0.15)

    p1, p2 = o1["point_cloud"][:, :3], o2["point_cloud"][:, :3]
    k1, k2 = common(p1, T2), common(p2, T1)
    assert k1.sum() > 50 and k2.sum() > 50
    base_cd = _chamfer(p1[k1], p2[k2])
    assert base_cd < 0.02, base_cd

    # The same scene and the same selected points, expressed in the camera frame, disagree.
    (c1, _, _), (c2, _, _), *_ = two_views["camera"]
    cam_cd = _chamfer(c1["point_cloud"][k1, :3], c2["point_cloud"][k2, :3])
    assert cam_cd > 5 * base_cd, (cam_cd, base_cd)


def test_camera_frame_cloud_is_base_cloud_seen_from_the_camera(two_views):
    # Same seed and actions: the same pixels are sampled (FPS runs in the base frame), and the
    # camera-frame xyz maps to the base-frame xyz through info["camera_pose"] = T_B<-C.
    for k in (0, 1):
        ob, ib, _ = two_views["base"][k]
        oc, ic, _ = two_views["camera"][k]
        np.testing.assert_array_equal(ob["point_pixels"], oc["point_pixels"])
        np.testing.assert_array_equal(ib["camera_pose"], ic["camera_pose"])
        np.testing.assert_array_equal(ob["point_cloud"][:, 3:], oc["point_cloud"][:, 3:])
        T = ib["camera_pose"]
        pc = oc["point_cloud"][:, :3].astype(np.float64)
        np.testing.assert_allclose(pc @ T[:3, :3].T + T[:3, 3], ob["point_cloud"][:, :3], atol=1e-5)
        # OpenCV convention: every point is in front of the camera.
        assert pc[:, 2].min() > 0.05


def test_point_pixels_rgb_and_projection(two_views):
    for k in (0, 1):
        obs, info, _ = two_views["base"][k]
        _, _, _, f, H, W = two_views["base"]
        pix = obs["point_pixels"]
        u, v = pix[:, 0], pix[:, 1]
        assert u.min() >= 0 and u.max() < W and v.min() >= 0 and v.max() < H
        rgb = obs["pixels"]["active"][v, u].astype(np.float64) / 255.0
        np.testing.assert_allclose(obs["point_cloud"][:, 3:], rgb, atol=1e-6)
        # Each base-frame point projects back onto its own source pixel.
        pu, pv, pz = _project(obs["point_cloud"][:, :3], info["camera_pose"], f, H, W)
        assert pz.min() > 0
        np.testing.assert_allclose(pu, u, atol=0.02)
        np.testing.assert_allclose(pv, v, atol=0.02)
        # Cropped to the workspace box, above the table top.
        xyz = obs["point_cloud"][:, :3]
        assert (
            xyz[:, 2].min() >= 0.003 and np.abs(xyz[:, 0]).max() <= 0.611 and np.abs(xyz[:, 1]).max() <= 0.371
        )
        # 512 distinct points.
        assert np.unique(pix, axis=0).shape[0] == pix.shape[0]


def test_point_cloud_is_metric_on_known_objects():
    """Points whose pixel shows the cube or the plate lie on that object's true geometry."""
    env = BavoEnv(n_points=512, render_mode=None)
    try:
        obs, info = env.reset(seed=5)
        for _ in range(3):
            obs, _, _, _, info = env.step(HOME)
        seg_renderer = SceneRenderer(env.model, env.obs_settings.image_height, env.obs_settings.image_width)
        try:
            seg = seg_renderer.render_segmentation(env.data, env.model.camera("cam_active").id)
        finally:
            seg_renderer.close()
        u, v = obs["point_pixels"][:, 0], obs["point_pixels"][:, 1]
        ids = seg[v, u]
        xyz = obs["point_cloud"][:, :3].astype(np.float64)
        cube_g, plate_g = env.model.geom("cube_geom").id, env.model.geom("plate_geom").id
        assert (ids == cube_g).sum() >= 5 and (ids == plate_g).sum() >= 5

        half = env.model.geom_size[cube_g][0]
        R = env.data.geom_xmat[cube_g].reshape(3, 3)
        local = (xyz[ids == cube_g] - env.data.geom_xpos[cube_g]) @ R
        assert np.abs(local).max() <= half + 0.003, np.abs(local).max()

        radius, half_h = env.model.geom_size[plate_g][:2]
        centre = env.data.geom_xpos[plate_g]
        on_plate = xyz[ids == plate_g]
        assert np.linalg.norm(on_plate[:, :2] - centre[:2], axis=1).max() <= radius + 0.003
        assert np.abs(on_plate[:, 2] - centre[2]).max() <= half_h + 0.003
    finally:
        env.close()


# --------------------------------------------------------------------------------------------
# milestones, reward, termination, truncation
# --------------------------------------------------------------------------------------------
def test_expert_episode_milestones_monotone_reward_and_termination(small_env):
    env = small_env
    obs, info = env.reset(seed=1)
    expert = make_expert(env)
    expert.reset()
    prev = info["progress"]
    assert prev == 0
    terminated = truncated = False
    steps = 0
    while not (terminated or truncated):
        obs, reward, terminated, truncated, info = env.step(expert.act(obs, info))
        steps += 1
        p = info["progress"]
        assert p >= prev, f"progress decreased {prev} -> {p} at step {steps}"
        assert 0 <= p - prev <= 5
        assert reward == p / 5
        assert terminated == (p == 5)
        assert info["is_success"] == (p == 5)
        prev = p
    assert terminated and not truncated and info["is_success"] and prev == 5
    assert steps < env.max_episode_steps


def test_noisy_policy_progress_never_decreases(small_env):
    env = small_env
    g = np.random.default_rng(2024)
    obs, info = env.reset(seed=4)
    prev = info["progress"]
    low, high = env.action_space.low, env.action_space.high
    for _ in range(100):
        a = np.clip(HOME + g.normal(0.0, 0.1, 21), low, high)
        obs, reward, terminated, truncated, info = env.step(a)
        assert info["progress"] >= prev
        assert reward == info["progress"] / 5
        prev = info["progress"]
        if terminated or truncated:
            break


def test_truncation_at_max_episode_steps():
    env = BavoEnv(episode_length=5, **SMALL)
    try:
        assert env.max_episode_steps == 5
        env.reset(seed=0)
        for k in range(1, 6):
            _, _, terminated, truncated, info = env.step(HOME)
            assert not terminated
            assert truncated == (k == 5), k
            assert info["elapsed_steps"] == k
        # reset starts a fresh episode
        _, info = env.reset(seed=0)
        assert info["elapsed_steps"] == 0
        assert env.step(HOME)[3] is False
    finally:
        env.close()


# --------------------------------------------------------------------------------------------
# bad input
# --------------------------------------------------------------------------------------------
def test_unknown_task_raises_value_error_naming_it():
    with pytest.raises(ValueError, match="no_such_task"):
        BavoEnv(task="no_such_task", render_mode=None)


def test_unknown_condition_raises_value_error():
    with pytest.raises(ValueError, match="foggy"):
        BavoEnv(condition="foggy", render_mode=None)


def test_bogus_point_frame_raises_value_error():
    with pytest.raises(ValueError, match="world"):
        BavoEnv(point_frame="world", render_mode=None)


@pytest.mark.parametrize(
    "kwargs", [dict(n_points=0), dict(image_height=8), dict(image_width=4), dict(render_mode="human")],
    ids=["n_points0", "tiny_h", "tiny_w", "render_human"],
)
def test_bad_observation_settings_raise_value_error(kwargs):
    with pytest.raises(ValueError):
        BavoEnv(**kwargs)


def test_step_before_reset_raises_runtime_error():
    env = BavoEnv(**SMALL)
    try:
        with pytest.raises(RuntimeError, match="reset"):
            env.step(HOME)
    finally:
        env.close()


@pytest.mark.parametrize(
    "bad",
    [np.zeros(20), np.zeros(22), np.zeros((21, 1)), np.zeros((1, 21))],
    ids=["20", "22", "21x1", "1x21"],
)
def test_wrong_action_shape_raises_value_error(small_env, bad):
    small_env.reset(seed=0)
    with pytest.raises(ValueError, match="shape"):
        small_env.step(bad)


@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_non_finite_action_raises_value_error(small_env, value):
    small_env.reset(seed=0)
    a = HOME.copy()
    a[3] = value
    q_before = small_env.joint_state()
    with pytest.raises(ValueError):
        small_env.step(a)
    # the rejected action did not advance the simulation
    np.testing.assert_array_equal(small_env.joint_state(), q_before)
    assert small_env.elapsed_steps == 0


def test_feature_keys_spell_lerobots_names_and_the_env_imports_no_pytorch():
    """`lerobot_bavo.features` spells out LeRobot's key names so the env and its workers need no PyTorch."""
    import subprocess
    import sys

    from lerobot.utils import constants as L

    from lerobot_bavo import features as F

    for name in ("OBS_STR", "OBS_STATE", "OBS_IMAGES", "ACTION"):
        assert getattr(F, name) == getattr(L, name), name
    code = ("import sys, lerobot_bavo.envs.bavo_env, lerobot_bavo.experts, lerobot_bavo.eval.cli, "
            "lerobot_bavo.datasets.collect; print('torch' in sys.modules or 'lerobot' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                         env={**__import__("os").environ, "BAVO_LIGHT_IMPORT": "1"})
    assert out.returncode == 0 and out.stdout.strip() == "False", out.stdout + out.stderr

"""The robot self-filter (`ObservationSettings.self_filter`): the robot's own body leaves the point cloud,
what is in front of it stays, and the setting travels from the collection to the checkpoint to
the eval env."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lerobot_bavo.envs.pointcloud import build_point_cloud, robot_pixel_mask

INF = np.inf


def test_robot_pixel_mask_hand_computed():
    depth = np.array([[1.00, 1.00, 0.50],
                      [2.00, 0.996, 0.90]])
    robot = np.array([[1.00, INF, 1.00],
                      [1.50, 1.00, 1.00]])
    # (0,0) the robot's surface itself; (0,1) no robot there; (0,2) 50 cm in front of the robot (held object);
    # (1,0) measured behind the robot's surface (cannot be seen through it: still the robot's pixel);
    # (1,1) 4 mm in front, within the 5 mm tolerance; (1,2) 10 cm in front
    expected = np.array([[True, False, False],
                         [True, True, False]])
    np.testing.assert_array_equal(robot_pixel_mask(depth, robot, 0.005), expected)
    assert not robot_pixel_mask(depth, robot, 0.0)[1, 1]  # no tolerance: 4 mm in front is not the robot
    with pytest.raises(ValueError, match="two \\(H, W\\) depth images"):
        robot_pixel_mask(depth, robot[:, :2], 0.005)
    with pytest.raises(ValueError, match="tolerance must be >= 0"):
        robot_pixel_mask(depth, robot, -0.001)


def test_dropped_pixels_are_never_sampled():
    h, w = 12, 16
    rgb = np.zeros((h, w, 3), np.uint8)
    depth = np.ones((h, w), np.float32)
    K = np.array([[10.0, 0, (w - 1) / 2], [0, 10.0, (h - 1) / 2], [0, 0, 1]])
    drop = np.zeros((h, w), bool)
    drop[:, : w // 2] = True  # the left half
    _, pixels = build_point_cloud(rgb, depth, K, np.eye(4), 20, stride=1, drop_pixels=drop)
    assert (pixels[:, 0] >= w // 2).all()
    _, all_pixels = build_point_cloud(rgb, depth, K, np.eye(4), 20, stride=1)
    assert (all_pixels[:, 0] < w // 2).any()  # without the mask FPS covers the left half too
    with pytest.raises(ValueError, match="drop_pixels must be"):
        build_point_cloud(rgb, depth, K, np.eye(4), 20, stride=1, drop_pixels=drop[:, :3])


def _groups_seen(env, obs) -> np.ndarray:
    from lerobot_bavo.features import ENV_POINT_PIXELS_KEY
    from lerobot_bavo.sim import constants as C
    from lerobot_bavo.sim.rendering import SceneRenderer

    s = env.obs_settings
    renderer = SceneRenderer(env.model, s.image_height, s.image_width)
    try:
        seg = renderer.render_segmentation(env.data, C.ACTIVE_CAMERA)
    finally:
        renderer.close()
    pix = obs[ENV_POINT_PIXELS_KEY]
    ids = seg[pix[:, 1], pix[:, 0]]
    assert (ids >= 0).all()
    return env.model.geom_group[ids]


def test_env_self_filter_drops_the_robot_keeps_objects_and_occluder():
    from lerobot_bavo.envs.bavo_env import BavoEnv
    from lerobot_bavo.sim import constants as C

    kw = dict(image_height=96, image_width=128, n_points=64, render_mode=None)
    plain = BavoEnv("block_stacking", "stage", **kw)
    filtered = BavoEnv("block_stacking", "stage", self_filter=True, **kw)
    obs_plain, _ = plain.reset(seed=1000)
    obs_filtered, _ = filtered.reset(seed=1000)
    g_plain, g_filtered = _groups_seen(plain, obs_plain), _groups_seen(filtered, obs_filtered)
    assert (g_plain == C.GROUP_ROBOT).sum() > 5  # the arms are in the plain cloud ...
    assert (g_filtered == C.GROUP_ROBOT).sum() == 0  # ... and none of them in the filtered one
    assert (g_filtered == C.GROUP_OBJECT).sum() > (g_plain == C.GROUP_OBJECT).sum()  # the points go elsewhere
    assert (g_filtered == C.GROUP_OCCLUDER).sum() > 0  # what blocks the view is never filtered
    # the same state and the same dynamics: only the cloud differs; same seed, same cloud
    np.testing.assert_array_equal(obs_plain["agent_pos"], obs_filtered["agent_pos"])
    again, _ = filtered.reset(seed=1000)
    np.testing.assert_array_equal(again["point_cloud"], obs_filtered["point_cloud"])
    assert filtered.obs_settings.self_filter and not plain.obs_settings.self_filter
    plain.close()
    filtered.close()


def test_robot_only_depth_lies_behind_or_on_the_scene():
    from lerobot_bavo.envs.bavo_env import BavoEnv
    from lerobot_bavo.sim import constants as C
    from lerobot_bavo.sim.rendering import SceneRenderer

    env = BavoEnv("cube_handoff", "clean", image_height=48, image_width=64, n_points=16, render_mode=None)
    env.reset(seed=1000)
    r = SceneRenderer(env.model, 48, 64)
    _, scene = r.render_rgbd(env.data, C.ACTIVE_CAMERA)
    robot = r.render_depth(env.data, C.ACTIVE_CAMERA, hidden_groups=C.NON_ROBOT_GROUPS)
    r.close()
    env.close()
    seen = np.isfinite(robot)
    assert 0 < seen.sum() < seen.size  # the arms are in view, and not everywhere
    assert (robot[seen] >= scene[seen] - 1e-4).all()  # hiding geoms never brings a surface nearer


def test_setting_travels_with_records(tmp_path):
    from lerobot_bavo.checkpoints import (
        INPUTS_RECORD,
        CheckpointMismatchError,
        recorded_cloud_settings,
        write_inputs_record,
    )
    from lerobot_bavo.datasets.collect_config import CollectConfig
    from lerobot_bavo.envs.configs import BavoEnvConfig
    from lerobot_bavo.features import ObservationSettings

    write_inputs_record(tmp_path, "base", self_filter=True)
    assert json.loads((tmp_path / INPUTS_RECORD).read_text()) == {"point_frame": "base", "self_filter": True}
    assert recorded_cloud_settings(tmp_path) == {"point_frame": "base", "self_filter": True}
    write_inputs_record(tmp_path, "camera")  # off: the record of before the option
    assert json.loads((tmp_path / INPUTS_RECORD).read_text()) == {"point_frame": "camera"}
    assert recorded_cloud_settings(tmp_path) == {"point_frame": "camera", "self_filter": False}
    (tmp_path / INPUTS_RECORD).write_text('{"point_frame": "base", "self_filter": "yes"}')
    with pytest.raises(CheckpointMismatchError, match="self_filter \\(optional\\) true or false"):
        recorded_cloud_settings(tmp_path)

    def record(self_filter: bool) -> dict:
        return CollectConfig(task="cube_handoff", condition="stage", episodes=1, repo_id="local/x",
                             root=tmp_path / "ds", settings=ObservationSettings(self_filter=self_filter),
                             ).record_settings()

    assert "self_filter" not in record(False)  # records of datasets made before the option still match
    assert record(True)["self_filter"] is True
    assert BavoEnvConfig(self_filter=True).gym_kwargs["self_filter"] is True
    with pytest.raises(ValueError, match="self_filter must be true or false"):
        ObservationSettings(self_filter="yes")


def test_cloud_composition_counts_by_hand():
    from _helpers import load_script

    from lerobot_bavo.sim import constants as C

    composition = load_script("scripts/cloud_composition.py").composition
    seg = np.array([[0, 1, 2],
                    [3, -1, 2]])  # geom ids per pixel (-1: nothing)
    groups = np.array([C.GROUP_ROBOT, C.GROUP_OBJECT, C.GROUP_OBJECT, C.GROUP_OCCLUDER])
    pixels = np.array([[0, 0], [1, 0], [2, 0], [2, 1], [0, 1], [1, 1]])  # (u, v)
    got = composition(seg, pixels, groups, {"block": [1], "cube": [2]})
    assert got == {"robot": 1, "block": 1, "cube": 2, "occluder": 1, "other": 1}

"""Decoy panels (`BavoEnv(decoy_panels=...)`, `bavo-collect --decoy-panels`): a data-collection lever
against the occluder shortcut (docs/results/decoy_panels.md).

What is checked, with expectations written here rather than read from the code under test:
  * the benchmark's scene is untouched: no decoy body without the option, and with it the same layout,
    schedule, occluder placements, target visibility and expert actions for a seed (decoys are invisible to
    the privileged renders and the expert);
  * a placed decoy is in the active camera's view, on a line of sight at one of the distances written
    out here, two panel widths from the occluder, clear of the robot, and leaves >= 80 % of the current
    target's pixels visible, recounted from segmentation renders of the real geoms at full resolution;
  * the same seed gives the same decoys; bad values fail with errors naming the option.
Short expert rollouts at 48 x 64 only (about 20 s on a 2-core machine).
"""

from __future__ import annotations

import copy

import mujoco
import numpy as np
import pytest
from _helpers import IndependentVisibility

from lerobot_bavo.datasets.collect_config import CollectConfig
from lerobot_bavo.envs.bavo_env import BavoEnv
from lerobot_bavo.experts import make_expert
from lerobot_bavo.sim import constants as C

SMALL = dict(image_height=48, image_width=64, n_points=64, render_mode=None)
DISTANCES = (0.32, 0.27, 0.23)  # metres from the camera a decoy may take
OCCLUDER_GROUP = 4


def _decoy_bodies(model) -> list[str]:
    return [model.body(b).name for b in range(model.nbody) if model.body(b).name.startswith("decoy_panel")]


def _rollout(env, seed, steps):
    """Expert rollout; per step: agent_pos, the action, the occlusion info."""
    obs, info = env.reset(seed=seed)
    expert = make_expert(env, seed=seed)
    expert.reset()
    out = []
    for _ in range(steps):
        action = np.asarray(expert.act(obs, info))
        out.append((obs["agent_pos"].copy(), action, info["occlusion"]))
        obs, _, term, trunc, info = env.step(action)
        if term or trunc:
            break
    return out


def test_benchmark_scene_has_no_decoys():
    for condition in ("clean", "stage", "random"):
        env = BavoEnv("cube_handoff", condition, **SMALL)
        assert _decoy_bodies(env.model) == []
        env.close()
    env = BavoEnv("cube_handoff", "stage", decoy_panels=2, **SMALL)
    assert _decoy_bodies(env.model) == ["decoy_panel_0", "decoy_panel_1"]
    for name in ("decoy_panel_0", "decoy_panel_1"):
        g = env.model.geom(f"{name}_geom")
        assert g.contype == 0 and g.conaffinity == 0 and g.group == OCCLUDER_GROUP
    env.close()


@pytest.mark.parametrize("condition", ["stage", "random"])
def test_decoys_leave_layout_schedule_and_expert_unchanged(condition):
    plain = BavoEnv("cube_handoff", condition, **SMALL)
    decoy = BavoEnv("cube_handoff", condition, decoy_panels=1, **SMALL)
    a = _rollout(plain, 3, 40)
    b = _rollout(decoy, 3, 40)
    assert len(a) == len(b)
    assert a[0][2]["triggers"] == b[0][2]["triggers"]
    np.testing.assert_array_equal(plain.task.object_poses(plain.model, plain.data)["cube"],
                                  decoy.task.object_poses(decoy.model, decoy.data)["cube"])
    for (qa, ua, oa), (qb, ub, ob) in zip(a, b):
        np.testing.assert_array_equal(qa, qb)
        np.testing.assert_array_equal(ua, ub)
        np.testing.assert_array_equal(oa["event"]["occluder_pos"], ob["event"]["occluder_pos"])
        assert oa["visibility"] == ob["visibility"]
    assert "decoy_positions" not in a[0][2] and len(b[0][2]["decoy_positions"]) == 1
    plain.close()
    decoy.close()


def test_same_seed_same_decoys():
    runs = []
    for _ in range(2):
        env = BavoEnv("block_stacking", "stage", decoy_panels=2, **SMALL)
        runs.append([o["decoy_positions"] for _, _, o in _rollout(env, 11, 5)])
        env.close()
    for pa, pb in zip(*runs):
        for x, y in zip(pa, pb):
            assert (x is None) == (y is None)
            if x is not None:
                np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("task,seed", [("cube_handoff", 0), ("block_stacking", 1), ("drawer_stowing", 2)])
def test_placed_decoys_are_in_view_and_leave_the_target_visible(task, seed):
    env = BavoEnv(task, "stage", decoy_panels=2, image_height=120, image_width=160, n_points=64,
                  render_mode=None)
    _, info = env.reset(seed=seed)
    model, data = env.model, env.data
    cam = model.camera(C.ACTIVE_CAMERA).id
    cam_pos = data.cam_xpos[cam].copy()
    cam_axis = -data.cam_xmat[cam].reshape(3, 3)[:, 2]
    occluder = np.asarray(info["occlusion"]["event"]["occluder_pos"])
    target_ids = np.asarray(env.current_target_geoms())
    recount = IndependentVisibility(model, 240, 320, cam)  # whatever of group 4 is in place
    placed = [p for p in info["occlusion"]["decoy_positions"] if p is not None]
    assert placed, "no decoy placed at reset"
    robot = [g for g in range(model.ngeom) if model.geom_group[g] == C.GROUP_ROBOT]
    for i, pos in enumerate(info["occlusion"]["decoy_positions"]):
        if pos is None:
            continue
        offset = pos - cam_pos
        assert min(abs(np.linalg.norm(offset) - d) for d in DISTANCES) < 1e-9
        half_angle = np.rad2deg(np.arccos(offset @ cam_axis / np.linalg.norm(offset)))
        assert half_angle <= env.obs_settings.fovy / 2 + 1e-6
        assert np.linalg.norm(pos - occluder) >= 0.15 - 1e-9
        geom = model.geom(f"decoy_panel_{i}_geom").id
        for g in robot:
            assert mujoco.mj_geomDistance(model, data, geom, g, 0.03, None) >= 0.03 - 1e-6
        # the decoy alone in the way: move the occluder and the other decoy out of sight in a copy
        alone = copy.deepcopy(data)
        for body in ["occluder"] + [f"decoy_panel_{j}" for j in range(2) if j != i]:
            alone.mocap_pos[model.body_mocapid[model.body(body).id]] = (0.0, 0.0, -2.0)
        mujoco.mj_kinematics(model, alone)
        mujoco.mj_camlight(model, alone)
        assert recount.visibility(alone, target_ids) >= 0.75  # 0.8 at half resolution
        seg = recount.renderer.render_segmentation(alone, cam)
        assert (seg == geom).sum() > 0, "a placed decoy is not seen by the active camera"
    recount.close()
    env.close()


def test_bad_decoy_settings_are_named():
    with pytest.raises(ValueError, match="decoy_panels needs an occluded condition"):
        BavoEnv("cube_handoff", "clean", decoy_panels=1, **SMALL)
    for bad in (-1, 1.5, True):
        with pytest.raises(ValueError, match="decoy_panels must be an integer"):
            BavoEnv("cube_handoff", "stage", decoy_panels=bad, **SMALL)
    with pytest.raises(ValueError, match="--decoy-panels needs an occluded condition"):
        CollectConfig(task="cube_handoff", condition="clean", episodes=1, repo_id="a/b", decoy_panels=1)
    with pytest.raises(ValueError, match="--decoy-panels must be >= 0"):
        CollectConfig(task="cube_handoff", condition="stage", episodes=1, repo_id="a/b", decoy_panels=-2)
    plain = CollectConfig(task="cube_handoff", condition="stage", episodes=1, repo_id="a/b")
    assert "decoy_panels" not in plain.record_settings()  # earlier datasets' records still match
    decoys = CollectConfig(task="cube_handoff", condition="stage", episodes=1, repo_id="a/b", decoy_panels=1)
    assert decoys.record_settings()["decoy_panels"] == 1

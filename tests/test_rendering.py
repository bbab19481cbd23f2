"""SceneRenderer: a context sized to the image draws the same pixels as one with the model's full buffer."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from lerobot_bavo.envs.bavo_env import BavoEnv
from lerobot_bavo.experts import make_expert
from lerobot_bavo.sim import constants as C
from lerobot_bavo.sim import rendering
from lerobot_bavo.sim.rendering import SceneRenderer


def _full_buffer_context(model, width, height):
    """What SceneRenderer built before issue 11: the model's own offscreen size (640 x 480 here)."""
    return mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150)


@pytest.mark.parametrize("height,width", [(240, 320), (120, 160)])
def test_sized_context_renders_identical_pixels(monkeypatch, height, width):
    env = BavoEnv(task="drawer_stowing", condition="stage", render_mode=None)
    model = env.model
    offscreen = (model.vis.global_.offwidth, model.vis.global_.offheight)
    sized = SceneRenderer(model, height, width)
    assert (sized._ctx.offWidth, sized._ctx.offHeight) == (width, height)
    assert (model.vis.global_.offwidth, model.vis.global_.offheight) == offscreen  # restored
    monkeypatch.setattr(rendering, "_context_of_size", _full_buffer_context)
    full = SceneRenderer(model, height, width)
    assert (full._ctx.offWidth, full._ctx.offHeight) == offscreen
    cam = model.camera(C.ACTIVE_CAMERA).id
    third = model.camera(C.THIRD_PERSON_CAMERA).id
    obs, info = env.reset(seed=5)
    expert = make_expert(env, seed=5)
    expert.reset()
    compared = 0
    for step in range(120):  # reaching, the first occlusion event and the camera's recovery
        if step % 8 == 0:
            for camera in (cam, third):
                for a, b in zip(sized.render_rgbd(env.data, camera), full.render_rgbd(env.data, camera)):
                    np.testing.assert_array_equal(a, b)
                seg_a, depth_a = sized.render_segmentation(env.data, camera, with_depth=True)
                seg_b, depth_b = full.render_segmentation(env.data, camera, with_depth=True)
                np.testing.assert_array_equal(seg_a, seg_b)
                np.testing.assert_array_equal(depth_a, depth_b)
                assert (seg_a >= 0).any()
                compared += 1
        obs, _, terminated, truncated, info = env.step(expert.act(obs, info))
        if terminated or truncated:
            break
    assert compared >= 20
    sized.close()
    full.close()
    env.close()


def _reference_decode(renderer: SceneRenderer, with_depth: bool):
    """The id decode and metric depth as written before issue 11, from the renderer's raw buffers."""
    rgb = np.flipud(renderer._rgb).astype(np.int32)
    segid = rgb[..., 0] + rgb[..., 1] * 256 + rgb[..., 2] * 65536 - 1
    scene = renderer._scene
    lut = np.full(scene.ngeom + 1, -1, dtype=np.int32)
    for i in range(scene.ngeom):
        if scene.geoms[i].objtype == mujoco.mjtObj.mjOBJ_GEOM:
            lut[i] = scene.geoms[i].objid
    seg = lut[np.where((segid >= 0) & (segid < scene.ngeom), segid, scene.ngeom)]
    near, far = renderer._near, renderer._far
    depth = np.flipud(near / (1.0 - renderer._depth * (1.0 - near / far))).astype(np.float32)
    return seg, depth


def test_segmentation_ids_and_depth_equal_the_reference_decode():
    """Ids and metric depth bit for bit against the plain per-channel decode, at both privileged sizes, with
    the occluder shown and hidden, from the realised and from a moved camera."""
    env = BavoEnv(task="block_stacking", condition="stage", render_mode=None)
    cam = env.model.camera(C.ACTIVE_CAMERA).id
    renderers = [SceneRenderer(env.model, 240, 320), SceneRenderer(env.model, 120, 160)]
    obs, info = env.reset(seed=3)
    expert = make_expert(env, seed=3)
    expert.reset()
    seen = set()
    for step in range(90):
        if step % 10 == 0:
            pose = (env.data.cam_xpos[cam] + [0.05, -0.03, 0.02], env.data.cam_xmat[cam].reshape(3, 3))
            for r in renderers:
                for kwargs in ({}, {"hidden_groups": (C.GROUP_OCCLUDER,)}, {"pose": pose}):
                    seg, depth = r.render_segmentation(env.data, cam, with_depth=True, **kwargs)
                    ref_seg, ref_depth = _reference_decode(r, True)
                    assert seg.dtype == ref_seg.dtype and depth.dtype == ref_depth.dtype == np.float32
                    np.testing.assert_array_equal(seg, ref_seg)
                    assert depth.tobytes() == ref_depth.tobytes()
                    np.testing.assert_array_equal(r.render_segmentation(env.data, cam, **kwargs), ref_seg)
                    seen.update(np.unique(seg).tolist())
                rgb, depth = r.render_rgbd(env.data, cam)
                assert depth.tobytes() == _reference_decode(r, True)[1].tobytes()
        obs, _, terminated, truncated, info = env.step(expert.act(obs, info))
    assert -1 in seen and len(seen) > 5  # background and several geoms were decoded
    for r in renderers:
        r.close()
    env.close()

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

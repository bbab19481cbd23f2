"""Lean offscreen rendering: one pass gives RGB and metric depth together; optional segmentation.

Why not `mujoco.Renderer`: it renders RGB and depth in two separate passes. Reading both buffers
from one pass roughly halves the per-step rendering cost on CPU (llvmpipe). Shadows are off in
the model (`visual.quality.shadowsize = 0`) and every light has `castshadow = False`.

A camera pose can be overridden for a render (counterfactual views for CVG) without touching
`MjData`, so such renders never affect observations or dynamics.
"""

from __future__ import annotations

import atexit
import weakref

import mujoco
import numpy as np

from lerobot_bavo.sim import constants as C


class SceneRenderer:
    """Offscreen renderer bound to one model and one image size.

    Args:
        model: compiled model; its `vis.global_.offwidth/offheight` must be >= the image size.
        height, width: image size in pixels.
        visible_groups: geom groups drawn by default (0 world, 1 robot, 2 objects, 4 occluder).
    """

    def __init__(self, model: mujoco.MjModel, height: int, width: int,
                 visible_groups=(C.GROUP_WORLD, C.GROUP_ROBOT, C.GROUP_OBJECT, C.GROUP_OCCLUDER)):
        if width > model.vis.global_.offwidth or height > model.vis.global_.offheight:
            raise ValueError(
                f"image {height}x{width} exceeds the model's offscreen buffer "
                f"{model.vis.global_.offheight}x{model.vis.global_.offwidth}"
            )
        self.model = model
        self.height, self.width = height, width
        self._gl = mujoco.GLContext(width, height)
        self._gl.make_current()
        self._ctx = _context_of_size(model, width, height)
        # Free the GL context when this renderer is collected or, at the latest, at interpreter
        # exit before EGL itself is terminated (avoids EGL errors from late destructors).
        # (weakref's own exit hook may run after EGL's eglTerminate hook, so register ours.)
        self._finalizer = weakref.finalize(self, _release, self._gl, self._ctx)
        self._finalizer.atexit = False
        atexit.register(self._finalizer)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._ctx)
        self._scene = mujoco.MjvScene(model, maxgeom=2000)
        self._opt = mujoco.MjvOption()
        self._opt.geomgroup[:] = 0
        for g in visible_groups:
            self._opt.geomgroup[g] = 1
        self._opt.sitegroup[:] = 0
        self._cam = mujoco.MjvCamera()
        self._cam.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self._pert = mujoco.MjvPerturb()
        self._rect = mujoco.MjrRect(0, 0, width, height)
        self._rgb = np.zeros((height, width, 3), dtype=np.uint8)
        self._depth = np.zeros((height, width), dtype=np.float32)
        extent = model.stat.extent
        self._near = model.vis.map.znear * extent
        self._far = model.vis.map.zfar * extent

    def _update(self, data: mujoco.MjData, camera: str | int, pose, hidden_groups=()) -> None:
        self._gl.make_current()
        self._cam.fixedcamid = camera if isinstance(camera, int) else self.model.camera(camera).id
        saved = [(g, self._opt.geomgroup[g]) for g in hidden_groups]
        for g in hidden_groups:
            self._opt.geomgroup[g] = 0
        mujoco.mjv_updateScene(self.model, data, self._opt, self._pert, self._cam,
                               mujoco.mjtCatBit.mjCAT_ALL, self._scene)
        for g, v in saved:
            self._opt.geomgroup[g] = v
        if pose is not None:
            pos, xmat = pose
            xmat = np.asarray(xmat, dtype=np.float64).reshape(3, 3)
            for glcam in self._scene.camera:
                glcam.pos[:] = pos
                glcam.forward[:] = -xmat[:, 2]
                glcam.up[:] = xmat[:, 1]

    def render_rgbd(self, data: mujoco.MjData, camera: str | int, pose=None,
                    hidden_groups=()) -> tuple[np.ndarray, np.ndarray]:
        """RGB (H, W, 3) uint8 and z-depth (H, W) float32 in metres, from one render pass.

        `pose` = (position (3,), MuJoCo camera rotation (3,3)) overrides the camera pose.
        The returned arrays are fresh copies.
        """
        self._update(data, camera, pose, hidden_groups)
        mujoco.mjr_render(self._rect, self._scene, self._ctx)
        mujoco.mjr_readPixels(self._rgb, self._depth, self._rect, self._ctx)
        return np.flipud(self._rgb).copy(), self._metric_depth_flipped()

    def render_depth(self, data: mujoco.MjData, camera: str | int, pose=None, hidden_groups=(),
                     background: float = np.inf) -> np.ndarray:
        """Metric z-depth (H, W) float32 in metres (a fresh array), `background` where no geom is drawn
        (the far plane). With `hidden_groups`, a render of the remaining groups only: e.g. the robot model
        alone, for a self-filter (`envs.pointcloud.robot_pixel_mask`)."""
        self._update(data, camera, pose, hidden_groups)
        skybox = self._scene.flags[mujoco.mjtRndFlag.mjRND_SKYBOX]
        self._scene.flags[mujoco.mjtRndFlag.mjRND_SKYBOX] = 0  # the skybox writes depth just short of far
        try:
            mujoco.mjr_render(self._rect, self._scene, self._ctx)
            mujoco.mjr_readPixels(None, self._depth, self._rect, self._ctx)
        finally:
            self._scene.flags[mujoco.mjtRndFlag.mjRND_SKYBOX] = skybox
        depth = self._metric_depth_flipped()
        depth[np.flipud(self._depth) >= 1.0] = background  # z-buffer 1: nothing drawn there
        return depth

    def render_rgb(self, data: mujoco.MjData, camera: str | int, pose=None, hidden_groups=()) -> np.ndarray:
        self._update(data, camera, pose, hidden_groups)
        mujoco.mjr_render(self._rect, self._scene, self._ctx)
        mujoco.mjr_readPixels(self._rgb, None, self._rect, self._ctx)
        return np.flipud(self._rgb).copy()

    def render_segmentation(self, data: mujoco.MjData, camera: str | int, pose=None,
                            hidden_groups=(), with_depth: bool = False):
        """Geom id per pixel (H, W) int32, -1 where no geom is seen; with `with_depth`, also the
        z-depth (H, W) float32 in metres from the same pass."""
        self._update(data, camera, pose, hidden_groups)
        self._scene.flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = 1
        self._scene.flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = 1
        try:
            mujoco.mjr_render(self._rect, self._scene, self._ctx)
            mujoco.mjr_readPixels(self._rgb, self._depth if with_depth else None, self._rect, self._ctx)
        finally:
            self._scene.flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = 0
            self._scene.flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = 0
        seg = self._decode_segmentation()
        if not with_depth:
            return seg
        return seg, self._metric_depth_flipped()

    def _decode_segmentation(self) -> np.ndarray:
        """Geom id per pixel (top row first) from the ID colours of the last segmentation pass.

        MuJoCo writes index + 1 of the scene geom drawn at a pixel as R + 256 G + 65536 B (0: nothing); a
        lookup table indexed by that raw id maps 0, and anything beyond the scene, to -1. `np.take` rather
        than fancy indexing for the lookup: same values, in less time (tested against the plain decode in
        tests/test_rendering.py).
        """
        rgb = self._rgb
        raw = rgb[..., 0].astype(np.uint32)
        raw |= rgb[..., 1].astype(np.uint32) << 8
        raw |= rgb[..., 2].astype(np.uint32) << 16
        ngeom = self._scene.ngeom
        np.minimum(raw, ngeom + 1, out=raw)
        lut = np.full(ngeom + 2, -1, dtype=np.int32)  # lut[k] for raw id k; lut[0] and lut[ngeom + 1] = -1
        for i in range(ngeom):
            g = self._scene.geoms[i]
            if g.objtype == mujoco.mjtObj.mjOBJ_GEOM:
                lut[i + 1] = g.objid
        return np.take(lut, raw[::-1])

    def _metric_depth_flipped(self) -> np.ndarray:
        """Metric z-depth (H, W) float32 in metres, top row first, of the last pass with depth readback:
        near / (1 - zbuffer (1 - near / far))."""
        near, far = self._near, self._far
        return np.flipud(near / (1.0 - self._depth * (1.0 - near / far))).astype(np.float32)

    def close(self) -> None:
        self._finalizer()


def _context_of_size(model: mujoco.MjModel, width: int, height: int) -> mujoco.MjrContext:
    """A rendering context whose offscreen buffer is exactly `width` x `height` pixels.

    MuJoCo sizes the offscreen buffer from `model.vis.global_.offwidth/offheight` (640 x 480 here, for the
    largest image any renderer of the model draws); a renderer that only ever draws a smaller image gets a
    buffer of its own size, which makes each render cheaper on llvmpipe and leaves its pixels
    unchanged (`tests/test_rendering.py` compares both buffers). The model's values are restored at once.
    """
    vis = model.vis.global_
    saved = (vis.offwidth, vis.offheight)
    vis.offwidth, vis.offheight = width, height
    try:
        return mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150)
    finally:
        vis.offwidth, vis.offheight = saved


def _release(gl, ctx) -> None:
    try:
        gl.make_current()
        ctx.free()
        gl.free()
    except Exception:  # noqa: BLE001 - EGL may already be torn down at interpreter exit
        pass

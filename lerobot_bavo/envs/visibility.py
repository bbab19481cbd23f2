"""Target visibility from renders (paper Eq. 1 inputs): which target pixels the occluder hides.

`TargetVisibility` renders the occluder-free scene's segmentation and depth from a camera pose and
counts the target's pixels (N^noOcc) and those the occluder panel leaves visible (N^occ, by
ray-rectangle intersection, `panel_hides`); `lerobot_bavo.metrics.normalized_visibility` turns
the counts into V. This is the privileged evaluation path: it never touches observations.
"""

from __future__ import annotations

import numpy as np

from lerobot_bavo.metrics import normalized_visibility

__all__ = ["TargetVisibility", "panel_hides", "pixel_rays"]


# --------------------------------------------------------------------------------------------
# Occluder geometry: which target pixels a thin rectangular panel hides
# --------------------------------------------------------------------------------------------
def pixel_rays(pixels_uv: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Camera-frame rays (OpenCV convention) with unit z for pixels (u = column, v = row).

    A point at z-depth d along the ray of pixel (u, v) is d * ray.
    """
    uv = np.asarray(pixels_uv, dtype=np.float64)
    rays = np.ones((uv.shape[0], 3))
    rays[:, 0] = (uv[:, 0] - K[0, 2]) / K[0, 0]
    rays[:, 1] = (uv[:, 1] - K[1, 2]) / K[1, 1]
    return rays


def panel_hides(
    pixels_uv: np.ndarray,
    scene_depth: np.ndarray,
    K: np.ndarray,
    T_base_cam: np.ndarray,
    panel_center: np.ndarray,
    panel_rot: np.ndarray,
    half_extents: tuple[float, float],
) -> np.ndarray:
    """Which pixels a thin rectangular panel hides: its plane is hit in front of the scene.

    The panel (the benchmark occluder) is the rectangle through `panel_center` spanned by the
    y and z columns of `panel_rot` (base frame) with half extents (a_y, a_z) metres; its normal
    is the x column. A pixel is hidden when its ray meets the rectangle at a z-depth (camera
    frame) smaller than `scene_depth` at that pixel, the depth of the scene rendered WITHOUT the
    occluder. Counting target pixels that are hidden this way gives N^noOcc - N^occ exactly for
    a panel of zero thickness, so one segmentation+depth render per camera pose serves both
    terms of Eq. 1.

    Args:
        pixels_uv: (M, 2) pixel coordinates (u = column, v = row).
        scene_depth: (M,) z-depth in metres of the occluder-free scene at those pixels.
        K: (3, 3) intrinsics.
        T_base_cam: (4, 4) T_B<-C, OpenCV camera convention.
        panel_center: (3,) base frame, metres.
        panel_rot: (3, 3) base frame; columns = panel normal, width axis, height axis.
        half_extents: (a_y, a_z) metres.

    Returns:
        (M,) bool.
    """
    if len(pixels_uv) == 0:
        return np.zeros(0, dtype=bool)
    R = T_base_cam[:3, :3]
    cam = T_base_cam[:3, 3]
    rays_base = pixel_rays(pixels_uv, K) @ R.T  # (M, 3), unit camera-z per unit step
    normal = panel_rot[:, 0]
    denom = rays_base @ normal
    with np.errstate(divide="ignore", invalid="ignore"):
        s = ((np.asarray(panel_center) - cam) @ normal) / denom  # z-depth of the plane hit
    hit = cam + s[:, None] * rays_base
    local = (hit - panel_center) @ panel_rot  # coordinates in the panel frame
    inside = (np.abs(local[:, 1]) <= half_extents[0]) & (np.abs(local[:, 2]) <= half_extents[1])
    return np.isfinite(s) & (s > 0) & inside & (s < np.asarray(scene_depth))


# --------------------------------------------------------------------------------------------
# Pixel counts from renders (privileged evaluation path; never touches observations)
# --------------------------------------------------------------------------------------------
class TargetVisibility:
    """Counts a target's visible pixels with and without the benchmark occluder.

    One segmentation+depth render of the occluder-free scene (geom group 4 hidden) from a camera
    pose gives N^noOcc (pixels of the target's geoms); the occluder panel's coverage of those
    pixels (`panel_hides`) gives N^occ. The camera pose can be any pose (the realised camera, or
    the camera frozen at an event's start for CVG's counterfactual); the render uses its own
    context and overrides only the GL camera, so `MjData` is never modified.

    Args:
        model: compiled model. camera_id: the active camera. height, width: render size (the
            counts are made at this resolution; V is a ratio, so a reduced size is a cheap and
            faithful estimate). fovy: the camera's vertical field of view, degrees.
    """

    def __init__(self, model, camera_id: int, height: int, width: int, fovy: float):
        from lerobot_bavo.envs.pointcloud import camera_pose_from_mujoco, intrinsics_from_fovy
        from lerobot_bavo.sim import constants as C
        from lerobot_bavo.sim.rendering import SceneRenderer

        self._to_opencv = camera_pose_from_mujoco
        self.camera_id = camera_id
        self.K = intrinsics_from_fovy(fovy, height, width)
        self.renderer = SceneRenderer(model, height, width,
                                      visible_groups=(C.GROUP_WORLD, C.GROUP_ROBOT, C.GROUP_OBJECT))

    def counts(self, data, target_geoms, panel=None, camera_pose=None) -> tuple[int, int]:
        """(N^occ, N^noOcc) of `target_geoms` from `camera_pose` = (pos, MuJoCo xmat) or the
        current active camera; `panel` = (centre, rotation, (a_y, a_z)) or None (no occluder)."""
        seg, depth = self.renderer.render_segmentation(
            data, self.camera_id, pose=camera_pose, with_depth=True
        )
        v, u = np.nonzero(np.isin(seg, np.asarray(target_geoms)))
        n_no_occ = int(u.size)
        if panel is None or n_no_occ == 0:
            return n_no_occ, n_no_occ
        if camera_pose is None:
            pos, xmat = data.cam_xpos[self.camera_id], data.cam_xmat[self.camera_id]
        else:
            pos, xmat = camera_pose
        T = self._to_opencv(np.asarray(pos), np.asarray(xmat))
        centre, rot, half = panel
        hidden = panel_hides(np.stack([u, v], axis=1), depth[v, u], self.K, T, centre, rot, half)
        return n_no_occ - int(hidden.sum()), n_no_occ

    def visibility(self, data, target_geoms, panel=None, camera_pose=None) -> float:
        return normalized_visibility(*self.counts(data, target_geoms, panel, camera_pose))

    def close(self) -> None:
        self.renderer.close()

"""How many of the policy's cloud points lie on each task object a policy must find, per task (issue 27).

Why: the learned policies fail on Block Stacking and Drawer Stowing at the first object they must pick
up, while the same recipe grasps Cube Handoff's cube. One candidate cause is that the object is a handful of
points of the cloud. This counts, at reset from the active camera's home pose, the cloud points whose source
pixel (`point_pixels`) shows one of each Stage target's geoms (a segmentation render of the same view), and
that target's pixel count in the image. The policy reads `points_per_step` (128) of the env's 256 points.

    python scripts/points_on_target.py [--condition clean] [--seeds 1000-1003] [--tasks cube_handoff,...]

Seeds default to the validation seeds (1000+), never the test seeds (2000+).
"""

from __future__ import annotations

import argparse

import numpy as np

from lerobot_bavo.envs.bavo_env import BavoEnv
from lerobot_bavo.envs.tasks import TASKS
from lerobot_bavo.features import ENV_POINT_PIXELS_KEY
from lerobot_bavo.sim import constants as C
from lerobot_bavo.sim.rendering import SceneRenderer


def points_on_geoms(segmentation: np.ndarray, pixels_uv: np.ndarray, geoms) -> int:
    """Number of cloud points whose source pixel (u = column, v = row) shows one of `geoms`; points with no
    source pixel (-1, -1: an empty view) count as on none."""
    valid = pixels_uv[:, 0] >= 0
    seen = segmentation[pixels_uv[valid, 1], pixels_uv[valid, 0]]
    return int(np.isin(seen, np.asarray(geoms)).sum())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tasks", default=",".join(name for name, _ in TASKS.items()))
    ap.add_argument("--condition", default="clean")
    ap.add_argument("--seeds", default="1000-1003", help="first-last (inclusive)")
    args = ap.parse_args()
    first, last = (int(s) for s in args.seeds.split("-"))
    for task in args.tasks.split(","):
        env = BavoEnv(task=task, condition=args.condition)
        s = env.obs_settings
        renderer = SceneRenderer(env.model, s.image_height, s.image_width)
        counts = {name: [] for name in env.task.target_geoms}
        for seed in range(first, last + 1):
            obs, _ = env.reset(seed=seed)
            seg = renderer.render_segmentation(env.data, C.ACTIVE_CAMERA)
            for name, geoms in env.task.target_geoms.items():
                counts[name].append((points_on_geoms(seg, obs[ENV_POINT_PIXELS_KEY], geoms),
                                     int(np.isin(seg, np.asarray(geoms)).sum())))
        renderer.close()
        env.close()
        print(f"{task} ({args.condition}, seeds {first}-{last}): points of {s.n_points} / image pixels of "
              f"{s.image_height * s.image_width}")
        for name, rows in counts.items():
            pts = [p for p, _ in rows]
            print(f"  {name:18s} points {min(pts):3d}-{max(pts):3d} (mean {np.mean(pts):5.1f})   pixels "
                  f"{min(p for _, p in rows)}-{max(p for _, p in rows)}")


if __name__ == "__main__":
    main()

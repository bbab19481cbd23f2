"""Teacher cache for stored datasets: clips from a LeRobot dataset, and re-caching with another teacher.

`bavo-collect` caches the simulator-exact teacher while it records (it needs privileged simulator
state that is not stored). A learned teacher (D4RT-like: RGB clips in, per-query features out)
can instead run on a stored dataset: `dataset_episode` rebuilds an episode's RGB frames (decoded
from the video), camera poses, intrinsics and source pixels, `make_clip` cuts the 32-frame clips,
and `recompute_teacher_cache` writes a copy of the dataset whose `observation.teacher.*` columns
come from that teacher (through LeRobot's `modify_features`).
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lerobot_bavo.datasets import schema as S
from lerobot_bavo.teacher.simulator import teacher_targets


@dataclass
class StoredEpisode:
    """Per-frame arrays of one stored episode, in the layout `make_clip` / `teacher_targets` read.

    rgb (T, H, W, 3) uint8; camera_pose (T, 4, 4) float64 T_B<-C; point_pixels (T, N, 2) int64;
    K (3, 3). No depth and no privileged state: only a learned teacher can answer on it.
    """

    rgb: np.ndarray
    camera_pose: np.ndarray
    point_pixels: np.ndarray
    K: np.ndarray


def dataset_episode(ds, episode_index: int, fovy: float | None = None) -> StoredEpisode:
    """Rebuild episode `episode_index` of a BAVO LeRobotDataset (decodes its video).

    `fovy` (degrees) defaults to the one recorded in `meta/bavo_collection.json`.
    """
    from lerobot_bavo.datasets.metadata import read_sidecar
    from lerobot_bavo.envs.pointcloud import intrinsics_from_fovy

    n = S.infer_n_points(ds.meta.features)
    h, w = ds.meta.features[S.OBS_IMAGE]["shape"][:2]
    if fovy is None:
        record = read_sidecar(ds.root)
        if record is None:
            raise ValueError(f"{ds.root} has no collection record: pass the camera's fovy explicitly")
        fovy = record["settings"]["fovy"]
    ep = ds.meta.episodes[episode_index]
    start, stop = int(ep["dataset_from_index"]), int(ep["dataset_to_index"])
    rows = ds.hf_dataset.with_format("numpy")[start:stop]
    frames = []
    for i in range(start, stop):
        img = ds[i][S.OBS_IMAGE]
        img = img[-1] if img.ndim == 4 else img  # with delta_timestamps: the current frame
        frames.append((img.permute(1, 2, 0).numpy() * 255.0 + 0.5).astype(np.uint8))
    rgb = np.stack(frames)
    return StoredEpisode(
        rgb=rgb,
        camera_pose=S.unflatten_camera_pose(np.asarray(rows[S.OBS_CAMERA_POSE], dtype=np.float64)),
        point_pixels=S.unflatten_point_pixels(np.asarray(rows[S.OBS_POINT_PIXELS]), n)
        .round()
        .astype(np.int64),
        K=intrinsics_from_fovy(fovy, h, w),
    )


def recompute_teacher_cache(ds, teacher, output_dir: str | Path, repo_id: str, fovy: float | None = None):
    """A copy of `ds` whose `observation.teacher.*` columns come from `teacher` (any `Teacher`).

    z0 / zf become (N * d,) with d = `teacher.feature_dim`; `visible` is all ones (a learned
    teacher's visibility head can be stored the same way); `valid` keeps its meaning. Statistics
    of the new columns are not computed (LeRobot's `modify_features` does not; the policies never
    normalise teacher keys). Returns the new LeRobotDataset.
    """
    from lerobot.datasets.dataset_tools import modify_features

    n = S.infer_n_points(ds.meta.features)
    parts: dict[str, list] = {"z0": [], "zf": [], "visible": [], "valid": []}
    for e in range(ds.meta.total_episodes):
        out = teacher_targets(dataset_episode(ds, e, fovy), teacher=teacher)
        for k in parts:
            parts[k].append(out[k])
    d = parts["z0"][0].shape[-1]
    cat = {k: np.concatenate(v) for k, v in parts.items()}
    F = cat["z0"].shape[0]

    def info(shape):
        return {"dtype": "float32", "shape": shape, "names": None}

    add = {
        S.TEACHER_Z0: (cat["z0"].reshape(F, n * d), info((n * d,))),
        S.TEACHER_ZF: (cat["zf"].reshape(F, n * d), info((n * d,))),
        S.TEACHER_VISIBLE: (cat["visible"].reshape(F, n), info((n,))),
        S.TEACHER_VALID: (cat["valid"].reshape(F, 1), info((1,))),
    }
    present = [k for k in S.TEACHER_KEYS if k in ds.meta.features]
    source, scratch = ds, None
    if present:  # LeRobot 0.6.1 refuses to add a feature that exists, even when removing it in the same call
        scratch = Path(output_dir).with_name(Path(output_dir).name + ".without_teacher")
        source = modify_features(ds, remove_features=present, output_dir=scratch, repo_id=f"{repo_id}_tmp")
    try:
        new = modify_features(source, add_features=add, output_dir=output_dir, repo_id=repo_id)
    finally:
        if scratch is not None:
            shutil.rmtree(scratch, ignore_errors=True)
    src_record = Path(ds.root) / "meta" / "bavo_collection.json"
    if src_record.exists():
        record = json.loads(src_record.read_text())
        record["settings"]["teacher"] = {
            "name": getattr(teacher, "name", type(teacher).__name__),
            "feature_dim": d,
            "clip_length": 32,
            "anchor_index": 16,
            "n_future": 15,
        }
        (Path(output_dir) / "meta" / "bavo_collection.json").write_text(json.dumps(record, indent=1))
    return new

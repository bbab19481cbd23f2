"""What `bavo-view` logs to rerun, as small pure functions of an `EpisodeData` and a frame.

Entity paths (the world is the robot base frame B: metres, +z up):

| path | archetype | when |
|---|---|---|
| `world` | ViewCoordinates (right-handed, z up) | static |
| `world/point_cloud` | Points3D: base-frame xyz, rgb colours | every frame |
| `world/camera` | Transform3D: T_B<-C from `observation.camera_pose` | every frame |
| `world/camera/image` | Pinhole: K, image size, OpenCV axes (RDF) | static |
| `world/camera/image/rgb` | Image (JPEG) | every frame, where the source has RGB |
| `world/camera/image/depth` | DepthImage (m) | every frame, where the source has depth |
| `world/camera_path` | LineStrips3D: camera positions of frames 0..k | every frame |
| `world/occluder` | Boxes3D: the panel (15 x 15 x 0.6 cm) | while an occlusion event is active; cleared
otherwise |
| `world/teacher/queries` | Arrows3D: teacher query points at t -> their answer at t + 15 | optional
(`--teacher`) |
| `world/teacher/relation` | Points3D coloured by the relation change dR^T of the chosen point | optional
(`--relation-point`) |
| `world/policy/action_chunk/<arm>` | LineStrips3D: grippers along the predicted chunk (forward kinematics of
the predicted joint targets) | eval, frames where a chunk was predicted |
| `plots/visibility` | Scalars: V of the current target | every frame (occluded conditions) |
| `plots/progress` | Scalars: milestone depth 0..5 | every frame |
| `plots/milestones/m1..m5` | Scalars: 0 / 1 | every frame |
| `plots/recovering` | Scalars: 1 while the view is being recovered | every frame (where recorded) |
| `plots/occlusion_events` | Scalars + SeriesPoints markers: V at each event start | event starts |
| `events` | TextLog: event index and target | event starts |
| `policy/action_chunk` | Tensor (k, 21): predicted joint targets | eval, where a chunk was predicted |

Timelines: `frame_index` (sequence) and `time` (seconds, the dataset's timestamps).
"""

from __future__ import annotations

import numpy as np

from lerobot_bavo.viz.episode import (
    FUTURE_OFFSET,
    OCCLUDER_HALF_EXTENTS,
    EpisodeData,
    diverging_colors,
    relation_row,
    to_base_frame,
)

WORLD = "world"
CLOUD = "world/point_cloud"
CAMERA = "world/camera"
PINHOLE = "world/camera/image"
RGB = "world/camera/image/rgb"
DEPTH = "world/camera/image/depth"
CAMERA_PATH = "world/camera_path"
OCCLUDER = "world/occluder"
TEACHER_QUERIES = "world/teacher/queries"
RELATION = "world/teacher/relation"
CHUNK_PATH = "world/policy/action_chunk"
VISIBILITY = "plots/visibility"
PROGRESS = "plots/progress"
MILESTONES = "plots/milestones"
RECOVERING = "plots/recovering"
EVENT_MARKERS = "plots/occlusion_events"
EVENTS = "events"
CHUNK = "policy/action_chunk"
TIMELINE = "frame_index"
SECONDS = "time"

OCCLUDER_COLOR = (230, 40, 40)
OCCLUDER_IDLE_COLOR = (160, 160, 160)
CAMERA_PATH_COLOR = (255, 200, 0)
ARM_COLORS = {"left": (40, 120, 255), "right": (40, 200, 80), "camera": (255, 200, 0)}


def static_entities(ep: EpisodeData) -> dict[str, object]:
    """Entities logged once (no timeline)."""
    import rerun as rr

    H, W = ep.image_size
    out: dict[str, object] = {
        WORLD: rr.ViewCoordinates.RIGHT_HAND_Z_UP,
        PINHOLE: rr.Pinhole(image_from_camera=np.asarray(ep.K, dtype=np.float32), resolution=[W, H],
                            camera_xyz=rr.ViewCoordinates.RDF, image_plane_distance=0.12),
    }
    names = {
        VISIBILITY: "visibility V",
        PROGRESS: "progress (milestone depth)",
        RECOVERING: "recovering the view",
        **{f"{MILESTONES}/m{i}": f"M{i}" for i in range(1, 6)},
    }
    for path, name in names.items():
        out[path] = rr.SeriesLines(names=name)
    if ep.occlusion_event is not None:
        out[EVENT_MARKERS] = rr.SeriesPoints(markers="diamond", marker_sizes=6.0, colors=OCCLUDER_COLOR,
                                             names="event start")
    return out


def cloud_entity(ep: EpisodeData, k: int):
    import rerun as rr

    pts = ep.point_cloud[k]
    rgb = np.clip(pts[:, 3:6], 0.0, 1.0)
    return rr.Points3D(pts[:, :3], colors=rgb, radii=0.004)


def camera_transform(ep: EpisodeData, k: int):
    """Transform3D of the active camera at frame k: exactly T_B<-C of `observation.camera_pose`."""
    import rerun as rr

    pose = np.asarray(ep.camera_pose[k], dtype=np.float64)
    return rr.Transform3D(translation=pose[:3, 3], mat3x3=pose[:3, :3])


def camera_path(ep: EpisodeData, k: int):
    import rerun as rr

    return rr.LineStrips3D([ep.camera_pose[: k + 1, :3, 3]], colors=CAMERA_PATH_COLOR, radii=0.002)


def occluder_active(ep: EpisodeData, k: int) -> bool:
    """An occluder stands at frame k: an event has started and the source recorded the panel's pose."""
    if ep.occluder_pose is None:
        return False
    if ep.occlusion_event is not None and ep.occlusion_event[k] < 0:
        return False
    return bool(np.linalg.norm(ep.occluder_pose[k, 3:7]) > 0.5)


def occluder_entity(ep: EpisodeData, k: int):
    """Boxes3D of the panel at frame k (red while the view is being recovered), or a Clear."""
    import rerun as rr

    if not occluder_active(ep, k):
        return rr.Clear(recursive=False)
    pose = ep.occluder_pose[k].astype(np.float64)
    w, x, y, z = pose[3:7] / np.linalg.norm(pose[3:7])
    recovering = ep.occlusion_active is not None and bool(ep.occlusion_active[k])
    label = None
    if ep.occlusion_event is not None:
        label = f"occluder (event {int(ep.occlusion_event[k])}"
        if ep.occlusion_target is not None and ep.occlusion_target[k]:
            label += f", hides {ep.occlusion_target[k]}"
        label += ")"
    return rr.Boxes3D(
        half_sizes=[OCCLUDER_HALF_EXTENTS],
        centers=[pose[:3]],
        quaternions=[rr.Quaternion(xyzw=[x, y, z, w])],
        colors=OCCLUDER_COLOR if recovering or ep.occlusion_active is None else OCCLUDER_IDLE_COLOR,
        fill_mode="solid",
        labels=label,
    )


def teacher_query_entity(ep: EpisodeData, k: int):
    """Arrows from each teacher query point at frame k (z0, moved to the base frame with the pose of k) to
    the teacher's answer 15 frames later (zf, in the camera frame of k + 15, clamped to the last frame)."""
    import rerun as rr

    poses = ep.meta.get("future_camera_pose", ep.camera_pose)  # all frames' poses, also after a `head`
    kf = min(k + FUTURE_OFFSET, len(poses) - 1)
    p0 = to_base_frame(ep.teacher_z0[k, :, :3].astype(np.float64), ep.camera_pose[k])
    pf = to_base_frame(ep.teacher_zf[k, :, :3].astype(np.float64), poses[kf])
    return rr.Arrows3D(origins=p0, vectors=pf - p0, radii=0.0015, colors=(255, 0, 255))


def relation_entity(ep: EpisodeData, k: int, point: int):
    """The cloud at frame k coloured by the teacher's relation change dR^T of `point` to every point
    (red: moves away from it over the next 15 frames, blue: comes closer); the chosen point is large."""
    import rerun as rr

    _, d_r = relation_row(ep.teacher_z0[k, :, :3], ep.teacher_zf[k, :, :3], point)
    colors = diverging_colors(d_r)
    radii = np.full(ep.n_points, 0.006, dtype=np.float32)
    radii[point] = 0.02
    colors[point] = (255, 0, 255)
    return rr.Points3D(ep.point_cloud[k, :, :3], colors=colors, radii=radii)


def chunk_path_entities(paths: dict[str, np.ndarray]) -> dict[str, object]:
    import rerun as rr

    return {
        f"{CHUNK_PATH}/{arm}": rr.LineStrips3D([p], colors=ARM_COLORS.get(arm, (255, 255, 255)), radii=0.003)
        for arm, p in paths.items()
    }


def frame_entities(ep: EpisodeData, k: int, *, teacher: bool = False, relation_point: int | None = None,
                   images: bool = True) -> dict[str, object]:
    """Everything logged at frame k (time series excepted: `scalar_columns`), entity path -> archetype."""
    import rerun as rr

    out: dict[str, object] = {
        CLOUD: cloud_entity(ep, k),
        CAMERA: camera_transform(ep, k),
        CAMERA_PATH: camera_path(ep, k),
    }
    if ep.occluder_pose is not None:
        out[OCCLUDER] = occluder_entity(ep, k)
    if images and ep.rgb is not None:
        out[RGB] = rr.Image(ep.rgb[k]).compress(jpeg_quality=85)
    if images and ep.depth is not None:
        out[DEPTH] = rr.DepthImage(ep.depth[k], meter=1.0)
    if teacher and ep.teacher_z0 is not None and ep.teacher_zf is not None:
        out[TEACHER_QUERIES] = teacher_query_entity(ep, k)
    if relation_point is not None and ep.teacher_z0 is not None and ep.teacher_zf is not None:
        out[RELATION] = relation_entity(ep, k, relation_point)
    if k in ep.chunk_paths:
        out.update(chunk_path_entities(ep.chunk_paths[k]))
    if k in ep.action_chunk:
        out[CHUNK] = rr.Tensor(np.asarray(ep.action_chunk[k], dtype=np.float32), dim_names=["step", "joint"])
    if ep.event_start is not None and ep.event_start[k]:
        target = ep.occlusion_target[k] if ep.occlusion_target is not None else None
        index = int(ep.occlusion_event[k]) if ep.occlusion_event is not None else -1
        out[EVENTS] = rr.TextLog(
            f"occlusion event {index} starts" + (f": the occluder hides the {target}" if target else ""),
            level="WARN",
        )
    return out


def scalar_columns(ep: EpisodeData) -> dict[str, np.ndarray]:
    """Time series over all frames, entity path -> (T,) float64 values (NaN where there is none)."""
    out: dict[str, np.ndarray] = {}
    if ep.visibility is not None:
        v = ep.visibility.astype(np.float64)
        out[VISIBILITY] = np.where(v < 0, np.nan, v)
    if ep.progress is not None:
        out[PROGRESS] = ep.progress.astype(np.float64)
    if ep.milestones is not None:
        for i in range(ep.milestones.shape[1]):
            out[f"{MILESTONES}/m{i + 1}"] = ep.milestones[:, i].astype(np.float64)
    if ep.occlusion_active is not None:
        out[RECOVERING] = ep.occlusion_active.astype(np.float64)
    return out


def event_frames(ep: EpisodeData) -> np.ndarray:
    """Frames where an occlusion event starts."""
    if ep.event_start is None:
        return np.zeros(0, dtype=np.int64)
    return np.flatnonzero(ep.event_start)

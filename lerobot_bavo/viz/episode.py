"""One episode as plain arrays: what `bavo-view` draws, read from a BAVO dataset (never re-simulated).

`EpisodeData` is the viewer's only input. `load_dataset_episode` fills it from a local LeRobot v3.0
dataset without building a `LeRobotDataset` (which would index and decode far more than one episode):
the episode's row of `meta/episodes`, a filtered read of its data file, and a PyAV decode of its video
segment only. `lerobot_bavo.viz.recorder` fills the same structure from a `bavo-eval` rollout.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

# re-exported for viz.entities: zf answers for frame t + 15 (camera frame of t + 15); the occluder's
# (thickness, width, height) / 2 in its frame, metres
from lerobot_bavo.datasets.schema import N_FUTURE as FUTURE_OFFSET  # noqa: F401
from lerobot_bavo.envs.occlusion import OCCLUDER_HALF_EXTENTS  # noqa: F401
from lerobot_bavo.features import (
    ACTION,
    ANN_ACTIVE,
    ANN_EVENT,
    ANN_EVENT_START,
    ANN_OCCLUDER_POSE,
    ANN_PROGRESS,
    ANN_TARGET,
    ANN_VISIBILITY,
    OBS_CAMERA_POSE,
    OBS_IMAGE,
    OBS_POINT_CLOUD,
    POINT_CHANNELS,
    TEACHER_Z0,
    TEACHER_ZF,
    ObservationSettings,
)
from lerobot_bavo.sim.constants import (
    ACTIVE_CAMERA_FOVY as DEFAULT_FOVY,  # the active camera's vertical FoV, degrees
)


@dataclass
class EpisodeData:
    """One episode of T frames, frame as leading axis. Optional fields are None where the source lacks them.

    Required: frame_index (T,) int64; timestamp (T,) float64 seconds; point_cloud (T, N, 6) float32 xyz in
    the base frame (m) + rgb in [0, 1]; camera_pose (T, 4, 4) T_B<-C (OpenCV camera axes); K (3, 3)
    intrinsics; image_size (H, W).
    Optional: rgb (T, H, W, 3) uint8; depth (T, H, W) float32 metres; progress (T,) int64 milestone depth;
    milestones (T, 5) bool instantaneous flags m1..m5 (datasets store only the depth: flags m_k = depth >= k);
    visibility (T,) float32 V of the current target (-1: none); occlusion_event (T,) int64 (-1: none);
    event_start (T,) bool; occlusion_active (T,) bool (recovering the view); occluder_pose (T, 7)
    float32 centre xyz + wxyz quaternion (all 0: no occluder); occlusion_target (T,) names or None;
    teacher_z0 / teacher_zf (T, N, 3) camera-frame teacher answers; action (T, 21); action_chunk: frame
    -> (k, 21) joint targets the policy predicted at that frame; chunk_paths: frame -> {arm: (k, 3)}.
    """

    frame_index: np.ndarray
    timestamp: np.ndarray
    point_cloud: np.ndarray
    camera_pose: np.ndarray
    K: np.ndarray
    image_size: tuple[int, int]
    rgb: np.ndarray | None = None
    depth: np.ndarray | None = None
    progress: np.ndarray | None = None
    milestones: np.ndarray | None = None
    visibility: np.ndarray | None = None
    occlusion_event: np.ndarray | None = None
    event_start: np.ndarray | None = None
    occlusion_active: np.ndarray | None = None
    occluder_pose: np.ndarray | None = None
    occlusion_target: list[str | None] | None = None
    teacher_z0: np.ndarray | None = None
    teacher_zf: np.ndarray | None = None
    action: np.ndarray | None = None
    action_chunk: dict[int, np.ndarray] = field(default_factory=dict)
    chunk_paths: dict[int, dict[str, np.ndarray]] = field(default_factory=dict)
    name: str = "episode"
    meta: dict = field(default_factory=dict)

    @property
    def length(self) -> int:
        return int(self.frame_index.shape[0])

    @property
    def n_points(self) -> int:
        return int(self.point_cloud.shape[1])

    def head(self, n: int) -> EpisodeData:
        """The first n frames (a copy sharing the arrays' memory)."""
        import dataclasses

        n = max(1, min(int(n), self.length))
        out = {}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if isinstance(v, np.ndarray) and f.name != "K" or isinstance(v, list):
                v = v[:n]
            elif isinstance(v, dict) and f.name in ("action_chunk", "chunk_paths"):
                v = {k: x for k, x in v.items() if k < n}
            out[f.name] = v
        # the teacher's answers at t + 15 need frames after n: keep the camera poses they are expressed in
        if self.teacher_zf is not None and n < self.length:
            out["meta"] = {**self.meta, "future_camera_pose": self.camera_pose}
        return EpisodeData(**out)


# ----------------------------------------------------------------------------- pure helpers
def intrinsics(fovy_deg: float, height: int, width: int) -> np.ndarray:
    """Pinhole K of the active camera, as `envs.pointcloud.intrinsics_from_fovy`: f = 0.5 H / tan(fovy / 2),
    principal point at the image centre in pixel-centre indices ((W - 1) / 2, (H - 1) / 2)."""
    f = 0.5 * height / np.tan(np.deg2rad(fovy_deg) / 2.0)
    return np.array([[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0.0, 0.0, 1.0]])


def to_base_frame(points_c: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """(N, 3) points in the camera frame -> base frame with T_B<-C (4, 4)."""
    return points_c @ pose[:3, :3].T + pose[:3, 3]


def milestones_from_progress(progress: np.ndarray) -> np.ndarray:
    """(T,) milestone depth -> (T, 5) flags: the tracker counts M_k only after M_{k-1}, so m_k = depth >=
    k."""
    return np.asarray(progress)[:, None] >= np.arange(1, 6)[None, :]


def relation_row(z0: np.ndarray, zf: np.ndarray, i: int, eps: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """Teacher relations of point i to every point (paper Eq. 4, `teacher.relations` in numpy).

    R^T_ij = ||z0_i - z0_j|| / (mean_{p<q} ||z0_p - z0_q|| + eps); dR^T_ij = R(ZF|Z0)_ij - R^T_ij.
    Returns (R row (N,), dR row (N,))."""
    z0 = np.asarray(z0, dtype=np.float64)
    zf = np.asarray(zf, dtype=np.float64)
    n = z0.shape[0]
    if not 0 <= i < n:
        raise ValueError(f"relation point {i} is out of range: the clouds have {n} points")
    d0 = np.linalg.norm(z0[:, None] - z0[None], axis=-1)
    scale = d0[np.triu_indices(n, 1)].mean() + eps
    r = d0[i] / scale
    rf = np.linalg.norm(zf - zf[i], axis=-1) / scale
    return r, rf - r


def diverging_colors(values: np.ndarray, limit: float | None = None) -> np.ndarray:
    """Blue (negative) - white (0) - red (positive) RGB uint8 colours for a heat map, symmetric in +-limit."""
    v = np.asarray(values, dtype=np.float64)
    lim = float(limit) if limit else float(np.max(np.abs(v))) or 1.0
    x = np.clip(v / lim, -1.0, 1.0)[:, None]
    white = np.array([1.0, 1.0, 1.0])
    red, blue = np.array([0.80, 0.10, 0.10]), np.array([0.10, 0.25, 0.85])
    rgb = np.where(x >= 0, white + x * (red - white), white - x * (blue - white))
    return (255 * rgb).round().astype(np.uint8)


# ----------------------------------------------------------------------------- datasets
class EpisodeNotFound(ValueError):
    pass


def _n_points(features: dict) -> int:
    if OBS_POINT_CLOUD not in features:
        raise ValueError(f"missing feature {OBS_POINT_CLOUD!r}: not a BAVO dataset")
    (width,) = features[OBS_POINT_CLOUD]["shape"]
    return int(width) // POINT_CHANNELS


def _episode_row(root: Path, episode: int) -> dict:
    import pyarrow.dataset as pads
    import pyarrow.parquet as pq

    files = sorted((root / "meta" / "episodes").glob("*/*.parquet"))
    if not files:
        raise FileNotFoundError(f"{root} has no meta/episodes/*/*.parquet: not a LeRobot v3.0 dataset")
    names = [n for n in pq.read_schema(files[0]).names if not n.startswith("stats/")]
    table = pads.dataset(files, format="parquet").to_table(
        columns=names, filter=pads.field("episode_index") == episode)
    if table.num_rows != 1:
        raise EpisodeNotFound(f"{root} has no episode {episode}")
    return table.to_pylist()[0]


def _decode_segment(path: Path, t0: float, t1: float, fps: float, n: int) -> np.ndarray:
    """Frames k = 0..n-1 of a video segment [t0, t1) (frame k at t0 + k / fps), (n, H, W, 3) uint8, decoded
    with PyAV from the keyframe before t0."""
    import av

    out: np.ndarray | None = None
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        stream.thread_type = "NONE"
        container.seek(
            max(0, int((t0 - 0.5 / fps) / stream.time_base)), stream=stream, backward=True, any_frame=False
        )
        for frame in container.decode(stream):
            k = int(round((float(frame.time) - t0) * fps))
            if k < 0:
                continue
            if k >= n:
                break
            img = frame.to_ndarray(format="rgb24")
            if out is None:
                out = np.zeros((n, *img.shape), dtype=np.uint8)
            out[k] = img
            last = k
    if out is None or last < n - 1:
        raise ValueError(
            f"{path}: the video segment [{t0:.3f}, {t1:.3f}) s does not cover the episode's {n} frames"
        )
    return out


class _EpisodeColumns:
    """One episode's rows of a data file as arrays in frame order (LeRobot's files need not store them so).

    Missing columns read as None: datasets collected before a column existed lack it."""

    def __init__(self, table) -> None:
        self._table = table
        self.length = table.num_rows
        self._order = np.argsort(self._raw("frame_index"))

    def _raw(self, key: str, width: int | None = None) -> np.ndarray | None:
        if key not in self._table.column_names:
            return None
        c = self._table.column(key).combine_chunks()
        if width is None:
            return c.to_numpy(zero_copy_only=False)
        if hasattr(c, "flatten"):  # list / fixed-size-list column; (1,) features are stored as plain values
            c = c.flatten()
        return np.asarray(c.to_numpy(zero_copy_only=False)).reshape(self.length, width)

    def get(self, key: str, width: int | None = None) -> np.ndarray | None:
        """Column `key` in frame order: (T,) when `width` is None, else (T, width)."""
        x = self._raw(key, width)
        return None if x is None else x[self._order]

    def scalar(self, key: str, dtype) -> np.ndarray | None:
        """A (1,)-shaped feature as a (T,) array of `dtype`."""
        x = self.get(key, 1)
        return None if x is None else x[:, 0].astype(dtype)


def _episode_rgb(root: Path, info: dict, row: dict, length: int) -> np.ndarray | None:
    """The episode's span of its active-camera video file, (T, H, W, 3) uint8; None for image features."""
    if info["features"][OBS_IMAGE]["dtype"] != "video":
        return None
    key = OBS_IMAGE
    path = root / info["video_path"].format(
        video_key=key, chunk_index=row[f"videos/{key}/chunk_index"],
        file_index=row[f"videos/{key}/file_index"],
    )
    return _decode_segment(path, float(row[f"videos/{key}/from_timestamp"]),
                           float(row[f"videos/{key}/to_timestamp"]), float(info["fps"]), length)


def load_dataset_episode(root: str | Path, episode: int, *, video: bool = True) -> EpisodeData:
    """One episode of a local BAVO dataset (LeRobot v3.0 layout) as `EpisodeData`.

    Reads only that episode: its `meta/episodes` row, its rows of one data file and its span of one video
    file. Clouds stored in the camera frame (`point_frame="camera"`) are moved to the base frame with
    `observation.camera_pose`, so the scene stays put while the camera moves."""
    import pyarrow.dataset as pads

    root = Path(root)
    info_path = root / "meta" / "info.json"
    if not info_path.is_file():
        raise FileNotFoundError(f"{root} has no meta/info.json: not a LeRobot dataset")
    info = json.loads(info_path.read_text())
    features = info["features"]
    n = _n_points(features)
    sidecar_path = root / "meta" / "bavo_collection.json"
    settings = json.loads(sidecar_path.read_text()).get("settings", {}) if sidecar_path.is_file() else {}
    row = _episode_row(root, episode)

    data_file = root / info["data_path"].format(
        chunk_index=row["data/chunk_index"], file_index=row["data/file_index"]
    )
    wanted = ["frame_index", "timestamp", OBS_POINT_CLOUD, OBS_CAMERA_POSE, ACTION,
              ANN_PROGRESS, ANN_VISIBILITY, ANN_EVENT, ANN_EVENT_START, ANN_ACTIVE, ANN_TARGET,
              ANN_OCCLUDER_POSE, TEACHER_Z0, TEACHER_ZF]
    columns = [c for c in wanted if c in features]
    table = pads.dataset(data_file, format="parquet").to_table(
        columns=columns, filter=pads.field("episode_index") == episode)
    T = table.num_rows
    if row["length"] != T:
        raise ValueError(f"{data_file}: episode {episode} has {T} rows, meta/episodes says {row['length']}")
    cols = _EpisodeColumns(table)

    def width(key: str) -> int | None:
        return features[key]["shape"][0] if key in features else None

    cloud = cols.get(OBS_POINT_CLOUD, n * POINT_CHANNELS).reshape(T, n, POINT_CHANNELS).astype(np.float32)
    pose = cols.get(OBS_CAMERA_POSE, 16).reshape(T, 4, 4).astype(np.float64)
    if settings.get("point_frame", "base") == "camera":
        cloud = cloud.copy()
        for t in range(T):
            cloud[t, :, :3] = to_base_frame(cloud[t, :, :3], pose[t])

    progress = cols.scalar(ANN_PROGRESS, np.int64)
    target_stage = cols.scalar(ANN_TARGET, np.int64)
    targets = settings.get("stage_targets")
    occlusion_target = None
    if target_stage is not None:
        occlusion_target = [None if s < 0 else (targets[s] if targets and s < len(targets) else f"stage {s}")
                            for s in target_stage]
    z0, zf = cols.get(TEACHER_Z0, width(TEACHER_Z0)), cols.get(TEACHER_ZF, width(TEACHER_ZF))

    H, W = settings.get("image_height"), settings.get("image_width")
    rgb = None
    if OBS_IMAGE in features:
        H, W = features[OBS_IMAGE]["shape"][:2]
        if video:
            rgb = _episode_rgb(root, info, row, T)
    if H is None:
        H, W = ObservationSettings.image_height, ObservationSettings.image_width
    fovy = float(settings.get("fovy", DEFAULT_FOVY))
    return EpisodeData(
        frame_index=cols.get("frame_index").astype(np.int64),
        timestamp=cols.get("timestamp").astype(np.float64),
        point_cloud=cloud,
        camera_pose=pose,
        K=intrinsics(fovy, int(H), int(W)),
        image_size=(int(H), int(W)),
        rgb=rgb,
        progress=progress,
        milestones=None if progress is None else milestones_from_progress(progress),
        visibility=cols.scalar(ANN_VISIBILITY, np.float32),
        occlusion_event=cols.scalar(ANN_EVENT, np.int64),
        event_start=None if (x := cols.scalar(ANN_EVENT_START, np.float32)) is None else x > 0.5,
        occlusion_active=None if (x := cols.scalar(ANN_ACTIVE, np.float32)) is None else x > 0.5,
        occluder_pose=cols.get(ANN_OCCLUDER_POSE, 7),
        occlusion_target=occlusion_target,
        teacher_z0=None if z0 is None else z0.reshape(T, n, -1).astype(np.float32),
        teacher_zf=None if zf is None else zf.reshape(T, n, -1).astype(np.float32),
        action=cols.get(ACTION, width(ACTION)) if ACTION in features else None,
        name=f"{root.name} episode {episode}",
        meta={
            "source": "dataset",
            "root": str(root),
            "episode_index": int(episode),
            "fps": float(info["fps"]),
            "task": settings.get("task"),
            "condition": settings.get("condition"),
            "point_frame": settings.get("point_frame", "base"),
        },
    )

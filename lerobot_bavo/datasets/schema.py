"""The one feature schema of BAVO-Bench datasets (LeRobot v3.0), and helpers to reshape it back.

Every array feature is stored **flat** (1-D): LeRobot 0.6.1's `delete_episodes` / `merge_datasets`
fail on 2-D features, so (N, C) arrays are stored row-major as (N * C,).
`unflatten_point_cloud` / ... (over `lerobot_bavo.features.unflatten_points`) give them back as
(..., N, C); they accept both the flat layout (dataset, (..., N * C)) and the unflattened one (env,
(..., N, C)). The keys and `ObservationSettings` (which fixes the schema) live in `lerobot_bavo.features`.

Features (N = points per cloud, H x W = active image size; all per frame, 25 fps):

| key | shape | dtype | meaning |
|---|---|---|---|
| observation.state | (21,) | float32 | joint state: left 6 + gripper, right 6 + gripper, camera arm 7 (rad;
grippers 0 closed .. 1 open) |
| action | (21,) | float32 | absolute joint targets, same order, sent after observing this frame |
| observation.images.active | (H, W, 3) | video | active-camera RGB |
| observation.point_cloud | (N*6,) | float32 | (N, 6) row-major: xyz (m, base frame unless
`point_frame="camera"`) + rgb in [0, 1] |
| observation.point_pixels | (N*2,) | float32 | (N, 2) row-major: source pixel (u = column, v = row) of each
point; -1 if the view was empty |
| observation.camera_pose | (16,) | float32 | T_B<-C (4, 4) row-major, OpenCV camera axes (x right, y down, z
forward) |
| observation.environment_state | (7 K,) | float32 | privileged: the task's K object poses (xyz m, base frame;
wxyz quaternion), as AV-ALOHA's `environment_state`; only for privileged-state policies (absent from datasets
collected before it existed) |
| observation.teacher.z0 | (N*3,) | float32 | (N, 3): teacher answer to q0 = (u, v, t, t, t) (see
`lerobot_bavo.teacher`) |
| observation.teacher.zf | (N*3,) | float32 | (N, 3): teacher answer to qF = (u, v, t, t+15, t+15) |
| observation.teacher.visible | (N,) | float32 | 1 if the queried point is the first surface seen along its
ray at t+15, else 0 |
| observation.teacher.valid | (1,) | float32 | 1 if frame t+15 exists in the episode; 0 where it was clamped
to the last frame |
| annotation.progress | (1,) | int64 | milestone depth d in 0..5 reached at this frame |
| annotation.occlusion_event | (1,) | int64 | index of the current occlusion event (0, 1, 2 under Stage), -1
if none |
| annotation.event_start | (1,) | float32 | 1 at the frame where an occlusion event starts (the occluder was
just placed) |
| annotation.occlusion_active | (1,) | float32 | 1 while the demonstrator is recovering the view after an
event (its action at this frame is a recovery move) |
| annotation.occlusion_target | (1,) | int64 | stage index s of the event's target, i.e. the target is
`task.stage_targets[s]`; -1 if none |
| annotation.visibility | (1,) | float32 | visibility ratio V of the current target in [0, 1] (privileged
render); -1 under Clean |
| annotation.episode_seed | (1,) | int64 | the env / expert seed of the episode |
| annotation.source | (1,) | int64 | who demonstrated the episode: 0 = scripted expert (`bavo-collect`), 1 =
human (`bavo-teleop`); absent from datasets collected before it existed |
| annotation.occluder_pose | (7,) | float32 | the occluder panel's centre (m, base frame) and wxyz quaternion
at this frame; all 0 when there is none (Clean); absent from datasets collected before it existed |

`annotation.*` columns are kept in the dataset but never reach a policy: LeRobot's
`dataset_to_policy_features` types only `observation.*` and `action*` keys, and
`batch_to_transition` drops other keys before `forward`. `observation.teacher.*` keys do reach
`forward` (training targets); the policies remove them from `input_features`.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from lerobot_bavo.features import (  # the keys and settings this schema is made of; defined there once
    ACTION,
    ANN_ACTIVE,
    ANN_EVENT,
    ANN_EVENT_START,
    ANN_OCCLUDER_POSE,
    ANN_PROGRESS,
    ANN_SEED,
    ANN_SOURCE,
    ANN_TARGET,
    ANN_VISIBILITY,
    ANNOTATION_KEYS,
    OBS_CAMERA_POSE,
    OBS_ENV_STATE,
    OBS_IMAGE,
    OBS_POINT_CLOUD,
    OBS_POINT_PIXELS,
    OBS_STATE,
    OPTIONAL_ANNOTATION_KEYS,
    PIXEL_CHANNELS,
    POINT_CHANNELS,
    POSE_CHANNELS,
    SOURCES,  # noqa: F401  (re-exported: schema users read S.SOURCES)
    TEACHER_CHANNELS,
    TEACHER_KEYS,
    TEACHER_OCCLUDER,  # noqa: F401  (re-exported)
    TEACHER_RECOVERING,  # noqa: F401  (re-exported)
    TEACHER_SAMPLE_WEIGHT,  # noqa: F401  (re-exported)
    TEACHER_VALID,
    TEACHER_VISIBLE,
    TEACHER_Z0,
    TEACHER_ZF,
    ObservationSettings,
    unflatten_points,
)
from lerobot_bavo.sim import constants as C
from lerobot_bavo.teacher.protocol import ANCHOR_INDEX, CLIP_LENGTH, FUTURE_INDEX  # noqa: F401  (re-exported)

FPS = C.CONTROL_HZ  # 25

# Teacher configuration (paper, Appendix B; `lerobot_bavo.teacher.protocol`): 32-frame clips, anchor 16,
# future 31, so Delta t = 15.
N_FUTURE = FUTURE_INDEX - ANCHOR_INDEX


def joint_names() -> list[str]:
    """The 21 state / action entry names, in order."""
    return list(C.ACTION_NAMES)


def build_features(
    settings: ObservationSettings, use_videos: bool = True, env_state_dim: int = 0
) -> dict[str, dict]:
    """LeRobot feature dict (for `LeRobotDataset.create`) of a BAVO dataset with these settings.

    `env_state_dim` > 0 adds `observation.environment_state` (the task's object poses, 7 per object;
    `lerobot_bavo.envs.tasks.environment_state_dim(task)`)."""
    n = settings.n_points
    names = joint_names()

    def vec(dim: int, dtype: str = "float32", names_=None) -> dict:
        return {"dtype": dtype, "shape": (dim,), "names": names_}

    features = {
        OBS_STATE: vec(C.ACTION_DIM, names_=names),
        ACTION: vec(C.ACTION_DIM, names_=list(names)),
        OBS_IMAGE: {
            "dtype": "video" if use_videos else "image",
            "shape": (settings.image_height, settings.image_width, 3),
            "names": ["height", "width", "channels"],
        },
        OBS_POINT_CLOUD: vec(n * POINT_CHANNELS),
        OBS_POINT_PIXELS: vec(n * PIXEL_CHANNELS),
        OBS_CAMERA_POSE: vec(16),
        **({OBS_ENV_STATE: vec(env_state_dim)} if env_state_dim else {}),
        TEACHER_Z0: vec(n * TEACHER_CHANNELS),
        TEACHER_ZF: vec(n * TEACHER_CHANNELS),
        TEACHER_VISIBLE: vec(n),
        TEACHER_VALID: vec(1),
        ANN_PROGRESS: vec(1, "int64"),
        ANN_EVENT: vec(1, "int64"),
        ANN_EVENT_START: vec(1),
        ANN_ACTIVE: vec(1),
        ANN_TARGET: vec(1, "int64"),
        ANN_VISIBILITY: vec(1),
        ANN_SEED: vec(1, "int64"),
        ANN_SOURCE: vec(1, "int64"),
        ANN_OCCLUDER_POSE: vec(POSE_CHANNELS),
    }
    return features


def expected_shapes(
    n_points: int, image_hw: tuple[int, int] | None = None
) -> dict[str, tuple[tuple[int, ...], str]]:
    """(shape, dtype) of every BAVO feature for `n_points` (the image entry only if `image_hw`)."""
    default = ObservationSettings()
    settings = ObservationSettings(
        *(image_hw or (default.image_height, default.image_width)), n_points=n_points
    )
    out = {k: (tuple(ft["shape"]), ft["dtype"]) for k, ft in build_features(settings).items()}
    if image_hw is None:
        out.pop(OBS_IMAGE)
    return out


def infer_n_points(features: Mapping[str, Mapping]) -> int:
    """N from a dataset's features (`observation.point_cloud` is (N * 6,)); ValueError if not."""
    if OBS_POINT_CLOUD not in features:
        raise ValueError(f"missing feature {OBS_POINT_CLOUD!r}: not a BAVO dataset")
    shape = tuple(features[OBS_POINT_CLOUD]["shape"])
    if len(shape) != 1 or shape[0] % POINT_CHANNELS:
        raise ValueError(
            f"feature {OBS_POINT_CLOUD!r} has shape {shape}; expected the flat layout (N * {POINT_CHANNELS},)"
        )
    return shape[0] // POINT_CHANNELS


def check_features(features: Mapping[str, Mapping], n_points: int | None = None,
                   require_teacher: bool = True, require_annotations: bool = True) -> int:
    """Validate a feature dict against the BAVO schema; return N. Raises ValueError naming the problem.

    Args:
        features: a dataset's `meta.features` (or `info.json`'s "features").
        n_points: expected N; None infers it from `observation.point_cloud`.
        require_teacher: the teacher cache (`observation.teacher.*`) must be present.
        require_annotations: the `annotation.*` columns must be present.
    """
    found = infer_n_points(features)
    if n_points is not None and found != n_points:
        raise ValueError(
            f"dataset has {found} points per cloud ({OBS_POINT_CLOUD} shape ({found * POINT_CHANNELS},)) "
            f"but {n_points} were requested"
        )
    expected = expected_shapes(found)
    if OBS_IMAGE in features:
        ft = features[OBS_IMAGE]
        if (
            ft["dtype"] not in ("video", "image")
            or len(tuple(ft["shape"])) != 3
            or tuple(ft["shape"])[2] != 3
        ):
            raise ValueError(f"feature {OBS_IMAGE!r} must be an (H, W, 3) video or image, got {dict(ft)}")
    else:
        raise ValueError(f"missing feature {OBS_IMAGE!r}")
    missing_teacher = [k for k in TEACHER_KEYS if k not in features]
    if require_teacher and missing_teacher:
        raise ValueError(
            f"missing teacher cache {missing_teacher}: this dataset has no cached 4D-teacher targets "
            f"(collect it with `bavo-collect`, which computes them, or pass require_teacher=False)"
        )
    if TEACHER_Z0 in features or TEACHER_ZF in features:
        # A learned teacher may have any feature width d: z0 and zf are (N * d,) with the same d.
        shapes = {k: tuple(features[k]["shape"]) for k in (TEACHER_Z0, TEACHER_ZF) if k in features}
        for key, shape in shapes.items():
            if len(shape) != 1 or shape[0] % found or shape[0] == 0:
                raise ValueError(
                    f"feature {key!r} has shape {shape}, expected (N * d_T,) with N = {found} points"
                )
        if len(set(shapes.values())) > 1:
            raise ValueError(f"teacher features must be point-aligned with the same width: {shapes}")
        d = next(iter(shapes.values()))[0] // found
        expected[TEACHER_Z0] = expected[TEACHER_ZF] = ((found * d,), "float32")
    if OBS_ENV_STATE in features:
        shape = tuple(features[OBS_ENV_STATE]["shape"])
        if len(shape) != 1 or shape[0] % POSE_CHANNELS or features[OBS_ENV_STATE]["dtype"] != "float32":
            raise ValueError(f"feature {OBS_ENV_STATE!r} must be float32 (7 K,) object poses, got "
                             f"{features[OBS_ENV_STATE]['dtype']} {shape}")
    for key, (shape, dtype) in expected.items():
        if key in TEACHER_KEYS and not require_teacher and key not in features:
            continue
        if key in ANNOTATION_KEYS and not require_annotations and key not in features:
            continue
        if key in OPTIONAL_ANNOTATION_KEYS and key not in features:
            continue
        if key not in features:
            raise ValueError(f"missing feature {key!r} (expected shape {shape}, dtype {dtype})")
        got_shape, got_dtype = tuple(features[key]["shape"]), features[key]["dtype"]
        if got_shape != shape:
            raise ValueError(
                f"feature {key!r} has shape {got_shape}, expected {shape} for N = {found} points"
            )
        if got_dtype != dtype:
            raise ValueError(f"feature {key!r} has dtype {got_dtype!r}, expected {dtype!r}")
    return found


# ------------------------------------------------------------------ reshaping
def unflatten_point_cloud(x, n_points: int):
    """`observation.point_cloud` -> (..., N, 6): xyz (m) + rgb in [0, 1]."""
    return unflatten_points(x, n_points, POINT_CHANNELS)


def unflatten_point_pixels(x, n_points: int):
    """`observation.point_pixels` -> (..., N, 2): (u, v) pixel indices as floats."""
    return unflatten_points(x, n_points, PIXEL_CHANNELS)


def unflatten_teacher(x, n_points: int, channels: int = TEACHER_CHANNELS):
    """`observation.teacher.z0` / `.zf` -> (..., N, d_T)."""
    return unflatten_points(x, n_points, channels)


def unflatten_camera_pose(x):
    """`observation.camera_pose` (..., 16) -> (..., 4, 4) T_B<-C."""
    if tuple(x.shape[-2:]) == (4, 4):
        return x
    if x.shape[-1] != 16:
        raise ValueError(f"expected (..., 16) or (..., 4, 4), got {tuple(x.shape)}")
    return x.reshape(*tuple(x.shape)[:-1], 4, 4)


# ------------------------------------------------------------------ per-channel statistics
def channel_stats(values: np.ndarray, quantiles=(0.01, 0.10, 0.50, 0.90, 0.99),
                  channels: list[int] | None = None) -> dict[str, np.ndarray]:
    """Statistics over all leading axes of (..., C) values, per channel: LeRobot's stat keys.

    Returns min, max, mean, std (population), count and q01/q10/q50/q90/q99, each (C,) (count (1,)).
    The values are those of numpy's `min`, `max`, `mean`, `std` and `quantile` along axis 0 of the float64
    (M, C) array, bit for bit, computed so that a whole dataset's point cloud (millions of points) takes a
    fraction of numpy's time (docs/results/costs.md; it runs once at the end of `bavo-collect`): the
    quantiles in one partition per channel of a float64 channel-major copy made in one pass, on two threads;
    the sums for the mean and the std in row blocks (`_row_sum`), each block continuing the previous total
    as numpy's axis-0 sum adds rows, instead of in arrays as large as the input.
    `tests/test_schema_stats.py` checks it against numpy's calls.

    `channels`: only these channels' statistics (the mean and std still summed over all channels' rows: the
    order numpy's axis-0 sum adds in depends on the number of columns, so a subset's sums could differ in
    the last bit); the subsets of a split put together (`hub.merge_channel_stats`) are the whole, bit for bit.
    """
    rows = np.asarray(values).reshape(-1, values.shape[-1])  # as given (float32 for the point cloud)
    if rows.shape[0] == 0:
        raise ValueError("channel_stats needs at least one value per channel")
    picked = list(range(rows.shape[1])) if channels is None else list(channels)
    count = np.intp(rows.shape[0])  # what numpy's mean / var divide by
    by_channel = np.empty((len(picked), rows.shape[0]), dtype=np.float64)
    # float64, channel-major, in one pass (no row-major float64 copy of the input)
    by_channel[...] = rows.T if channels is None else rows[:, picked].T
    mean = np.true_divide(_row_sum(rows, lambda block: block), count)
    squares = _row_sum(rows, lambda block: np.multiply(np.subtract(block, mean, out=block), block, out=block))
    stats = {
        "min": by_channel.min(axis=1), "max": by_channel.max(axis=1), "mean": mean[picked],
        "std": np.sqrt(np.true_divide(squares, count))[picked],
        "count": np.array([rows.shape[0]]),
    }
    for q, value in zip(quantiles, _quantiles(by_channel, list(quantiles))):
        stats[f"q{int(round(q * 100)):02d}"] = value
    return stats


def _row_sum(rows: np.ndarray, transform) -> np.ndarray:
    """numpy's `np.add.reduce(transform(rows as float64), axis=0)`, bit for bit, a block of rows at a time.

    numpy's axis-0 sum of a C-ordered (M, C) array adds the rows one after the other; a block continues the
    previous blocks' total by adding it to its first row (a + b == b + a in floating point), so no float64
    array as large as the input is ever held."""
    total = None
    for start in range(0, rows.shape[0], _STATS_BLOCK_ROWS):
        block = transform(np.array(rows[start:start + _STATS_BLOCK_ROWS], dtype=np.float64))
        if total is not None:
            block[0] += total
        total = np.add.reduce(block, axis=0)
    return total


def _quantiles(by_channel: np.ndarray, quantiles: list[float]) -> np.ndarray:
    """`np.quantile(by_channel, quantiles, axis=1)`, the channels split between two threads (numpy's partition
    releases the GIL; each channel's quantiles depend on that channel only, so the values are the same)."""
    from concurrent.futures import ThreadPoolExecutor

    if by_channel.shape[0] < 2 or by_channel.shape[1] < (1 << 16):
        return np.quantile(by_channel, quantiles, axis=1)
    half = by_channel.shape[0] // 2
    with ThreadPoolExecutor(2) as threads:
        parts = list(threads.map(lambda part: np.quantile(part, quantiles, axis=1),
                                 (by_channel[:half], by_channel[half:])))
    return np.concatenate(parts, axis=1)


# rows of squared deviations held at a time by `channel_stats` (12 MB for 6 channels)
_STATS_BLOCK_ROWS = 1 << 18


def tile_channel_stats(stats: dict[str, np.ndarray], n_points: int) -> dict[str, np.ndarray]:
    """Per-channel (C,) stats tiled to the flat layout (N * C,), so that LeRobot's element-wise
    normaliser on the flat feature normalises every point per channel (ManiFlow's `limits`)."""
    return {k: (v if k == "count" else np.tile(np.asarray(v), n_points)) for k, v in stats.items()}

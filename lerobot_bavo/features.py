"""Feature keys, observation settings and point-cloud layout: the names the env, datasets and policies share.

- Raw env observation keys (`ENV_*`, what `BavoEnv` returns) and their policy / dataset names
  (`OBS_*`, LeRobot's `observation.*` convention; `BavoEnvConfig.features_map` maps one to the other).
- Training-only teacher keys (`observation.teacher.*`) and the dataset's `annotation.*` columns.
- `ObservationSettings`: what the env observes and so what fixes a dataset's schema (image size,
  point count, point frame, field of view); `BavoEnv`, `BavoEnvConfig` and the dataset schema all
  check their settings with it.
- `unflatten_points` / `flatten_points`: datasets store (N, C) arrays flat as (N * C,) (LeRobot's
  episode tools fail on 2-D features); every reshape between the two layouts goes through these.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

from lerobot_bavo.limits import bound_problems
from lerobot_bavo.sim import constants as C

# ------------------------------------------------------------------ raw env observation keys
ENV_STATE_KEY = "agent_pos"
ENV_IMAGE_KEY = "pixels/active"  # LeRobot's "pixels/<camera>" convention for nested camera dicts
ENV_POINT_CLOUD_KEY = "point_cloud"
ENV_POINT_PIXELS_KEY = "point_pixels"
ENV_ENV_STATE_KEY = "environment_state"

# ------------------------------------------------------------------ policy / dataset keys
# LeRobot's names (`lerobot.utils.constants`), spelled out here because importing that module imports PyTorch
# (through `lerobot.utils`), and the env, the experts and the collection / evaluation workers that only step
# them need neither; tests/test_env.py checks they equal LeRobot's.
OBS_STR = "observation"
OBS_STATE = f"{OBS_STR}.state"
OBS_IMAGES = f"{OBS_STR}.images"
ACTION = "action"
OBS_IMAGE = f"{OBS_IMAGES}.active"  # "observation.images.active"
OBS_POINT_CLOUD = f"{OBS_STR}.point_cloud"  # "observation.point_cloud"
OBS_POINT_PIXELS = f"{OBS_STR}.point_pixels"  # "observation.point_pixels"
OBS_CAMERA_POSE = f"{OBS_STR}.camera_pose"  # "observation.camera_pose"
OBS_ENV_STATE = f"{OBS_STR}.environment_state"  # "observation.environment_state"

# Training-only targets: they reach `forward`, and the policies drop them from `input_features`.
TEACHER_PREFIX = f"{OBS_STR}.teacher"
TEACHER_Z0 = f"{TEACHER_PREFIX}.z0"
TEACHER_ZF = f"{TEACHER_PREFIX}.zf"
TEACHER_VISIBLE = f"{TEACHER_PREFIX}.visible"
TEACHER_VALID = f"{TEACHER_PREFIX}.valid"
TEACHER_KEYS = (TEACHER_Z0, TEACHER_ZF, TEACHER_VISIBLE, TEACHER_VALID)
# (N,) float32, 1 where the cloud point lies on the benchmark occluder: a label derived from the occluder's
# pose when a `points` training view is made, for the occluder-dropout training recipe
# (`policies/augment.py`). Not part of a collected dataset.
TEACHER_OCCLUDER = f"{TEACHER_PREFIX}.occluder"
# (1,) float32, 1 on frames the demonstrator spent recovering the view after an occlusion event: a copy of
# `annotation.occlusion_active` made when a `points` training view is made (annotations never reach a policy;
# LeRobot's processors pass only `observation.*` keys through), for the recovery-weighted training recipe
# (`--policy.recovery_weight`). Not part of a collected dataset.
TEACHER_RECOVERING = f"{TEACHER_PREFIX}.recovering"
# (1,) float32 >= 0, each frame's weight in the action losses: written by `scripts/mix_views.py` when a source
# of a joined view is given a weight (`--source ROOT:EPISODES:WEIGHT`: its frames outside the view recoveries,
# or with `--weigh recovery` its recovery frames, weigh WEIGHT), read by `--policy.sample_weights`. Not part
# of a collected dataset.
TEACHER_SAMPLE_WEIGHT = f"{TEACHER_PREFIX}.sample_weight"

# Dataset annotations (never reach a policy).
ANNOTATION_PREFIX = "annotation"
ANN_PROGRESS = f"{ANNOTATION_PREFIX}.progress"
ANN_EVENT = f"{ANNOTATION_PREFIX}.occlusion_event"
ANN_EVENT_START = f"{ANNOTATION_PREFIX}.event_start"
ANN_ACTIVE = f"{ANNOTATION_PREFIX}.occlusion_active"
ANN_TARGET = f"{ANNOTATION_PREFIX}.occlusion_target"
ANN_VISIBILITY = f"{ANNOTATION_PREFIX}.visibility"
ANN_SEED = f"{ANNOTATION_PREFIX}.episode_seed"
# Who demonstrated an episode: the value is the index in SOURCES (bavo-collect's expert 0, bavo-teleop's human
# 1).
ANN_SOURCE = f"{ANNOTATION_PREFIX}.source"
SOURCES = ("expert", "human")
ANN_OCCLUDER_POSE = f"{ANNOTATION_PREFIX}.occluder_pose"  # occluder centre + wxyz quaternion (bavo-view)
ANNOTATION_KEYS = (ANN_PROGRESS, ANN_EVENT, ANN_EVENT_START, ANN_ACTIVE, ANN_TARGET, ANN_VISIBILITY, ANN_SEED,
                   ANN_OCCLUDER_POSE, ANN_SOURCE)
# Optional in stored datasets: those collected before these columns existed lack them and stay valid.
OPTIONAL_ANNOTATION_KEYS = (ANN_OCCLUDER_POSE, ANN_SOURCE)

# ------------------------------------------------------------------ per-point / per-object channels
POINT_CHANNELS = 6  # xyz + rgb
PIXEL_CHANNELS = 2  # u, v
TEACHER_CHANNELS = 3  # xyz in the camera frame of t_cam (SimulatorTeacher)
POSE_CHANNELS = 7  # xyz + wxyz quaternion per object in `observation.environment_state`

POINT_FRAMES = ("base", "camera")  # frames of the point-cloud xyz: robot base (default) or active camera


@dataclass(frozen=True)
class ObservationSettings:
    """What the env observes, and so what fixes a dataset's schema. Defaults follow DESIGN.md.

    Args:
        image_height, image_width: active-camera image size in pixels (16 to `limits.MAX_IMAGE_SIDE` each).
        n_points: points per cloud N (= teacher queries N_q; >= 2, relations need pairs; at most
            `limits.MAX_POINTS`).
        point_frame: frame of the point-cloud xyz, one of `POINT_FRAMES`.
        fovy: active camera vertical field of view, degrees (for the intrinsics).
        self_filter: drop the robot's own body (all three arms) from the point cloud before sampling it, as
            real robots do with their model and joint state (`envs.pointcloud.robot_pixel_mask`). Why: in the
            default cloud the arms take 35-60 % of the points, and a 4 cm block gets 2-7 of the 128 a policy
            reads. Off by default: the paper's cloud keeps everything in the workspace box.
    """

    image_height: int = 240
    image_width: int = 320
    n_points: int = 256
    point_frame: str = "base"
    fovy: float = C.ACTIVE_CAMERA_FOVY
    self_filter: bool = False

    def __post_init__(self):
        if self.image_height < 16 or self.image_width < 16:
            raise ValueError(
                f"image size must be >= 16 x 16 pixels, got {self.image_height} x {self.image_width}"
            )
        if self.n_points < 2:
            raise ValueError(f"n_points must be >= 2 (relations need pairs), got {self.n_points}")
        if self.point_frame not in POINT_FRAMES:
            raise ValueError(
                f"unknown point_frame {self.point_frame!r}; expected one of {', '.join(POINT_FRAMES)}"
            )
        if not isinstance(self.self_filter, bool):
            raise ValueError(f"self_filter must be true or false, got {self.self_filter!r}")
        problems = bound_problems({"image_height": self.image_height, "image_width": self.image_width,
                                   "n_points": self.n_points})  # upper bounds: `lerobot_bavo.limits`
        if problems:
            raise ValueError("observation settings out of bounds: " + "; ".join(problems))

    def to_dict(self) -> dict:
        return asdict(self)


# ------------------------------------------------------------------ point layout
def unflatten_points(x, n_points: int, channels: int):
    """(..., N * C) flat (dataset) or (..., N, C) (env) -> (..., N, C); numpy arrays and torch tensors (a view
    when possible). Any other shape raises a ValueError naming both layouts."""
    shape = tuple(x.shape)
    if len(shape) >= 2 and shape[-2:] == (n_points, channels):
        return x
    if not shape or shape[-1] != n_points * channels:
        raise ValueError(
            f"expected (..., {n_points * channels}) or (..., {n_points}, {channels}), got {shape}"
        )
    return x.reshape(*shape[:-1], n_points, channels)


def flatten_points(x):
    """(..., N, C) -> (..., N * C) (row-major)."""
    return x.reshape(*tuple(x.shape)[:-2], x.shape[-2] * x.shape[-1])


__all__ = [
    "ACTION",
    "ANNOTATION_KEYS",
    "ANNOTATION_PREFIX",
    "ANN_ACTIVE",
    "ANN_EVENT",
    "ANN_EVENT_START",
    "ANN_PROGRESS",
    "ANN_SEED",
    "ANN_SOURCE",
    "ANN_TARGET",
    "ANN_VISIBILITY",
    "ENV_ENV_STATE_KEY",
    "ENV_IMAGE_KEY",
    "ENV_POINT_CLOUD_KEY",
    "ENV_POINT_PIXELS_KEY",
    "ENV_STATE_KEY",
    "OBS_CAMERA_POSE",
    "OBS_ENV_STATE",
    "OBS_IMAGE",
    "OBS_POINT_CLOUD",
    "OBS_POINT_PIXELS",
    "OBS_STATE",
    "ObservationSettings",
    "PIXEL_CHANNELS",
    "POINT_CHANNELS",
    "POINT_FRAMES",
    "POSE_CHANNELS",
    "SOURCES",
    "TEACHER_CHANNELS",
    "TEACHER_KEYS",
    "TEACHER_PREFIX",
    "TEACHER_VALID",
    "TEACHER_VISIBLE",
    "TEACHER_Z0",
    "TEACHER_ZF",
    "flatten_points",
    "unflatten_points",
]

"""LeRobot `EnvConfig` for BAVO-Bench, registered as env type "bavo".

With the `lerobot_env_bavo` distribution installed, LeRobot's CLIs import this package on start-up, so

    lerobot-eval --policy.path=<dir> --env.type=bavo --env.task=cube_handoff

works with no extra flags. `gym_kwargs` is the only bridge to `gym.make` (see `lerobot_bavo.envs`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot.configs import FeatureType, PolicyFeature
from lerobot.envs.configs import EnvConfig

from lerobot_bavo.envs.conditions import CONDITIONS
from lerobot_bavo.envs.tasks import TASKS, environment_state_dim
from lerobot_bavo.features import (
    ACTION,
    ENV_ENV_STATE_KEY,
    ENV_IMAGE_KEY,
    ENV_POINT_CLOUD_KEY,
    ENV_POINT_PIXELS_KEY,
    ENV_STATE_KEY,
    OBS_ENV_STATE,
    OBS_IMAGE,
    OBS_POINT_CLOUD,
    OBS_POINT_PIXELS,
    OBS_STATE,
    PIXEL_CHANNELS,
    POINT_CHANNELS,
    ObservationSettings,
)
from lerobot_bavo.sim.constants import ACTION_DIM, CONTROL_HZ

from . import GYM_NAMESPACE, gym_id

RENDER_MODES = ("rgb_array",)


@EnvConfig.register_subclass("bavo")
@dataclass
class BavoEnvConfig(EnvConfig):
    """One BAVO-Bench task under one visibility condition, for `lerobot-eval` / `lerobot-train`.

    Args:
        task: a registered task's name, one of `lerobot_bavo.envs.tasks.TASKS` ("cube_handoff",
            "block_stacking", ...). The gym id is `lerobot_bavo/<GymName>-v0`, e.g.
            `lerobot_bavo/CubeHandoff-v0`.
        condition: a registered visibility condition (`lerobot_bavo.envs.conditions`): "clean" (no
            occluder), "stage" (occluder placed at stage transitions) or "random" (random-time
            occlusion events).
        fps: control rate in Hz; the simulator runs at 25 Hz, so this is informational (it sets the
            fps of recorded datasets) and must be 25.
        episode_length: control steps before truncation (`TimeLimit`, read by LeRobot's rollout as
            `_max_episode_steps`); None = the task's own limit (`Task.max_episode_steps`).
        image_height, image_width: active-camera image size in pixels (observation
            `observation.images.active`, HWC uint8 in the env, CHW float in [0, 1] for policies).
        n_points: points per point cloud (`observation.point_cloud`, (n_points, 6): xyz + rgb).
        point_frame: frame of the point-cloud xyz, "base" (robot base / world, default) or
            "camera" (active-camera frame, an ablation).
        self_filter: drop the robot's own body from the point cloud (`ObservationSettings.self_filter`);
            set it as the policy's training data was collected (`bavo-eval` reads it from the checkpoint).
        environment_state: also observe the task's object poses (`observation.environment_state`,
            (7 K,): xyz in metres in the base frame + wxyz quaternion per object). Privileged: for
            the privileged-state rung of the failure ladder, not for benchmark results.
        render_mode: mode of `env.render()`, used by `lerobot-eval` for its episode videos
            ("rgb_array": third-person view beside the active view).
        features: raw env feature specs (filled in `__post_init__`; visual shapes are HWC).
        features_map: raw env key -> policy/dataset key, e.g. "agent_pos" -> "observation.state".
    """

    task: str = "cube_handoff"
    condition: str = "clean"
    fps: int = CONTROL_HZ
    episode_length: int | None = None
    # observation defaults: ObservationSettings' own (one place for them)
    image_height: int = ObservationSettings.image_height
    image_width: int = ObservationSettings.image_width
    n_points: int = ObservationSettings.n_points
    point_frame: str = ObservationSettings.point_frame
    self_filter: bool = ObservationSettings.self_filter
    environment_state: bool = False
    render_mode: str = "rgb_array"
    features: dict[str, PolicyFeature] = field(
        default_factory=lambda: {ACTION: PolicyFeature(type=FeatureType.ACTION, shape=(ACTION_DIM,))}
    )
    features_map: dict[str, str] = field(
        default_factory=lambda: {
            ACTION: ACTION,
            ENV_STATE_KEY: OBS_STATE,
            ENV_IMAGE_KEY: OBS_IMAGE,
            ENV_POINT_CLOUD_KEY: OBS_POINT_CLOUD,
            ENV_POINT_PIXELS_KEY: OBS_POINT_PIXELS,
        }
    )

    def __post_init__(self):
        TASKS.lookup(self.task)  # raises for unknown names, listing the registered ones
        CONDITIONS.lookup(self.condition)  # raises for unknown names, listing the registered ones
        if self.render_mode not in RENDER_MODES:
            raise ValueError(f"unsupported render_mode {self.render_mode!r}; expected one of {RENDER_MODES}")
        if self.fps != CONTROL_HZ:
            raise ValueError(f"fps={self.fps} but BAVO-Bench is controlled at {CONTROL_HZ} Hz")
        # Image size, n_points, point_frame and self_filter: the same checks as the env's and the datasets'.
        self.obs_settings  # noqa: B018  (builds ObservationSettings, which raises for invalid values)
        if self.episode_length is not None and self.episode_length < 1:
            raise ValueError(f"episode_length must be >= 1 or None, got {self.episode_length}")

        self.features[ENV_STATE_KEY] = PolicyFeature(type=FeatureType.STATE, shape=(ACTION_DIM,))
        self.features[ENV_IMAGE_KEY] = PolicyFeature(
            type=FeatureType.VISUAL, shape=(self.image_height, self.image_width, 3)
        )
        # Non-image `observation.*` features are typed STATE, as LeRobot's dataset_to_policy_features
        # does for our datasets; policies that cannot use them (ACT, Diffusion) ignore them.
        self.features[ENV_POINT_CLOUD_KEY] = PolicyFeature(
            type=FeatureType.STATE, shape=(self.n_points, POINT_CHANNELS))
        self.features[ENV_POINT_PIXELS_KEY] = PolicyFeature(
            type=FeatureType.STATE, shape=(self.n_points, PIXEL_CHANNELS))
        if self.environment_state:
            self.features_map[ENV_ENV_STATE_KEY] = OBS_ENV_STATE
            self.features[ENV_ENV_STATE_KEY] = PolicyFeature(
                type=FeatureType.ENV, shape=(environment_state_dim(self.task),))

    @property
    def obs_settings(self) -> ObservationSettings:
        """The observation settings these fields describe (raises for invalid ones)."""
        return ObservationSettings(self.image_height, self.image_width, self.n_points, self.point_frame,
                                   self_filter=self.self_filter)

    @property
    def package_name(self) -> str:
        """Imported by `create_envs` if the gym id is not registered yet."""
        return GYM_NAMESPACE

    @property
    def gym_id(self) -> str:
        return gym_id(self.task)

    @property
    def gym_kwargs(self) -> dict:
        """Keyword arguments of `gym.make(self.gym_id, ...)`. `max_episode_steps` is consumed by
        gym.make for its TimeLimit wrapper (None keeps the registered task limit); the same limit
        goes to `BavoEnv` as `episode_length`, so both truncate at the same step."""
        return {
            "condition": self.condition,
            "image_height": self.image_height,
            "image_width": self.image_width,
            "n_points": self.n_points,
            "point_frame": self.point_frame,
            "self_filter": self.self_filter,
            "environment_state": self.environment_state,
            "render_mode": self.render_mode,
            "max_episode_steps": self.episode_length,
            "episode_length": self.episode_length,
        }

"""The settings of a `bavo-collect` run (`CollectConfig`, the CLI's flags, checked once here) and its error.

Below every other part of the collection pipeline (session, writer, the command), so each of them imports
it without a loop.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from lerobot_bavo.datasets import schema as S
from lerobot_bavo.datasets.video_codec import DEFAULT_VIDEO_CODEC, check_video_codec
from lerobot_bavo.datasets.video_codec import record_entry as video_codec_record_entry
from lerobot_bavo.experts.perturbation import ExecutionNoise
from lerobot_bavo.features import ObservationSettings
from lerobot_bavo.runtime.pool import executor_problem

STAGING = ".bavo_staging"


@dataclass
class CollectConfig:
    """Arguments of a collection (the CLI's flags).

    Args:
        task, condition: benchmark task and visibility condition.
        episodes: number of successful episodes wanted in the dataset.
        repo_id: `<user>/<name>`; also the default local folder `$HF_LEROBOT_HOME/<repo_id>`.
        root: local dataset folder (default: LeRobot's).
        workers: worker processes; 0 runs episodes in this process (tests, debugging). With executor "ray" and
            no ray_address: the CPUs of the private local Ray (>= 1).
        executor: "local" (`WorkerPool`) or "ray" (`RayPool`: episode rollouts as Ray tasks).
        ray_address: with executor "ray", the cluster to use (`ray start --head` prints it); None: a private
        Ray. seed: seed of the first attempt (demonstration seeds should stay clear of eval seeds, 1000+).
        commit_every: episodes appended per LeRobot writer session (resume granularity).
        settings: observation settings (image size, points, frame, fovy).
        episode_length: control-step limit per episode (None: the task's own).
        keep_failures: keep unsuccessful episodes too (tests / debugging only).
        execution_noise: DART-style noise on the executed arm joint targets; the dataset records the
            expert's clean actions (`experts/perturbation.py`). Off by default.
        events_outside_contacts: occlusion events wait while the expert is in one of its `contact_phases`
            (`BavoEnv.hold_occlusion_events`); only for an occluded condition. Off by default.
        decoy_panels: decoy panels in the scene (`BavoEnv(decoy_panels=...)`): copies of the occluder that
            never hide the current target; only for an occluded condition. 0 (default): the benchmark's scene.
        square_grasps: the scripted expert's top-down grasps keep the wrist at yaw 0 (`ScriptedExpert`'s
            `square_grasps`; Cube Handoff only). Off by default.
        use_videos: store the active image as video.
        video_codec: that video's codec (`datasets/video_codec.py`): "h264" or "libsvtav1" (LeRobot's default
        AV1).
            None: "h264" for a new dataset, the dataset's own codec when continuing one.
        push_to_hub, private: upload when done.
        max_discard_ratio: abort when more than this many discards per wanted episode (plus 10) occur.
        progress: show a progress bar.
        command: the command line, recorded in the collection record and the dataset card.
    """

    task: str
    condition: str
    episodes: int
    repo_id: str
    root: Path | None = None
    workers: int = 2
    executor: str = "local"
    ray_address: str | None = None
    seed: int = 0
    commit_every: int = 10
    settings: ObservationSettings = field(default_factory=ObservationSettings)
    episode_length: int | None = None
    keep_failures: bool = False
    execution_noise: ExecutionNoise = field(default_factory=ExecutionNoise)
    events_outside_contacts: bool = False
    decoy_panels: int = 0
    square_grasps: bool = False
    use_videos: bool = True
    video_codec: str | None = None
    push_to_hub: bool = False
    private: bool | None = None
    max_discard_ratio: float = 2.0
    progress: bool = True
    command: str | None = None

    def __post_init__(self):
        if self.episodes < 1:
            raise ValueError(f"--episodes must be >= 1, got {self.episodes}")
        if self.workers < 0:
            raise ValueError(f"--workers must be >= 0, got {self.workers}")
        if (problem := executor_problem(self.executor, self.ray_address, self.workers)) is not None:
            raise ValueError(problem)
        if self.commit_every < 1:
            raise ValueError(f"--commit-every must be >= 1, got {self.commit_every}")
        if self.seed < 0:
            raise ValueError(f"--seed must be >= 0, got {self.seed}")
        if self.video_codec is not None:
            check_video_codec(self.video_codec)
        if self.events_outside_contacts:
            from lerobot_bavo.envs.conditions import get_condition

            if not get_condition(self.condition).occluded:
                raise ValueError(f"--events-outside-contacts needs an occluded condition; "
                                 f"{self.condition!r} has no occlusion events")
        if self.decoy_panels < 0:
            raise ValueError(f"--decoy-panels must be >= 0, got {self.decoy_panels}")
        if self.decoy_panels:
            from lerobot_bavo.envs.conditions import get_condition

            if not get_condition(self.condition).occluded:
                raise ValueError(f"--decoy-panels needs an occluded condition; {self.condition!r} has no "
                                 "occlusion events to place them at")
        if self.square_grasps:
            from lerobot_bavo.experts import EXPERTS

            if self.task not in EXPERTS or not EXPERTS[self.task].supports_square_grasps:
                supported = sorted(n for n in EXPERTS if EXPERTS[n].supports_square_grasps)
                raise ValueError(f"--square-grasps is not implemented for the {self.task!r} expert; tasks "
                                 f"whose expert has it: {', '.join(supported)}")
        if "/" not in self.repo_id:
            raise ValueError(f"--repo-id must look like '<user>/<name>', got {self.repo_id!r}")

    def resolved_root(self) -> Path:
        if self.root is not None:
            return Path(self.root)
        from lerobot.utils.constants import HF_LEROBOT_HOME

        return Path(HF_LEROBOT_HOME) / self.repo_id

    def record_settings(self, video_codec: str = DEFAULT_VIDEO_CODEC) -> dict:
        """What must match for a run to continue an existing dataset, recording video with `video_codec`."""
        from lerobot_bavo.envs.tasks import make_task

        task = make_task(self.task)
        settings = self.settings.to_dict()
        if not settings["self_filter"]:  # only when on: records made before the option existed still match
            del settings["self_filter"]
        return {
            "task": self.task,
            "task_description": task.description,
            "stage_targets": list(task.stage_targets),
            "condition": self.condition,
            **settings,
            "fps": S.FPS,
            "episode_length": self.episode_length,
            "base_seed": self.seed,
            "keep_failures": self.keep_failures,
            # Only when on, so that the records of collections made before the option existed still match.
            **({"execution_noise": self.execution_noise.to_dict()} if self.execution_noise.enabled else {}),
            **({"events_outside_contacts": True} if self.events_outside_contacts else {}),
            **({"decoy_panels": self.decoy_panels} if self.decoy_panels else {}),
            **({"square_grasps": True} if self.square_grasps else {}),
            "use_videos": self.use_videos,
            # Only when not the codec of datasets made before the choice existed (their records name none).
            **video_codec_record_entry(video_codec, self.use_videos),
            "teacher": {
                "name": "simulator-exact",
                "clip_length": S.CLIP_LENGTH,
                "anchor_index": S.ANCHOR_INDEX,
                "n_future": S.N_FUTURE,
                "visibility_tol_m": 0.01,
            },
        }


class CollectionError(RuntimeError):
    pass

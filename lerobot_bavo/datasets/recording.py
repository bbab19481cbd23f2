"""Record one scripted-expert episode with everything the dataset and the simulator teacher need.

Frame t of an episode pairs observation o_t with the action a_t the expert sends after seeing it
(LeRobot's convention); the observation after the last action is not stored. Episode length
T = number of actions. Besides the dataset's arrays, the recorder keeps privileged per-frame
state for the teacher (never stored in the dataset): the z-depth and the id of the body seen at
every pixel (one segmentation render at the observation resolution, from the state the
observation was rendered in: after the step's occluder placement), and the poses of all bodies.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from lerobot_bavo.datasets import schema as S
from lerobot_bavo.envs.occlusion import stage_index
from lerobot_bavo.envs.pointcloud import intrinsics_from_fovy
from lerobot_bavo.experts.perturbation import ExecutionNoise
from lerobot_bavo.features import ObservationSettings, flatten_points
from lerobot_bavo.sim import constants as C


@dataclass
class EpisodeRecord:
    """One recorded episode (T frames). Arrays have the frame as leading axis.

    Dataset arrays: state, action (T, 21) float32; rgb (T, H, W, 3) uint8; point_cloud (T, N, 6)
    float32; point_pixels (T, N, 2) int32; camera_pose (T, 4, 4) float64 (T_B<-C, OpenCV axes);
    environment_state (T, 7 K) float32 (object poses, privileged);
    progress, occlusion_event, occlusion_target (T,) int64; event_start, occlusion_active,
    visibility (T,) float32; occluder_pose (T, 7) float32 (see `schema` for their meaning).
    Privileged (teacher only): depth (T, H, W) float32 z-depth (m); body_seg (T, H, W) int16
    body id per pixel (-1: none); body_xpos (T, n_body, 3), body_xmat (T, n_body, 3, 3) float64;
    K (3, 3) intrinsics.
    """

    task: str
    condition: str
    seed: int
    success: bool
    final_progress: int
    state: np.ndarray
    action: np.ndarray
    rgb: np.ndarray
    point_cloud: np.ndarray
    point_pixels: np.ndarray
    camera_pose: np.ndarray
    environment_state: np.ndarray
    progress: np.ndarray
    occlusion_event: np.ndarray
    event_start: np.ndarray
    occlusion_active: np.ndarray
    occlusion_target: np.ndarray
    visibility: np.ndarray
    depth: np.ndarray
    body_seg: np.ndarray
    body_xpos: np.ndarray
    body_xmat: np.ndarray
    K: np.ndarray
    occluder_pose: np.ndarray | None = None
    timings: dict = field(default_factory=dict)
    recoveries: int = 0
    source: str = "expert"  # S.SOURCES: "expert" (scripted) or "human" (bavo-teleop)

    @property
    def length(self) -> int:
        return int(self.action.shape[0])


class EpisodeRecorder:
    """Owns an env, its expert and a segmentation renderer; records seeded episodes.

    Args:
        task, condition: the benchmark task and visibility condition.
        settings: observation settings (`lerobot_bavo.features.ObservationSettings`).
        episode_length: control-step limit (None: the task's own); truncated episodes fail.
        decoy_panels: decoy panels in the scene (`BavoEnv(decoy_panels=...)`; 0: the benchmark's scene).
    """

    def __init__(
        self, task: str, condition: str, settings: ObservationSettings, episode_length: int | None = None,
        decoy_panels: int = 0,
    ):
        from lerobot_bavo.envs.bavo_env import BavoEnv
        from lerobot_bavo.sim.rendering import SceneRenderer

        self.task, self.condition, self.settings = task, condition, settings
        self.env = BavoEnv(
            task=task,
            condition=condition,
            image_height=settings.image_height,
            image_width=settings.image_width,
            n_points=settings.n_points,
            point_frame=settings.point_frame,
            fovy=settings.fovy,
            self_filter=settings.self_filter,
            episode_length=episode_length,
            render_mode=None,
            decoy_panels=decoy_panels,
        )
        model = self.env.model
        self._camera_id = model.camera(C.ACTIVE_CAMERA).id
        self._seg = SceneRenderer(model, settings.image_height, settings.image_width)
        # geom id -> body id lookup with -1 (nothing seen) mapped to -1
        self._geom_body = np.append(model.geom_bodyid.astype(np.int16), np.int16(-1))
        self.K = intrinsics_from_fovy(settings.fovy, settings.image_height, settings.image_width)

    def close(self) -> None:
        self._seg.close()
        self.env.close()

    def record(self, seed: int, agent=None, execution_noise: ExecutionNoise | None = None,
               events_outside_contacts: bool = False, square_grasps: bool = False) -> EpisodeRecord:
        """Record the episode of `seed`, driven by the scripted expert, or by `agent` when given.

        With `execution_noise` (DART, `experts/perturbation.py`), the env executes the agent's arm joint
        targets plus seeded noise while the record keeps the agent's clean action.

        `agent` (e.g. `lerobot_bavo.teleop`'s human operator) has the expert's interface: `reset()`,
        `act(obs, info)`, `recovering` (True marks recovery frames), and optionally `source`
        ("human") and `stop_requested` (True ends the episode after the current step).

        With `events_outside_contacts`, an occlusion event that falls due while the agent is in one of its
        `contact_phases` waits until that phase is over (`BavoEnv.hold_occlusion_events`).

        With `square_grasps`, the scripted expert grasps square to the table's axes
        (`ScriptedExpert`'s `square_grasps`); ignored when `agent` is given.
        """
        from lerobot_bavo.experts import make_expert
        from lerobot_bavo.experts.base import in_contact_phase

        env = self.env
        t0 = time.perf_counter()
        obs, info = env.reset(seed=seed)
        expert = make_expert(env, seed=seed, square_grasps=square_grasps) if agent is None else agent
        expert.reset()
        noise = (
            execution_noise.process(seed) if execution_noise is not None and execution_noise.enabled else None
        )
        task = env.task
        rows: dict[str, list] = {
            k: []
            for k in (
                "state",
                "action",
                "rgb",
                "point_cloud",
                "point_pixels",
                "camera_pose",
                "environment_state",
                "progress",
                "occlusion_event",
                "event_start",
                "occlusion_active",
                "occlusion_target",
                "visibility",
                "depth",
                "body_seg",
                "body_xpos",
                "body_xmat",
                "occluder_pose",
            )
        }
        target_stage = -1
        t_render = 0.0
        while True:
            # o_t (and privileged state in the same simulator state it was rendered in)
            ts = time.perf_counter()
            seg, depth = self._privileged_view()
            t_render += time.perf_counter() - ts
            rows["depth"].append(depth)
            rows["body_seg"].append(self._geom_body[seg])
            rows["body_xpos"].append(env.data.xpos.copy())
            rows["body_xmat"].append(env.data.xmat.reshape(-1, 3, 3).copy())
            rows["state"].append(obs["agent_pos"])
            rows["rgb"].append(obs["pixels"]["active"])
            rows["point_cloud"].append(obs["point_cloud"])
            rows["point_pixels"].append(obs["point_pixels"])
            rows["camera_pose"].append(np.asarray(info["camera_pose"], dtype=np.float64))
            rows["environment_state"].append(task.environment_state(env.model, env.data))
            progress = int(info["progress"])
            rows["progress"].append(progress)
            annotation = occlusion_annotation(task, info.get("occlusion"), progress, target_stage)
            target_stage = annotation["occlusion_target"]
            for key, value in annotation.items():
                rows[key].append(value)
            # a_t
            action = np.asarray(expert.act(obs, info), dtype=np.float32)
            rows["action"].append(action)
            rows["occlusion_active"].append(float(expert.recovering))
            # DART: execute the perturbed targets, keep the clean ones (contact phases stay clean)
            if noise is not None:
                action = noise.perturb(action, quiet=execution_noise.quiet_for(expert))
            if events_outside_contacts:
                env.hold_occlusion_events(in_contact_phase(expert))
            obs, _, terminated, truncated, info = env.step(action)
            if terminated or truncated or getattr(expert, "stop_requested", False):
                break
        arrays = {k: np.stack(v) for k, v in rows.items()}
        wall = time.perf_counter() - t0
        return EpisodeRecord(
            task=self.task,
            condition=self.condition,
            seed=int(seed),
            success=bool(info["is_success"]),
            final_progress=int(info["progress"]),
            state=arrays["state"].astype(np.float32),
            action=arrays["action"].astype(np.float32),
            rgb=arrays["rgb"],
            point_cloud=arrays["point_cloud"].astype(np.float32),
            point_pixels=arrays["point_pixels"].astype(np.int32),
            camera_pose=arrays["camera_pose"],
            environment_state=arrays["environment_state"].astype(np.float32),
            progress=arrays["progress"].astype(np.int64),
            occlusion_event=arrays["occlusion_event"].astype(np.int64),
            event_start=arrays["event_start"].astype(np.float32),
            occlusion_active=arrays["occlusion_active"].astype(np.float32),
            occlusion_target=arrays["occlusion_target"].astype(np.int64),
            visibility=arrays["visibility"].astype(np.float32),
            occluder_pose=arrays["occluder_pose"].astype(np.float32),
            depth=arrays["depth"],
            body_seg=arrays["body_seg"],
            body_xpos=arrays["body_xpos"],
            body_xmat=arrays["body_xmat"],
            K=self.K.copy(),
            timings={"episode_s": wall, "segmentation_s": t_render},
            recoveries=len(getattr(expert, "recoveries", [])),
            source=getattr(expert, "source", "expert"),
        )

    def _privileged_view(self) -> tuple[np.ndarray, np.ndarray]:
        """(geom id per pixel, z-depth) of the current state, from one segmentation pass with depth readback.

        Reusing the observation's own depth (`BavoEnv.observation_depth`) instead was tried: it
        is bit-identical at 48 x 64 (`tests/test_datasets.py`, `tests/test_collect_content.py`), but
        `benchmarks/collect_throughput.py --compare-paths` at 240 x 320 reported non-identical privileged
        arrays (not yet diagnosed), so the readback stays until that is understood.
        """
        return self._seg.render_segmentation(self.env.data, self._camera_id, with_depth=True)


def occlusion_annotation(task, occlusion: dict | None, progress: int, target_stage: int) -> dict:
    """One step's occlusion annotations from the env's `info["occlusion"]` (None in Clean).

    `target_stage` is the stage index of the event in force at the previous step: it changes only when an
    event starts (the target is fixed for the event's whole span), and is -1 before the first event.
    Values: the event index (-1 none), event start (1.0 at the step it starts), the target's stage index,
    the target's visibility (-1.0 unknown or Clean) and the occluder's pose [x, y, z (m, base frame),
    quaternion w, x, y, z] (zeros in Clean)."""
    if occlusion is None:
        return {"occlusion_event": -1, "event_start": 0.0, "occlusion_target": -1, "visibility": -1.0,
                "occluder_pose": np.zeros(7)}
    event = occlusion["event"]
    if occlusion["event_started"]:
        target_stage = _target_stage(task, occlusion["target"], progress)
    visibility = occlusion["visibility"]
    return {
        "occlusion_event": int(event["index"]),
        "event_start": float(bool(occlusion["event_started"])),
        "occlusion_target": target_stage,
        "visibility": -1.0 if visibility is None else float(visibility),
        "occluder_pose": np.concatenate([event["occluder_pos"], event["occluder_quat"]]),
    }


def _target_stage(task, target: str, progress: int) -> int:
    """Stage index s of an event's target (`task.stage_targets[s] == target`), from the milestone
    depth at the event start (the env picks the target by the stage reached at that time)."""
    s = stage_index(progress, task.stage_transitions)
    if task.stage_targets[s] == target:
        return s
    return task.stage_targets.index(target)  # first match (an event not aligned with the stages)


def episode_frames(record: EpisodeRecord, targets: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The dataset columns of an episode (flat layouts, exact dtypes), frame as leading axis."""
    T = record.length
    n = record.point_cloud.shape[1]
    col = {
        S.OBS_STATE: record.state.astype(np.float32),
        S.ACTION: record.action.astype(np.float32),
        S.OBS_IMAGE: record.rgb,
        S.OBS_POINT_CLOUD: flatten_points(record.point_cloud).astype(np.float32),
        S.OBS_POINT_PIXELS: flatten_points(record.point_pixels).astype(np.float32),
        S.OBS_CAMERA_POSE: record.camera_pose.reshape(T, 16).astype(np.float32),
        S.OBS_ENV_STATE: record.environment_state.reshape(T, -1).astype(np.float32),
        S.TEACHER_Z0: targets["z0"].reshape(T, -1).astype(np.float32),
        S.TEACHER_ZF: targets["zf"].reshape(T, -1).astype(np.float32),
        S.TEACHER_VISIBLE: targets["visible"].reshape(T, n).astype(np.float32),
        S.TEACHER_VALID: targets["valid"].reshape(T, 1).astype(np.float32),
        S.ANN_PROGRESS: record.progress.reshape(T, 1).astype(np.int64),
        S.ANN_EVENT: record.occlusion_event.reshape(T, 1).astype(np.int64),
        S.ANN_EVENT_START: record.event_start.reshape(T, 1).astype(np.float32),
        S.ANN_ACTIVE: record.occlusion_active.reshape(T, 1).astype(np.float32),
        S.ANN_TARGET: record.occlusion_target.reshape(T, 1).astype(np.int64),
        S.ANN_VISIBILITY: record.visibility.reshape(T, 1).astype(np.float32),
        S.ANN_SEED: np.full((T, 1), record.seed, dtype=np.int64),
        S.ANN_SOURCE: np.full((T, 1), S.SOURCES.index(record.source), dtype=np.int64),
    }
    if record.occluder_pose is not None:
        col[S.ANN_OCCLUDER_POSE] = record.occluder_pose.reshape(T, S.POSE_CHANNELS).astype(np.float32)
    return col

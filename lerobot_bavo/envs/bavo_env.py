"""`BavoEnv`: one BAVO-Bench task under one visibility condition, as a gymnasium Env.

Control: absolute joint-position targets (21) at 25 Hz; each control step runs 20 physics steps
of 2 ms with the actuator targets linearly interpolated from the previous target (as AV-ALOHA).
Observation (copies, never views into simulator memory):
    agent_pos (21,) float32: left 6 joints + gripper, right 6 + gripper, camera arm 7 (rad; the
        grippers as normalised opening in [0, 1], 1 = open);
    pixels/active (H, W, 3) uint8: the active camera's RGB image;
    point_cloud (N, 6) float32: xyz in the base frame (default) or the camera frame (OpenCV
        convention: x right, y down, z forward), rgb in [0, 1];
    point_pixels (N, 2) int32: the source pixel (u, v) of every point (-1 if the view is empty);
    environment_state (7 K,) float32, only with `environment_state=True`: the task's K object
        poses (xyz in metres, base frame; wxyz quaternion), the privileged-state observation
        that bounds what behaviour cloning can reach with perfect perception.
Reward: task progress d / 5 (deepest milestone so far, monotone), so LeRobot's
`avg_max_reward` is the Task Progress Score. `terminated` and `info["is_success"]` at M5.
Privileged information (milestone flags, object poses, camera pose) only goes into `info`.
Conditions (`envs/conditions.py`): "clean" has no occluder; "stage" and "random" place the benchmark
occluder at reset and at the Stage transitions / Random-time triggers (`envs/occlusion.py`);
`info["occlusion"]` reports the current event and the target's per-step visibility, and under "random"
`info["cvg"]` at episode end holds the events' CVG (`lerobot_bavo/metrics.py`). The visibility
renders use their own GL context and never touch observations, actions or dynamics.
Seeding: every random draw (task layout, then the occlusion schedule) comes from
`self.np_random`, seeded by `reset(seed=...)`.
"""

from __future__ import annotations

import gymnasium as gym
import mujoco
import numpy as np

from lerobot_bavo.envs.conditions import Condition, OcclusionSchedule, get_condition
from lerobot_bavo.envs.occlusion import (
    OCCLUDER_HALF_EXTENTS,
    OccluderPlacer,
    OcclusionEvent,
    stage_index,
)
from lerobot_bavo.envs.pointcloud import (
    DEFAULT_STRIDE,
    build_point_cloud,
    camera_pose_from_mujoco,
    intrinsics_from_fovy,
    robot_pixel_mask,
)
from lerobot_bavo.envs.tasks import Task, make_task
from lerobot_bavo.envs.visibility import TargetVisibility
from lerobot_bavo.features import (
    ENV_ENV_STATE_KEY,
    ENV_POINT_CLOUD_KEY,
    ENV_POINT_PIXELS_KEY,
    ENV_STATE_KEY,
    PIXEL_CHANNELS,
    POINT_CHANNELS,
    ObservationSettings,
)
from lerobot_bavo.metrics import NUM_MILESTONES, CVGAccumulator
from lerobot_bavo.sim import constants as C
from lerobot_bavo.sim.kinematics import make_arm_kinematics
from lerobot_bavo.sim.rendering import SceneRenderer
from lerobot_bavo.sim.scene import add_decoy_panels, add_occluder, build_base_spec, decoy_body_name

# Point-cloud crop box in the base frame (metres): the table's extent, from just above the table
# top (so the bare table surface is not sampled) to 0.6 m above it.
WORKSPACE_LOW = np.array([-0.61, -0.37, 0.004])
WORKSPACE_HIGH = np.array([0.61, 0.37, 0.6])
# Self-filter (`self_filter=True`): a measured surface up to this much (metres) nearer than the robot model's
# rendered surface still counts as the robot. The simulated depth matches the model exactly, so this only
# has to absorb float error; anything further in front (a held object, the occluder) stays in the cloud.
SELF_FILTER_TOLERANCE = 0.005


class BavoEnv(gym.Env):
    """A BAVO-Bench task under a visibility condition.

    Args:
        task: a registered task's name (`lerobot_bavo.envs.tasks.TASKS`) or a `Task` instance.
        condition: a registered condition's name ("clean", "stage", "random"; `envs/conditions.py`)
            or a `Condition` instance.
        image_height, image_width: active-camera image size in pixels.
        n_points: points per cloud (farthest-point sampled).
        point_frame: "base" (robot-base frame, default) or "camera" (ablation).
        fovy: active camera vertical field of view, degrees.
        episode_length: control steps before truncation (default: the task's own limit). Named
            so because `gym.make` keeps a `max_episode_steps` keyword for its TimeLimit wrapper.
        render_mode: "rgb_array" (third-person view beside the active view) or None.
        render_height: height of each of the two panels of `render()`.
        compute_cvg: render the frozen-camera counterfactual every step of an open recovery
            window and report CVG (default: the condition's `reports_cvg`, true only under
            "random", the condition the paper reports CVG for). The realised visibility of the
            current target is always recorded under occluded conditions.
        visibility_scale: resolution of the privileged visibility renders relative to the
            observation image (V is a pixel ratio; 0.5 keeps it cheap).
        environment_state: also observe the task's object poses (`environment_state`, privileged;
            for the privileged-state policies of the failure ladder, never for benchmark results).
        self_filter: drop the robot's own body from the point cloud (`ObservationSettings.self_filter`): a
            depth render of the robot model alone at the current joint state, compared with the measured
            depth (`pointcloud.robot_pixel_mask`). Uses only what a real robot knows (its model, joints and
            camera calibration); one more depth-only render per observation.
        decoy_panels: how many decoy panels to add (default 0: the benchmark's scene). A data-collection
            lever against the occluder shortcut (docs/results/decoy_panels.md), never a benchmark setting:
            panels that look exactly like the occluder, re-drawn at every occlusion event where they leave the
            current target visible (`OccluderPlacer.place_decoy`), so that a panel in the cloud no longer
            tells where the target is. Occluded conditions only. V, CVG and the experts ignore them (they
            share the occluder's geom group, which the privileged renders drop). Their draws come from a
            generator seeded from `np_random` after the occlusion schedule, so a seed gives the same layout,
            schedule and occluder placements with and without decoys.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": C.CONTROL_HZ}

    def __init__(
        self,
        task: str | Task = "cube_handoff",
        condition: str | Condition = "clean",
        image_height: int = ObservationSettings.image_height,
        image_width: int = ObservationSettings.image_width,
        n_points: int = ObservationSettings.n_points,
        point_frame: str = ObservationSettings.point_frame,
        fovy: float = ObservationSettings.fovy,
        episode_length: int | None = None,
        render_mode: str | None = "rgb_array",
        render_height: int = 240,
        compute_cvg: bool | None = None,
        visibility_scale: float = 0.5,
        environment_state: bool = False,
        self_filter: bool = ObservationSettings.self_filter,
        decoy_panels: int = 0,
    ):
        self.condition_rule = get_condition(condition)  # unknown names raise, listing the registered ones
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"unsupported render_mode {render_mode!r}; use 'rgb_array' or None")

        self.task = task if isinstance(task, Task) else make_task(task)
        self.condition = self.condition_rule.name
        # checks them
        self.obs_settings = ObservationSettings(image_height, image_width, n_points, point_frame, fovy,
                                                self_filter)
        self.render_mode = render_mode
        self.render_height = render_height
        if episode_length is not None and episode_length < 1:
            raise ValueError(f"episode_length must be >= 1, got {episode_length}")
        self.max_episode_steps = episode_length or self.task.max_episode_steps
        self.task_description = self.task.description

        spec = build_base_spec(fovy=fovy)
        spec.visual.global_.offwidth = max(640, image_width, 4 * render_height // 3)
        spec.visual.global_.offheight = max(480, image_height, render_height)
        self.task.build(spec)
        self.occluded = self.condition_rule.occluded
        if self.occluded:
            add_occluder(spec, OCCLUDER_HALF_EXTENTS)
        if (isinstance(decoy_panels, bool) or not isinstance(decoy_panels, (int, np.integer))
                or decoy_panels < 0):
            raise ValueError(f"decoy_panels must be an integer >= 0, got {decoy_panels!r}")
        if decoy_panels and not self.occluded:
            raise ValueError(f"decoy_panels needs an occluded condition; {self.condition!r} has no occluder "
                             "events to place them at")
        self.decoy_panels = int(decoy_panels)
        add_decoy_panels(spec, OCCLUDER_HALF_EXTENTS, self.decoy_panels)
        self.compute_cvg = bool((self.condition_rule.reports_cvg if compute_cvg is None else compute_cvg)
                                and self.occluded)
        self.model = spec.compile()
        self.data = mujoco.MjData(self.model)
        self.task.bind(self.model)
        self.kinematics = make_arm_kinematics(self.model)
        self.environment_state = bool(environment_state)
        self.environment_state_dim = int(self.task.environment_state(self.model, self.data).shape[0])

        # Actuator i drives the joint of action entry i (same 21-entry order).
        self._act_qpos_adr = self.model.jnt_qposadr[self.model.actuator_trnid[:, 0]]
        self._grip_adr = [
            self.model.jnt_qposadr[self.model.joint(f"{p}finger_a").id] for p in ("left_", "right_")
        ]
        self._camera_id = self.model.camera(C.ACTIVE_CAMERA).id
        self._K = intrinsics_from_fovy(fovy, image_height, image_width)
        self._vis_size = (max(16, int(round(image_height * visibility_scale))),
                          max(16, int(round(image_width * visibility_scale))))

        lo, hi = C.action_bounds()
        self.action_space = gym.spaces.Box(lo, hi, dtype=np.float32)
        self.observation_space = gym.spaces.Dict(
            {
                ENV_STATE_KEY: gym.spaces.Box(-np.inf, np.inf, (C.ACTION_DIM,), np.float32),
                "pixels": gym.spaces.Dict(
                    {
                        "active": gym.spaces.Box(0, 255, (image_height, image_width, 3), np.uint8),
                    }
                ),
                ENV_POINT_CLOUD_KEY: gym.spaces.Box(-np.inf, np.inf, (n_points, POINT_CHANNELS), np.float32),
                ENV_POINT_PIXELS_KEY: gym.spaces.Box(
                    -1, max(image_height, image_width), (n_points, PIXEL_CHANNELS), np.int32
                ),
            }
        )
        if self.environment_state:
            self.observation_space[ENV_ENV_STATE_KEY] = gym.spaces.Box(
                -np.inf, np.inf, (self.environment_state_dim,), np.float32)

        self._renderer: SceneRenderer | None = None
        self._observation_depth: np.ndarray | None = None
        self._video_renderer: SceneRenderer | None = None
        self._ctrl = np.zeros(self.model.nu)
        self._elapsed = 0
        self._tracker = None
        self._flags: dict[str, bool] = {}
        self._visibility: TargetVisibility | None = None
        self._placer: OccluderPlacer | None = None
        self._decoy_placers: list[OccluderPlacer] = []
        self._decoy_rng: np.random.Generator | None = None
        self._decoys: list[tuple[np.ndarray, np.ndarray] | None] = []
        self._schedule: OcclusionSchedule | None = None
        self._events: list[OcclusionEvent] = []
        self._events_held = False
        self._event_pending = False
        self._cvg = CVGAccumulator()
        self._step_visibility: float | None = None
        self._episode_summary: dict | None = None
        self._ended = False

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        from lerobot_bavo.envs.tasks.base import MilestoneTracker

        mujoco.mj_resetData(self.model, self.data)
        home = self.action_to_ctrl(C.HOME_ACTION)
        self.data.qpos[self._act_qpos_adr] = home
        for adr in self._grip_adr:  # finger_b follows finger_a through the equality
            self.data.qpos[adr + 1] = self.data.qpos[adr]
        self.data.ctrl[:] = home
        self._ctrl = home.copy()
        self.task.initialize_episode(self.model, self.data, self.np_random)
        mujoco.mj_forward(self.model, self.data)
        self._elapsed = 0
        self._tracker = MilestoneTracker()
        self._flags = self.task.evaluate(self.model, self.data)
        self._tracker.update(self._flags, 0)
        self._events = []
        self._events_held = False
        self._event_pending = False
        self._cvg = CVGAccumulator()
        self._episode_summary = None
        self._ended = False
        if self.occluded:
            # Drawn after the task's reset, so a seed gives the same layout under every condition.
            self._schedule = OcclusionSchedule.sample(
                self.condition_rule, self.task.stage_transitions, self.np_random
            )
            if self.decoy_panels:
                self._decoy_rng = np.random.default_rng(int(self.np_random.integers(2**63)))
            self._update_occlusion()
        return self._observation(), self._info()

    def step(self, action):
        """One 25 Hz control step. After an episode ended (`terminated` or `truncated` was returned), stepping
        again raises `RuntimeError` until `reset()`: gymnasium leaves that call undefined, and continuing
        would run past the step limit and report milestones of a finished episode (gymnasium's vector envs
        reset automatically, so LeRobot's rollouts never do it)."""
        if self._ended:
            raise RuntimeError("the episode has ended (terminated or truncated); call reset() before step()")
        self.simulate(action)
        self._flags = self.task.evaluate(self.model, self.data)
        depth = self._tracker.update(self._flags, self._elapsed)
        terminated = self._tracker.success
        truncated = self._elapsed >= self.max_episode_steps and not terminated
        if self.occluded:
            self._update_occlusion()
        if terminated or truncated:
            self._ended = True
            self._episode_summary = self._cvg.close_episode()
        return self._observation(), depth / NUM_MILESTONES, terminated, truncated, self._info()

    def render(self):
        """Third-person view (left) beside the active-camera view (right), HWC uint8; None when the env
        was made with `render_mode=None` (gymnasium's convention: nothing is rendered)."""
        if self.render_mode is None:
            return None
        h = self.render_height
        w = 4 * h // 3
        if self._video_renderer is None:
            self._video_renderer = SceneRenderer(self.model, h, w)
        third = self._video_renderer.render_rgb(self.data, C.THIRD_PERSON_CAMERA)
        active = self._video_renderer.render_rgb(self.data, self._camera_id)
        return np.concatenate([third, active], axis=1)

    def close(self):
        for r in (self._renderer, self._video_renderer, self._visibility):
            if r is not None:
                r.close()
        self._renderer = self._video_renderer = self._visibility = None
        self._placer = None
        self._decoy_placers = []  # they hold the closed visibility probe

    # ------------------------------------------------------------------ occlusion
    @property
    def visibility_probe(self) -> TargetVisibility:
        """Privileged visibility renders (lazily created; experts may use it for view search)."""
        if self._visibility is None:
            self._visibility = TargetVisibility(
                self.model, self._camera_id, *self._vis_size, self.obs_settings.fovy
            )
        return self._visibility

    @property
    def current_event(self) -> OcclusionEvent | None:
        return self._events[-1] if self._events else None

    def current_target_geoms(self) -> tuple[int, ...]:
        event = self.current_event
        return self.task.target_geoms[event.target] if event is not None else ()

    def occluder_panel(self):
        """(centre, rotation, (a_y, a_z)) of the current occluder, or None."""
        event = self.current_event
        if event is None:
            return None
        return event.occluder_pos, event.occluder_rot, (OCCLUDER_HALF_EXTENTS[1], OCCLUDER_HALF_EXTENTS[2])

    def hold_occlusion_events(self, held: bool) -> None:
        """While `held`, an occlusion event that falls due waits, and starts at the first step after the
        hold is lifted (several that fall due meanwhile start once). A data-collection lever
        (`bavo-collect --events-outside-contacts`): demonstrations whose events never interrupt the expert's
        grasps and releases. Evaluation never holds events; `reset()` lifts the hold."""
        self._events_held = bool(held)

    def _start_event(self) -> None:
        if self._placer is None:
            robot = [g for g in range(self.model.ngeom) if self.model.geom_group[g] == C.GROUP_ROBOT]
            others = [g for g in range(self.model.ngeom)
                      if self.model.geom_group[g] == C.GROUP_OBJECT and self.model.geom_contype[g]]
            others.append(self.model.geom("table").id)
            self._placer = OccluderPlacer(self.model, self.data, self.visibility_probe, robot, others)
        stage = stage_index(self._tracker.depth, self.task.stage_transitions)
        target = self.task.stage_targets[stage]
        centre, rot, v, fallback = self._placer.place(self.task.target_geoms[target], self._camera_id)
        step = self._elapsed
        self._events.append(OcclusionEvent(
            index=len(self._events), step=step, target=target, occluder_pos=centre, occluder_rot=rot,
            camera_pos=self.data.cam_xpos[self._camera_id].copy(),
            camera_xmat=self.data.cam_xmat[self._camera_id].reshape(3, 3).copy(),
            visibility=v, fallback=fallback,
        ))
        self._cvg.end_open_events(step)
        self._cvg.start_event(step, target)
        if self.decoy_panels:
            self._place_decoys(target, centre)

    def _place_decoys(self, target: str, occluder_centre: np.ndarray) -> None:
        """Re-draw every decoy panel for the event just started (`decoy_panels`)."""
        if not self._decoy_placers:
            self._decoy_placers = [
                OccluderPlacer(self.model, self.data, self.visibility_probe, self._placer.robot_geoms,
                               self._placer.other_geoms, body=decoy_body_name(i))
                for i in range(self.decoy_panels)
            ]
        self._decoys = []
        avoid = [np.asarray(occluder_centre)]
        for placer in self._decoy_placers:
            placed = placer.place_decoy(self._decoy_rng, self.task.target_geoms[target], self._camera_id,
                                        avoid, self.obs_settings.fovy)
            self._decoys.append(placed)
            if placed is not None:
                avoid.append(placed[0])

    def _update_occlusion(self) -> None:
        """Start an event if one is due, then record this step's visibility samples."""
        step = self._elapsed
        started = self._schedule.due(step, self._tracker.depth)  # always asked: Stage keeps state in it
        if self._events_held:
            self._event_pending |= started
            started = False
        elif self._event_pending:
            started, self._event_pending = True, False
        if started:
            self._start_event()
        event = self.current_event
        geoms = self.task.target_geoms[event.target]
        panel = self.occluder_panel()
        v_real = self.visibility_probe.visibility(self.data, geoms, panel)
        self._step_visibility = v_real
        if self.compute_cvg and self._cvg.open_events(step):
            if step == event.step:
                v_frozen = v_real  # the camera has not moved yet: same pose, same state
            else:
                v_frozen = self.visibility_probe.visibility(
                    self.data, geoms, panel, camera_pose=(event.camera_pos, event.camera_xmat))
            self._cvg.record(step, v_real, v_frozen)
        self._event_started = started

    # ------------------------------------------------------------------ helpers
    def simulate(self, action) -> None:
        """Physics of one control step only (no milestones, no observation).

        Validates the action, clips it to the joint limits and runs `CONTROL_SUBSTEPS` physics
        steps with the actuator targets linearly interpolated from the previous target.
        `step()` calls this; benchmarks use it to time physics alone.
        """
        if self._tracker is None:
            raise RuntimeError("call reset() before step()")
        action = np.asarray(action, dtype=np.float64)
        if action.shape != (C.ACTION_DIM,):
            raise ValueError(f"action must have shape ({C.ACTION_DIM},), got {action.shape}")
        if not np.all(np.isfinite(action)):
            raise ValueError(
                f"action contains NaN or inf at indices {np.flatnonzero(~np.isfinite(action)).tolist()}"
            )
        target = self.action_to_ctrl(np.clip(action, self.action_space.low, self.action_space.high))
        start = self._ctrl
        for k in range(1, C.CONTROL_SUBSTEPS + 1):
            self.data.ctrl[:] = start + (target - start) * (k / C.CONTROL_SUBSTEPS)
            mujoco.mj_step(self.model, self.data)
        # mj_step leaves positions, contacts and camera poses from before its last integration;
        # recompute them so observations, milestones and info all describe the same state.
        mujoco.mj_forward(self.model, self.data)
        self._ctrl = target
        self._elapsed += 1

    @staticmethod
    def action_to_ctrl(action: np.ndarray) -> np.ndarray:
        """21-dim action (grippers normalised) -> actuator targets (grippers in metres)."""
        ctrl = np.array(action, dtype=np.float64)
        for i in C.GRIPPER_INDICES:
            ctrl[i] = C.gripper_to_finger(ctrl[i])
        return ctrl

    def joint_state(self) -> np.ndarray:
        """Current 21-dim joint state (grippers normalised), float64 copy."""
        q = self.data.qpos[self._act_qpos_adr].copy()
        for i in C.GRIPPER_INDICES:
            q[i] = C.finger_to_gripper(q[i])
        return q

    def camera_pose(self) -> np.ndarray:
        """T_B<-C (4x4) of the active camera, OpenCV camera convention, from forward kinematics."""
        return camera_pose_from_mujoco(
            self.data.cam_xpos[self._camera_id], self.data.cam_xmat[self._camera_id]
        )

    @property
    def progress(self) -> int:
        return self._tracker.depth if self._tracker is not None else 0

    @property
    def elapsed_steps(self) -> int:
        return self._elapsed

    @property
    def observation_depth(self) -> np.ndarray | None:
        """Z-depth (H, W) float32 metres of the last observation's render (privileged; not part of the
        observation). Kept for a follow-up: whether the teacher can reuse it instead of reading
        depth back a second time is not settled (identical at 48 x 64 in tests/test_datasets.py, not shown at
        240 x 320), so the recorder does not use it yet."""
        return self._observation_depth

    def render_active_rgb(self) -> np.ndarray:
        """The active camera's RGB image (H, W, 3) uint8 of the current state, without building an observation
        (no point cloud): what a live view shows between steps (`bavo-teleop`)."""
        return self._render_active()[0]

    def current_info(self) -> dict:
        """The `info` a step would return for the current state; {} before the first `reset`."""
        return self._info() if self._tracker is not None else {}

    def _active_renderer(self) -> SceneRenderer:
        """The observation-size renderer of the active camera's views, made on first use (a GL context)."""
        if self._renderer is None:
            s = self.obs_settings
            self._renderer = SceneRenderer(self.model, s.image_height, s.image_width)
        return self._renderer

    def _render_active(self) -> tuple[np.ndarray, np.ndarray]:
        return self._active_renderer().render_rgbd(self.data, self._camera_id)

    def point_cloud_of_view(self, rgb: np.ndarray, depth: np.ndarray,
                            self_filter: bool | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The observation's (cloud, point pixels) from the active camera's RGB-D view of the current state:
        the workspace crop, stride and FPS of every observation, with the robot self-filter as the env's
        settings say or as `self_filter` overrides it (e.g. both clouds of one view:
        scripts/cloud_composition.py)."""
        s = self.obs_settings
        robot_pixels = None
        if s.self_filter if self_filter is None else self_filter:
            robot_depth = self._active_renderer().render_depth(self.data, self._camera_id,
                                                               hidden_groups=C.NON_ROBOT_GROUPS)
            robot_pixels = robot_pixel_mask(depth, robot_depth, SELF_FILTER_TOLERANCE)
        return build_point_cloud(
            rgb, depth, self._K, self.camera_pose(), s.n_points, frame=s.point_frame,
            workspace_low=WORKSPACE_LOW, workspace_high=WORKSPACE_HIGH, stride=DEFAULT_STRIDE,
            drop_pixels=robot_pixels,
        )

    def _observation(self) -> dict:
        rgb, depth = self._render_active()
        self._observation_depth = depth  # a fresh array per render, never written to
        cloud, pixels = self.point_cloud_of_view(rgb, depth)
        obs = {
            ENV_STATE_KEY: self.joint_state().astype(np.float32),
            "pixels": {"active": rgb},
            ENV_POINT_CLOUD_KEY: cloud,
            ENV_POINT_PIXELS_KEY: pixels,
        }
        if self.environment_state:
            obs[ENV_ENV_STATE_KEY] = self.task.environment_state(self.model, self.data)
        return obs

    def _info(self) -> dict:
        info = {
            "progress": self._tracker.depth,
            "is_success": bool(self._tracker.success),
            "milestones": dict(self._flags),
            "camera_pose": self.camera_pose(),
            "elapsed_steps": self._elapsed,
            "object_poses": self.task.object_poses(self.model, self.data),
        }
        if self.occluded:
            event = self.current_event
            info["occlusion"] = {
                "condition": self.condition,
                "event": event.to_info(),
                "event_started": self._event_started,
                "num_events": len(self._events),
                "target": event.target,
                "visibility": self._step_visibility,
                "triggers": list(self._schedule.triggers),
            }
            if self.decoy_panels:
                info["occlusion"]["decoy_positions"] = [None if d is None else d[0].copy()
                                                        for d in self._decoys]
        if self._episode_summary is not None:
            info["cvg"] = self._episode_summary
        return info

"""Scripted-expert machinery: the `ScriptedExpert` lifecycle and its Cartesian motion primitives.

An expert is a generator script (`ScriptedExpert.script`) that yields once per control step
after updating the commanded targets of the arms. Targets for a phase are computed when the
phase starts, from privileged simulator state read through the env, so each phase adapts to
where the objects really are. The camera arm is driven separately each step by
`experts/camera.py` (look-at tracking, view recovery after occlusion events), so manipulation and
viewing are decoupled; rotations come from `sim/transforms.py`.

Frames: base (world) frame, metres. Gripper site frame: x = approach direction (out of the
gripper), y = finger closing direction, z = x cross y.
"""

from __future__ import annotations

import abc
from collections.abc import Generator

import numpy as np

from lerobot_bavo.experts.camera import CameraController, ViewRecovery, ViewSearch, plan_view_recovery
from lerobot_bavo.sim import constants as C
from lerobot_bavo.sim.kinematics import ArmKinematics
from lerobot_bavo.sim.transforms import slerp_matrix


def smoothstep(alpha: float) -> float:
    """Minimum-jerk-like easing so motions start and stop gently."""
    return alpha * alpha * (3.0 - 2.0 * alpha)


class ArmCommander:
    """Commanded Cartesian pose and joint target of one manipulator."""

    def __init__(self, kin: ArmKinematics, q0: np.ndarray, gripper: float):
        self.kin = kin
        self.q = np.array(q0, dtype=np.float64)
        self.pos, self.rot = kin.fk(self.q)
        self.gripper = gripper

    def set_pose(self, pos, rot) -> None:
        res = self.kin.ik(pos, rot, q_init=self.q)
        self.q = res.qpos
        self.pos, self.rot = np.asarray(pos, float), np.asarray(rot, float)


def in_contact_phase(agent) -> bool:
    """Whether `agent` (an expert, after its `act`) is in one of its declared `contact_phases`: the final
    approach, grasp and release of an object. Agents without phases (a human at the teleop page) never are.
    Used by DART noise's `clean_contacts` and by `bavo-collect --events-outside-contacts`."""
    return getattr(agent, "phase", None) in getattr(agent, "contact_phases", ())


class ScriptedExpert(abc.ABC):
    """Privileged scripted expert: `reset()` after `env.reset()`, then `act(obs, info)` per step.

    Camera behaviour: the camera arm looks at the task's view points from a set point. When an
    occlusion event starts (privileged: the env's current event), the expert pauses its
    manipulation script (the arms hold their last targets), searches candidate camera positions
    around the current one for the view that best reveals the occluded target (visibility
    renders from each candidate, only for reachable poses), moves the camera there smoothly,
    waits until it has settled, makes that position its new set point, and resumes the script,
    as the paper's demonstrations do (Sec. 3.2).

    Args:
        env: a `BavoEnv` (or a wrapper around one); privileged state is read from it.
        seed: if given, the expert varies its motion durations by up to +-`speed_jitter`, drawn
            from its own generator, so collected demonstrations differ in timing. None keeps
            the nominal timing.
        frozen_camera: reference variant whose camera arm never moves (same manipulation, no
            look-at tracking, no recovery).
        square_grasps: a data variant (`bavo-collect --square-grasps`) for experts that support it
            (`supports_square_grasps`): top-down grasps keep the gripper square to the table's axes
            (yaw 0) instead of turning it to the object's faces, and the closing fingers turn the
            object. Why: the learned policies' wrist yaw at the grasp does not follow the cube's
            (docs/results/learning_rate.md), so demonstrations that never turn the wrist ask for a
            behaviour they can copy. ValueError for an expert that does not support it.
    """

    task_name: str = ""  # the benchmark task this expert solves
    # Phases of approach, grasp and release, where DART-style execution noise is switched off
    # (`experts/perturbation.py`); empty: noise in every phase.
    contact_phases: frozenset[str] = frozenset()
    speed_jitter = 0.15
    supports_square_grasps = False  # whether `square_grasps=True` changes this expert's grasps
    view_search = ViewSearch()  # where view recovery looks, and when it ends

    def __init__(self, env, seed: int | None = None, frozen_camera: bool = False,
                 square_grasps: bool = False):
        if square_grasps and not self.supports_square_grasps:
            raise ValueError(f"square grasps are not implemented for the {self.task_name!r} expert (its "
                             "`supports_square_grasps` is False)")
        self.env = env.unwrapped
        self.seed = seed
        self.frozen_camera = frozen_camera
        self.square_grasps = square_grasps
        self.rng = np.random.default_rng(seed) if seed is not None else None
        self._script: Generator | None = None
        self.phase = "idle"

    # -- lifecycle --------------------------------------------------------------------------
    def reset(self) -> None:
        env = self.env
        q = env.joint_state()
        self.left = ArmCommander(env.kinematics["left"], q[C.LEFT_ARM], q[C.LEFT_GRIPPER])
        self.right = ArmCommander(env.kinematics["right"], q[C.RIGHT_ARM], q[C.RIGHT_GRIPPER])
        self.camera = CameraController(env.kinematics["camera"])
        self.camera.q = q[C.CAMERA_ARM].copy()
        self._script = self.script()
        self.done = False
        self.phase = "start"
        self._seen_event = -1
        self.recovery: ViewRecovery | None = None  # the recovery under way, if any
        self.recoveries: list[ViewRecovery] = []  # what each recovery did (for logs and tests)

    def act(self, obs=None, info=None) -> np.ndarray:
        if self._script is None:
            raise RuntimeError("call expert.reset() after env.reset() before act()")
        if self.frozen_camera:
            self._advance_script()
            return self.action(self.camera.q.copy())
        event = getattr(self.env, "current_event", None)
        if event is not None and event.index != self._seen_event:
            self._seen_event = event.index
            self._start_recovery(event)
        if self.recovery is not None:
            return self.action(self._recovery_step())
        self._advance_script()
        return self.action(self.camera.track(self.look_at()))

    def _advance_script(self) -> None:
        if not self.done:
            try:
                next(self._script)
            except StopIteration:
                self.done = True

    def action(self, cam_q: np.ndarray) -> np.ndarray:
        a = np.empty(C.ACTION_DIM)
        a[C.LEFT_ARM] = self.left.q
        a[C.LEFT_GRIPPER] = self.left.gripper
        a[C.RIGHT_ARM] = self.right.q
        a[C.RIGHT_GRIPPER] = self.right.gripper
        a[C.CAMERA_ARM] = cam_q
        return a

    # -- camera recovery --------------------------------------------------------------------
    @property
    def recovering(self) -> bool:
        """Whether the expert is recovering the view (manipulation paused) after its last action."""
        return self.recovery is not None

    def _start_recovery(self, event) -> None:
        # An event during a recovery re-plans it; the script resumes where it was paused either way.
        resume = self.recovery.resume_phase if self.recovery is not None else self.phase
        self.recovery = plan_view_recovery(self.env, self.camera, event, self.view_search, resume)
        self.recoveries.append(self.recovery)
        self.phase = "recover_view"

    def _recovery_step(self) -> np.ndarray:
        actual = self.env.joint_state()[C.CAMERA_ARM]
        if self.recovery.step(self.camera, actual, self.view_search):
            self.phase = self.recovery.resume_phase
            self.recovery = None
        return self.camera.q.copy()

    # -- script primitives ------------------------------------------------------------------
    def duration(self, steps: int) -> int:
        if self.rng is None:
            return steps
        return max(1, int(round(steps * self.rng.uniform(1 - self.speed_jitter, 1 + self.speed_jitter))))

    def move(self, steps: int, left=None, right=None, phase: str | None = None):
        """Move the given arms to (pos, rot) targets over `steps` control steps (eased)."""
        if phase:
            self.phase = phase
        steps = self.duration(steps)
        plans = []
        for arm, target in ((self.left, left), (self.right, right)):
            if target is not None:
                plans.append(
                    (
                        arm,
                        arm.pos.copy(),
                        arm.rot.copy(),
                        np.asarray(target[0], float),
                        np.asarray(target[1], float),
                    )
                )
        for k in range(1, steps + 1):
            a = smoothstep(k / steps)
            for arm, p0, r0, p1, r1 in plans:
                arm.set_pose(p0 + (p1 - p0) * a, slerp_matrix(r0, r1, a))
            yield

    def grip(
        self, steps: int, left: float | None = None, right: float | None = None, phase: str | None = None
    ):
        """Ramp the gripper commands (0 closed .. 1 open) over `steps` control steps."""
        if phase:
            self.phase = phase
        steps = self.duration(steps)
        starts = (self.left.gripper, self.right.gripper)
        for k in range(1, steps + 1):
            a = k / steps
            if left is not None:
                self.left.gripper = starts[0] + (left - starts[0]) * a
            if right is not None:
                self.right.gripper = starts[1] + (right - starts[1]) * a
            yield

    def wait(self, steps: int, phase: str | None = None):
        if phase:
            self.phase = phase
        for _ in range(steps):
            yield

    # -- privileged state -------------------------------------------------------------------
    def body_pos(self, name: str) -> np.ndarray:
        return self.env.data.body(name).xpos.copy()

    def body_rot(self, name: str) -> np.ndarray:
        return self.env.data.body(name).xmat.reshape(3, 3).copy()

    def gripper_pos(self, side: str) -> np.ndarray:
        return self.env.data.site(f"{side}_gripper_center").xpos.copy()

    def look_at(self) -> np.ndarray:
        """Point the camera aims at: the centroid of the task's current view points."""
        pts = self.env.task.view_points(self.env.model, self.env.data, self.env.progress)
        return pts.mean(axis=0)

    @abc.abstractmethod
    def script(self) -> Generator:
        """The manipulation script; yields once per control step."""

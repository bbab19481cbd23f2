"""Scripted-expert machinery: Cartesian motion primitives solved with IK, and a look-at camera.

An expert is a generator script (`ScriptedExpert.script`) that yields once per control step
after updating the commanded targets of the arms. Targets for a phase are computed when the
phase starts, from privileged simulator state read through the env, so each phase adapts to
where the objects really are. The camera arm is driven separately each step by
`CameraController`, so manipulation and viewing are decoupled (issue 4 pauses the script while
the camera recovers the view).

Frames: base (world) frame, metres. Gripper site frame: x = approach direction (out of the
gripper), y = finger closing direction, z = x cross y.
"""

from __future__ import annotations

import abc
from collections.abc import Generator

import mujoco
import numpy as np

from lerobot_bavo.sim import constants as C
from lerobot_bavo.sim.kinematics import ArmKinematics


def rot_from_axes(x_axis, y_axis) -> np.ndarray:
    """Right-handed rotation matrix whose columns are x, y (re-orthogonalised) and x cross y."""
    x = np.asarray(x_axis, float)
    x = x / np.linalg.norm(x)
    y = np.asarray(y_axis, float)
    y = y - x * (x @ y)
    y = y / np.linalg.norm(y)
    return np.column_stack([x, y, np.cross(x, y)])


def rot_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def slerp_matrix(R0: np.ndarray, R1: np.ndarray, alpha: float) -> np.ndarray:
    q0 = np.zeros(4)
    q1 = np.zeros(4)
    mujoco.mju_mat2Quat(q0, R0.reshape(9))
    mujoco.mju_mat2Quat(q1, R1.reshape(9))
    if q0 @ q1 < 0:
        q1 = -q1
    dot = float(np.clip(q0 @ q1, -1.0, 1.0))
    theta = np.arccos(dot)
    if theta < 1e-6:
        q = q1
    else:
        q = (np.sin((1 - alpha) * theta) * q0 + np.sin(alpha * theta) * q1) / np.sin(theta)
    q /= np.linalg.norm(q)
    out = np.zeros(9)
    mujoco.mju_quat2Mat(out, q)
    return out.reshape(3, 3)


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


class CameraController:
    """Points the active camera at a target point while keeping its position near a set point.

    Each call solves 7-DoF IK for a look-at pose (camera site, MuJoCo camera convention) with a
    null-space pull towards the home posture, then limits the joint change per control step.
    """

    def __init__(self, kin: ArmKinematics, max_joint_speed: float = 1.5):
        self.kin = kin
        self.q = np.array(C.CAMERA_ARM_HOME, dtype=np.float64)
        self.home_pos, _ = kin.fk(self.q)
        self.position = self.home_pos.copy()
        self.max_delta = max_joint_speed * C.CONTROL_DT

    @staticmethod
    def look_rotation(pos, target) -> np.ndarray:
        fwd = np.asarray(target, float) - np.asarray(pos, float)
        fwd /= np.linalg.norm(fwd)
        right = np.cross(fwd, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        up = np.cross(right, fwd)
        return np.column_stack([right, up, -fwd])

    def solve(self, position, look_at) -> np.ndarray:
        """Joint target (7,) for a camera at `position` looking at `look_at` (no rate limit)."""
        rot = self.look_rotation(position, look_at)
        return self.kin.ik(position, rot, q_init=self.q, rot_weight=0.5, nullspace_gain=0.2).qpos

    def track(self, look_at, position=None) -> np.ndarray:
        """Rate-limited step towards looking at `look_at` from `position` (default: set point)."""
        goal = self.solve(self.position if position is None else position, look_at)
        self.q = self.q + np.clip(goal - self.q, -self.max_delta, self.max_delta)
        return self.q.copy()


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
    """

    task_name: str = ""  # the benchmark task this expert solves
    speed_jitter = 0.15
    # View search: lateral / vertical / along-view offsets (metres) from the camera's home set point.
    search_lateral = (-0.2, -0.12, 0.12, 0.2)
    search_vertical = (-0.08, 0.0, 0.08)
    search_depth = (0.0, 0.08)
    recovery_settle_tol = 0.03  # rad, camera joints within this of their goal
    recovery_max_steps = 45  # control steps spent on one recovery at most

    def __init__(self, env, seed: int | None = None, frozen_camera: bool = False):
        self.env = env.unwrapped
        self.seed = seed
        self.frozen_camera = frozen_camera
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
        self._recovery: dict | None = None
        self.recoveries: list[dict] = []  # what each recovery did (for logs and tests)

    def act(self, obs=None, info=None) -> np.ndarray:
        if self._script is None:
            raise RuntimeError("call expert.reset() after env.reset() before act()")
        if self.frozen_camera:
            self._advance_script()
            return self.action(self.camera.q.copy())
        event = getattr(self.env, "current_event", None)
        if event is not None and event.index != self._seen_event:
            self._seen_event = event.index
            self._recovery = self._plan_recovery(event)
        if self._recovery is not None:
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
    def _plan_recovery(self, event) -> dict:
        """Best reachable camera set point for seeing `event`'s target past its occluder."""
        env = self.env
        geoms = env.task.target_geoms[event.target]
        target = env.data.geom_xpos[np.asarray(geoms)].mean(axis=0)
        panel = env.occluder_panel()
        kin = self.camera.kin
        here = self.camera.position
        # Candidates are offsets from the HOME set point (plus staying where we are), so repeated
        # recoveries cannot walk the camera down into the workspace.
        home = self.camera.home_pos
        view = target - home
        view_flat = np.array([view[0], view[1], 0.0])
        forward = view_flat / max(np.linalg.norm(view_flat), 1e-6)
        lateral = np.cross([0.0, 0.0, 1.0], forward)
        candidates = [here.copy()]
        for dl in (0.0, *self.search_lateral):
            for dz in self.search_vertical:
                for dd in self.search_depth:
                    candidates.append(home + dl * lateral + dz * np.array([0.0, 0.0, 1.0]) + dd * forward)
        best = None
        for pos in candidates:
            rot = CameraController.look_rotation(pos, target)
            res = kin.ik(pos, rot, q_init=self.camera.q, rot_weight=0.5, nullspace_gain=0.2)
            if not res.converged:
                continue
            v = env.visibility_probe.visibility(env.data, geoms, panel, camera_pose=(pos, rot))
            cost = float(np.abs(res.qpos - self.camera.q).sum())
            key = (round(v, 2), -cost)
            if best is None or key > best[0]:
                best = (key, pos, res.qpos, v)
        phase = self.phase
        self.phase = "recover_view"
        if best is None:  # nothing reachable: keep the current view
            plan = {"event": event.index, "goal": self.camera.q.copy(), "position": here.copy(),
                    "look_at": target, "visibility": None, "steps": 0, "resume_phase": phase}
        else:
            plan = {"event": event.index, "goal": best[2], "position": best[1], "look_at": target,
                    "visibility": best[3], "steps": 0, "resume_phase": phase}
        self.recoveries.append(plan)
        return plan

    def _recovery_step(self) -> np.ndarray:
        plan = self._recovery
        plan["steps"] += 1
        cam = self.camera
        cam.q = cam.q + np.clip(plan["goal"] - cam.q, -cam.max_delta, cam.max_delta)
        actual = self.env.joint_state()[C.CAMERA_ARM]
        settled = np.max(np.abs(actual - plan["goal"])) < self.recovery_settle_tol
        if settled or plan["steps"] >= self.recovery_max_steps:
            cam.position = plan["position"].copy()
            self.phase = plan["resume_phase"]
            self._recovery = None
        return cam.q.copy()

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
                plans.append((arm, arm.pos.copy(), arm.rot.copy(), np.asarray(target[0], float), np.asarray(target[1], float)))
        for k in range(1, steps + 1):
            a = smoothstep(k / steps)
            for arm, p0, r0, p1, r1 in plans:
                arm.set_pose(p0 + (p1 - p0) * a, slerp_matrix(r0, r1, a))
            yield

    def grip(self, steps: int, left: float | None = None, right: float | None = None, phase: str | None = None):
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

"""The experts' camera behaviour: a look-at controller for the camera arm, and view recovery after an
occlusion event (paper Sec. 3.2).

- `CameraController` points the active camera at a point from a set point (7-DoF IK with a pull
  towards the home posture, rate-limited per control step).
- `plan_view_recovery` searches camera positions around the home set point for the reachable view
  that best reveals an event's target past its occluder (privileged visibility renders), and returns
  a `ViewRecovery`; `ViewRecovery.step` moves the camera there until it has settled.

Frames: base (world) frame, metres; camera orientations in MuJoCo's camera convention.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lerobot_bavo.sim import constants as C
from lerobot_bavo.sim.kinematics import ArmKinematics
from lerobot_bavo.sim.transforms import look_at_matrix


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

    def solve(self, position, look_at) -> np.ndarray:
        """Joint target (7,) for a camera at `position` looking at `look_at` (no rate limit)."""
        rot = look_at_matrix(position, look_at)
        return self.kin.ik(position, rot, q_init=self.q, rot_weight=0.5, nullspace_gain=0.2).qpos

    def track(self, look_at, position=None) -> np.ndarray:
        """Rate-limited step towards looking at `look_at` from `position` (default: set point)."""
        goal = self.solve(self.position if position is None else position, look_at)
        self.q = self.q + np.clip(goal - self.q, -self.max_delta, self.max_delta)
        return self.q.copy()


@dataclass(frozen=True)
class ViewSearch:
    """Where `plan_view_recovery` looks: offsets (metres) from the camera's home set point, laterally
    (horizontal, across the view), vertically, and along the horizontal view direction, plus when a
    recovery ends: camera joints within `settle_tol` (rad) of their goal, or after `max_steps` steps."""

    lateral: tuple[float, ...] = (-0.2, -0.12, 0.12, 0.2)
    vertical: tuple[float, ...] = (-0.08, 0.0, 0.08)
    depth: tuple[float, ...] = (0.0, 0.08)
    settle_tol: float = 0.03
    max_steps: int = 45


@dataclass
class ViewRecovery:
    """One camera recovery after an occlusion event: what was planned and how far it has gone.

    Attributes:
        event: index of the occlusion event it answers.
        goal: camera-arm joint target (7,) of the chosen view.
        position: the chosen camera position, the new set point once the recovery ends.
        look_at: the target's centroid the camera looks at (base frame).
        visibility: V of the target from the chosen view, or None when no candidate was reachable
            (the camera then keeps its current view).
        resume_phase: the manipulation phase to resume when the recovery ends.
        steps: control steps spent so far.
    """

    event: int
    goal: np.ndarray
    position: np.ndarray
    look_at: np.ndarray
    visibility: float | None
    resume_phase: str
    steps: int = 0

    def step(self, camera: CameraController, actual_q: np.ndarray, search: ViewSearch) -> bool:
        """Move `camera` one rate-limited step towards the goal; True when the recovery is over (the measured
        camera joints `actual_q` settled, or `search.max_steps` spent), and the camera's set point is then the
        chosen position."""
        self.steps += 1
        camera.q = camera.q + np.clip(self.goal - camera.q, -camera.max_delta, camera.max_delta)
        done = np.max(np.abs(actual_q - self.goal)) < search.settle_tol or self.steps >= search.max_steps
        if done:
            camera.position = self.position.copy()
        return bool(done)


def plan_view_recovery(
    env, camera: CameraController, event, search: ViewSearch, resume_phase: str
) -> ViewRecovery:
    """Best reachable camera set point for seeing `event`'s target past its occluder.

    Candidates: staying where the camera is, and the home set point shifted by every combination of
    `search`'s offsets (offsets from HOME, so repeated recoveries cannot walk the camera down into the
    workspace). Each is scored by the target's visibility from it (rounded to 0.01), ties broken by
    the smallest joint change; candidates whose IK does not converge are skipped.
    """
    geoms = env.task.target_geoms[event.target]
    target = env.data.geom_xpos[np.asarray(geoms)].mean(axis=0)
    panel = env.occluder_panel()
    kin = camera.kin
    here = camera.position
    home = camera.home_pos
    view = target - home
    view_flat = np.array([view[0], view[1], 0.0])
    forward = view_flat / max(np.linalg.norm(view_flat), 1e-6)
    lateral = np.cross([0.0, 0.0, 1.0], forward)
    candidates = [here.copy()]
    for dl in (0.0, *search.lateral):
        for dz in search.vertical:
            for dd in search.depth:
                candidates.append(home + dl * lateral + dz * np.array([0.0, 0.0, 1.0]) + dd * forward)
    best = None
    for pos in candidates:
        rot = look_at_matrix(pos, target)
        res = kin.ik(pos, rot, q_init=camera.q, rot_weight=0.5, nullspace_gain=0.2)
        if not res.converged:
            continue
        v = env.visibility_probe.visibility(env.data, geoms, panel, camera_pose=(pos, rot))
        cost = float(np.abs(res.qpos - camera.q).sum())
        key = (round(v, 2), -cost)
        if best is None or key > best[0]:
            best = (key, pos, res.qpos, v)
    if best is None:  # nothing reachable: keep the current view
        return ViewRecovery(event=event.index, goal=camera.q.copy(), position=here.copy(), look_at=target,
                            visibility=None, resume_phase=resume_phase)
    return ViewRecovery(event=event.index, goal=best[2], position=best[1], look_at=target, visibility=best[3],
                        resume_phase=resume_phase)

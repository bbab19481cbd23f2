"""Shared task machinery: the task interface, contact queries by bound geom id, milestones.

A task is one class (ManiSkill / dm_control style) with fixed hooks:
- `build(spec)`: add its objects to the MjSpec (once per env).
- `bind_objects(model)`: look up and cache the ids it needs (once per compiled model; `Task.bind`
  binds the grippers, the table, the Stage targets' geoms and the pose bodies first).
- `initialize_episode(model, data, rng)`: sample the episode's object poses from `rng` only.
- `evaluate(model, data) -> dict`: instantaneous milestone flags `m1`..`m5` (privileged state).
Milestone depth is tracked monotonically and in order by `MilestoneTracker`.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass, field

import mujoco
import numpy as np

from lerobot_bavo.metrics import NUM_MILESTONES
from lerobot_bavo.sim.transforms import yaw_quat


class GripperGeoms:
    """Bound geom ids of one manipulator's fingers (pads and stems)."""

    def __init__(self, model: mujoco.MjModel, prefix: str):
        self.pad_a = model.geom(f"{prefix}finger_a_pad").id
        self.pad_b = model.geom(f"{prefix}finger_b_pad").id
        stems = [model.geom(f"{prefix}finger_{s}_stem").id for s in "ab"]
        self.all = frozenset([self.pad_a, self.pad_b, *stems])


def contact_pairs(data: mujoco.MjData) -> set[tuple[int, int]]:
    """All current contact geom pairs, each stored in both orders."""
    n = data.ncon
    if n == 0:
        return set()
    g1 = data.contact.geom1[:n]
    g2 = data.contact.geom2[:n]
    return set(zip(g1.tolist(), g2.tolist())) | set(zip(g2.tolist(), g1.tolist()))


def touching(pairs: set[tuple[int, int]], geoms_a, geoms_b) -> bool:
    return any((a, b) in pairs for a in geoms_a for b in geoms_b)


def holds(pairs: set[tuple[int, int]], gripper: GripperGeoms, object_geoms) -> bool:
    """A grasp: both finger pads touch the object."""
    return touching(pairs, (gripper.pad_a,), object_geoms) and touching(pairs, (gripper.pad_b,), object_geoms)


@dataclass
class MilestoneTracker:
    """Deepest milestone reached so far, in order (M_k counts only after M_{k-1}).

    Once reached a milestone is never lost (paper, App. A "Task progress"); several may be
    reached in one step if their predicates hold together.
    """

    depth: int = 0
    reached_at: list[int] = field(default_factory=list)  # control step at which each was reached

    def update(self, flags: dict[str, bool], step: int) -> int:
        while self.depth < NUM_MILESTONES and flags[f"m{self.depth + 1}"]:
            self.depth += 1
            self.reached_at.append(step)
        return self.depth

    @property
    def success(self) -> bool:
        return self.depth == NUM_MILESTONES


def set_free_body_pose(model: mujoco.MjModel, data: mujoco.MjData, joint_id: int, pos, yaw: float) -> None:
    """Place a free-joint body at `pos` (m) with heading `yaw` (rad about +z), at rest."""
    adr = model.jnt_qposadr[joint_id]
    dof = model.jnt_dofadr[joint_id]
    data.qpos[adr:adr + 3] = pos
    data.qpos[adr + 3:adr + 7] = yaw_quat(yaw)
    data.qvel[dof:dof + 6] = 0.0


class Task(abc.ABC):
    """Base class of a BAVO-Bench task. Subclasses set the class attributes below and implement
    `build`, `initialize_episode` and `evaluate`; `bind_objects` and `view_points` are optional.

    `bind(model)` (once per compiled model) binds what every task needs, then calls `bind_objects`:
    `self.left` / `self.right` (`GripperGeoms` of the manipulators' fingers), `self.table_geoms`,
    `self.target_geoms` (Stage target -> geom ids, from `target_geom_names`; a missing geom raises
    here, so a typo fails when the env is built, not at the first occlusion event) and the bodies of
    `pose_bodies`.
    """

    name: str = ""
    description: str = ""  # the language instruction (LeRobot's `task`)
    order: int = 100  # position in `TASKS` (the paper's order for the five benchmark tasks)
    max_episode_steps: int = 600  # control steps at 25 Hz
    # Stage Occlusion targets (paper, App. A Stage table): initial, after 1st and 2nd transition.
    stage_targets: tuple[str, str, str] = ("", "", "")
    # Milestones at which the Stage target switches (e.g. (2, 4) = after M2 and after M4).
    stage_transitions: tuple[int, int] = (0, 0)
    # Geoms each Stage target is made of, by name: {target: (geom name, ...)}. Every Stage target
    # needs an entry; the occluder is placed on the line of sight to their centroid and V counts
    # their pixels.
    target_geom_names: dict[str, tuple[str, ...]] = {}
    # Bodies whose 7-d poses are `object_poses` (and `environment_state`, in this order): {pose name: body
    # name}.
    pose_bodies: dict[str, str] = {}

    # Bound by `bind`.
    left: GripperGeoms
    right: GripperGeoms
    table_geoms: tuple[int, ...]
    target_geoms: dict[str, tuple[int, ...]]

    @abc.abstractmethod
    def build(self, spec: mujoco.MjSpec) -> None: ...

    def bind(self, model: mujoco.MjModel) -> None:
        """Bind the shared handles and the Stage targets' geoms, then the task's own (`bind_objects`)."""
        missing = [t for t in self.stage_targets if t not in self.target_geom_names]
        if missing:
            raise ValueError(
                f"task {self.name!r}: Stage target(s) {missing} have no entry in target_geom_names "
                f"(declared: {sorted(self.target_geom_names)})"
            )
        geom_names = {model.geom(i).name for i in range(model.ngeom)}
        self.target_geoms = {}
        for target, names in self.target_geom_names.items():
            absent = [g for g in names if g not in geom_names]
            if absent or not names:
                raise ValueError(
                    f"task {self.name!r}: Stage target {target!r} names geom(s) {absent or names} "
                    "that the compiled model does not have (does build() add them?)"
                )
            self.target_geoms[target] = tuple(model.geom(g).id for g in names)
        self.left = GripperGeoms(model, "left_")
        self.right = GripperGeoms(model, "right_")
        self.table_geoms = (model.geom("table").id,)
        self._pose_body_ids = {pose: model.body(body).id for pose, body in self.pose_bodies.items()}
        self.bind_objects(model)

    def bind_objects(self, model: mujoco.MjModel) -> None:  # noqa: B027  (optional hook: a task may bind nothing)
        """Look up and cache the task's own ids (bodies, joints, geoms) once per compiled model."""

    @abc.abstractmethod
    def initialize_episode(
        self, model: mujoco.MjModel, data: mujoco.MjData, rng: np.random.Generator
    ) -> None: ...

    @abc.abstractmethod
    def evaluate(self, model: mujoco.MjModel, data: mujoco.MjData) -> dict[str, bool]: ...

    def object_poses(self, model: mujoco.MjModel, data: mujoco.MjData) -> dict[str, np.ndarray]:
        """Privileged 7-d poses (xyz, wxyz quaternion) of the `pose_bodies`, for `info`."""
        return {
            pose: np.concatenate([data.xpos[b], data.xquat[b]]) for pose, b in self._pose_body_ids.items()
        }

    def environment_state(self, model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
        """`object_poses` flattened in their declared order: (7 * K,) float32 (xyz in metres, base frame;
        wxyz quaternion). The privileged-state observation (`observation.environment_state`), as
        AV-ALOHA's `environment_state`: the ceiling of behaviour cloning with perfect perception."""
        poses = self.object_poses(model, data)
        if not poses:
            return np.zeros(0, dtype=np.float32)
        return np.concatenate([np.asarray(p, dtype=np.float64) for p in poses.values()]).astype(np.float32)

    def view_points(self, model: mujoco.MjModel, data: mujoco.MjData, depth: int) -> np.ndarray:
        """Points (K, 3) the camera should keep in view at milestone depth `depth`."""
        return np.zeros((1, 3))


def free_body_speed(model: mujoco.MjModel, data: mujoco.MjData, joint_id: int) -> tuple[float, float]:
    """Linear (m/s) and angular (rad/s) speed of a free-joint body."""
    dof = model.jnt_dofadr[joint_id]
    return float(np.linalg.norm(data.qvel[dof:dof + 3])), float(np.linalg.norm(data.qvel[dof + 3:dof + 6]))

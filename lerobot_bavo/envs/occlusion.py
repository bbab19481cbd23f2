"""Occlusion (paper Sec. 3.1, App. A): Random-time triggers, Stage indices and where the occluder goes.

- Timing helpers: `sample_random_triggers` (one trigger per window, gaps > 60) and `stage_index`
  (which Stage target applies at a milestone depth). When events start is each condition's rule
  (`envs/conditions.py`); an event's target is the task's Stage target for the stage reached then.
- Placement: candidate poses for a thin camera-facing panel on the line of sight from the active
  camera to the target; the first candidate (in a fixed order) that suppresses the target's
  visibility to V <= `VISIBILITY_THRESHOLD` and keeps clearance from the robot, the objects and
  the table is accepted; otherwise the best-suppressing clear candidate is used and the event is
  flagged as a fallback. The occluder is a mocap body with no collision (contype = conaffinity
  = 0): a purely visual obstacle that can never push objects or arms.

Every random draw takes an explicit ``np.random.Generator`` so that a seeded ``reset``
reproduces the whole schedule.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "RANDOM_TRIGGER_WINDOWS",
    "MIN_TRIGGER_GAP",
    "sample_random_triggers",
    "VISIBILITY_THRESHOLD",
    "OCCLUDER_HALF_EXTENTS",
    "OcclusionEvent",
    "stage_index",
    "panel_rotation_facing",
    "candidate_placements",
    "OCCLUDER_POINT_MARGIN",
    "points_on_occluder",
    "OccluderPlacer",
    "DECOY_MIN_TARGET_VISIBILITY",
]

# --- schedules ---

# Random-time Occlusion (Appendix A): besides the occlusion at reset, one trigger step per window,
# bounds inclusive, in control steps.
RANDOM_TRIGGER_WINDOWS: tuple[tuple[int, int], ...] = (
    (60, 130),
    (130, 200),
    (200, 270),
    (270, 340),
    (340, 410),
    (410, 480),
)
# Consecutive triggers are separated by MORE than this many steps (t_k - t_{k-1} > MIN_TRIGGER_GAP),
# so the H = 60 CVG windows of consecutive events never overlap.
MIN_TRIGGER_GAP = 60
_BATCH = 256  # candidate schedules drawn per round of rejection sampling
_MAX_ROUNDS = 400


def sample_random_triggers(
    rng: np.random.Generator,
    windows: tuple[tuple[int, int], ...] = RANDOM_TRIGGER_WINDOWS,
    min_gap: int = MIN_TRIGGER_GAP,
) -> list[int]:
    """Sample the Random-time trigger steps: one per window, consecutive gaps > min_gap.

    Distribution: uniform over all feasible schedules, i.e. one integer drawn uniformly from each
    window independently, conditioned on every consecutive gap exceeding `min_gap` (rejection
    sampling). This is the plain reading of App. A ("one trigger step is sampled ... from each of
    six windows, subject to consecutive triggers being separated by more than 60 steps") and,
    unlike sampling window by window, it does not push later triggers towards the ends of their
    windows (exact means with the defaults: about 77, 155, 232, 308, 385, 463). About 2% of
    independent draws are feasible with the defaults, so candidates are drawn in batches.
    The occlusion at reset (step 0) is not a sampled trigger and is not part of the gap rule.

    Args:
        rng: the episode's generator; the result is a deterministic function of its state.
        windows: (lo, hi) integer bounds, inclusive, in time order.
        min_gap: consecutive triggers satisfy t_k - t_{k-1} > min_gap.

    Returns:
        len(windows) increasing trigger steps.

    Raises:
        ValueError: for an empty window, or when no feasible schedule is found (windows that are
            infeasible or nearly so).
    """
    for lo, hi in windows:
        if lo > hi:
            raise ValueError(f"empty trigger window ({lo}, {hi})")
    lows = np.array([lo for lo, _ in windows])
    highs = np.array([hi for _, hi in windows])
    for _ in range(_MAX_ROUNDS):
        candidates = rng.integers(lows, highs, size=(_BATCH, len(windows)), endpoint=True)
        ok = np.all(np.diff(candidates, axis=1) > min_gap, axis=1)
        if ok.any():
            return [int(t) for t in candidates[np.argmax(ok)]]
    raise ValueError(
        f"could not sample triggers in windows {windows} with gaps > {min_gap} after "
        f"{_MAX_ROUNDS * _BATCH} candidates; the windows are (nearly) infeasible"
    )


def stage_index(depth: int, transitions: tuple[int, int]) -> int:
    """Which Stage target applies at milestone depth `depth` (0 initial, 1 after the first
    transition milestone, 2 after the second)."""
    return int(depth >= transitions[0]) + int(depth >= transitions[1])


# --- placement ---

# Accept a placement only if it leaves at most this fraction of the target's unoccluded pixels
# visible (V_e <= 0.2).
VISIBILITY_THRESHOLD = 0.2
# The occluder: a thin panel (a board or a hand-sized plate), half extents in metres along its
# normal (x), width (y) and height (z).
OCCLUDER_HALF_EXTENTS = (0.003, 0.075, 0.075)
# Clearance the panel keeps from robot geoms, and from objects and the table, in metres.
ROBOT_CLEARANCE = 0.03
OBJECT_CLEARANCE = 0.01
# Candidate distances from the camera centre along the line of sight (metres), tried from far to
# near (a far occluder sits in the workspace like a real obstacle; near ones cover more), and
# small lateral shifts (metres) in the panel plane.
CANDIDATE_DISTANCES = (0.32, 0.27, 0.23, 0.19, 0.16, 0.13, 0.11)
CANDIDATE_SHIFTS = ((0.0, 0.0), (0.0, 0.03), (0.0, -0.03), (0.03, 0.0), (-0.03, 0.0))
MAX_FRACTION_OF_TARGET_DISTANCE = 0.75


def panel_rotation_facing(direction: np.ndarray) -> np.ndarray:
    """Panel rotation (columns: normal, width, height) whose normal is along `direction` (the
    camera-to-target viewing direction) and whose height axis is as close to world +z as
    possible."""
    n = np.asarray(direction, float)
    n = n / np.linalg.norm(n)
    up = np.array([0.0, 0.0, 1.0])
    width = np.cross(up, n)
    if np.linalg.norm(width) < 1e-6:  # looking straight down: any width axis will do
        width = np.array([1.0, 0.0, 0.0])
    width /= np.linalg.norm(width)
    height = np.cross(n, width)
    return np.column_stack([n, width, height])


def candidate_placements(
    camera_pos: np.ndarray, target_pos: np.ndarray
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Candidate (centre, rotation) poses on the camera-to-target line of sight, in trial order."""
    camera_pos = np.asarray(camera_pos, float)
    view = np.asarray(target_pos, float) - camera_pos
    dist = float(np.linalg.norm(view))
    rot = panel_rotation_facing(view)
    out = []
    for d in CANDIDATE_DISTANCES:
        if d > MAX_FRACTION_OF_TARGET_DISTANCE * dist:
            continue
        for dy, dz in CANDIDATE_SHIFTS:
            centre = camera_pos + view / dist * d + rot[:, 1] * dy + rot[:, 2] * dz
            out.append((centre, rot))
    return out


# How far (metres) outside the panel's box a cloud point may lie and still count as the panel's
# (`points_on_occluder`): depth back-projection puts the panel's points on its camera-facing face,
# 3 mm from the centre plane, and FPS may keep points on its rim.
OCCLUDER_POINT_MARGIN = 0.01


def points_on_occluder(
    xyz: np.ndarray, pose: np.ndarray, margin: float = OCCLUDER_POINT_MARGIN
) -> np.ndarray:
    """Which cloud points lie on the occluder panel: (..., N) bool.

    Why: training-time labels for the occluder-dropout recipe (`policies/augment.py`); the panel is a
    box of `OCCLUDER_HALF_EXTENTS` (+ `margin`) around its pose. Nothing here reaches a policy at
    deployment.

    Args:
        xyz: (..., N, 3) point positions in the base (= world) frame, metres.
        pose: (..., 7) the panel's centre (base frame, metres) and wxyz quaternion, as the dataset's
            `annotation.occluder_pose`; an all-zero quaternion means no occluder (no point is on it).
        margin: metres added to each half extent.
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    pose = np.asarray(pose, dtype=np.float64)
    if xyz.shape[-1] != 3 or pose.shape[-1] != 7 or xyz.shape[:-2] != pose.shape[:-1]:
        raise ValueError(f"expected xyz (..., N, 3) and pose (..., 7) with the same leading axes; got "
                         f"{xyz.shape} and {pose.shape}")
    from lerobot_bavo.sim.transforms import matrices_from_quats

    q = pose[..., 3:]
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    present = norm[..., 0] > 1e-9
    rot = matrices_from_quats(q / np.where(norm > 1e-9, norm, 1.0))  # columns: normal, width, height axes
    local = np.einsum("...nj,...jk->...nk", xyz - pose[..., None, :3], rot)  # point coords along the axes
    half = np.asarray(OCCLUDER_HALF_EXTENTS) + margin
    inside = np.all(np.abs(local) <= half, axis=-1)
    return inside & present[..., None]


# --- decoy panels (a data-collection lever: `BavoEnv(decoy_panels=...)`, `bavo-collect --decoy-panels`) ---

# Where a decoy may aim (base frame, metres): the point cloud's workspace crop, from 2 cm above the table.
DECOY_AIM_LOW = np.array([-0.61, -0.37, 0.02])
DECOY_AIM_HIGH = np.array([0.61, 0.37, 0.4])
# Distances from the camera a decoy may take (metres): the occluder's candidates that put a panel in the
# workspace rather than in front of the lens (the occluder itself is accepted at the farthest one that works).
DECOY_DISTANCES = CANDIDATE_DISTANCES[:3]
# A decoy may hide at most a fifth of the current target (the occluder hides at least four fifths).
DECOY_MIN_TARGET_VISIBILITY = 0.8
# Decoy centres keep this far (metres) from the occluder's: two panel widths, so the two never overlap.
DECOY_MIN_SEPARATION = 0.15
DECOY_TRIES = 40


@dataclass
class OcclusionEvent:
    """One intervention: where the occluder went and what it hid (privileged, for `info`)."""

    index: int
    step: int
    target: str
    occluder_pos: np.ndarray
    occluder_rot: np.ndarray
    camera_pos: np.ndarray  # active camera at the event start, base frame
    camera_xmat: np.ndarray  # (3, 3) MuJoCo camera rotation at the event start
    visibility: float  # V_e right after placement, from the event-start camera
    fallback: bool  # no candidate met the threshold and clearance; best clear one used

    def to_info(self) -> dict:
        return {"index": self.index, "step": self.step, "target": self.target,
                "occluder_pos": self.occluder_pos.copy(), "occluder_quat": self.occluder_quat(),
                "visibility_at_start": self.visibility, "fallback": self.fallback}

    def occluder_quat(self) -> np.ndarray:
        """The panel's orientation as a wxyz unit quaternion (MuJoCo's convention, as its mocap body)."""
        from lerobot_bavo.sim.transforms import quat_from_matrix

        return quat_from_matrix(self.occluder_rot)


class OccluderPlacer:
    """Places the occluder panel for an event (App. A "Occluder placement").

    Candidates come from `candidate_placements` in a fixed order. A candidate is clear if the
    panel keeps `ROBOT_CLEARANCE` from every robot geom (links and grippers of all three arms)
    and `OBJECT_CLEARANCE` from task objects and the table (signed distances from
    `mujoco.mj_geomDistance`). The first clear candidate with V_e <= `VISIBILITY_THRESHOLD`
    (from the current camera) is accepted. If none qualifies, the clear candidate with the
    lowest V_e is used, or, if none is clear, the first candidate; both are flagged `fallback`.
    `place` is deterministic: no randomness is involved (`place_decoy` draws from the generator it is given).

    Args:
        model, data: the env's simulation (only the panel's mocap pose and derived
            kinematics are written).
        visibility: the env's `TargetVisibility` probe.
        robot_geoms, other_geoms: geom ids to keep clear of.
        body: the panel's mocap body (its geom: `sim.scene.panel_geom_name`): the occluder, or a decoy panel
            (`place_decoy`).
    """

    def __init__(self, model, data, visibility, robot_geoms, other_geoms, body: str = "occluder"):
        import mujoco

        from lerobot_bavo.sim.scene import panel_geom_name

        self._mj = mujoco
        self.model, self.data = model, data
        self.visibility = visibility
        self.body = model.body(body).id
        self.mocap = model.body_mocapid[self.body]
        self.geom = model.geom(panel_geom_name(body)).id
        self.half = (OCCLUDER_HALF_EXTENTS[1], OCCLUDER_HALF_EXTENTS[2])
        self.robot_geoms = np.asarray(robot_geoms)
        self.other_geoms = np.asarray(other_geoms)

    def set_pose(self, centre: np.ndarray, rot: np.ndarray) -> None:
        quat = np.zeros(4)
        self._mj.mju_mat2Quat(quat, np.ascontiguousarray(rot).reshape(9))
        self.data.mocap_pos[self.mocap] = centre
        self.data.mocap_quat[self.mocap] = quat
        self._mj.mj_kinematics(self.model, self.data)

    def _clear(self) -> bool:
        for geoms, margin in ((self.robot_geoms, ROBOT_CLEARANCE), (self.other_geoms, OBJECT_CLEARANCE)):
            for g in geoms:
                if self._mj.mj_geomDistance(self.model, self.data, self.geom, int(g), margin, None) < margin:
                    return False
        return True

    def place(self, target_geoms, camera_id: int) -> tuple[np.ndarray, np.ndarray, float, bool]:
        """Place the panel for `target_geoms`; returns (centre, rotation, V_e, fallback)."""
        target_pos = self.data.geom_xpos[np.asarray(target_geoms)].mean(axis=0)
        camera_pos = self.data.cam_xpos[camera_id].copy()
        candidates = candidate_placements(camera_pos, target_pos)
        if not candidates:  # target closer than the nearest candidate distance allows
            candidates = [
                (camera_pos + 0.5 * (target_pos - camera_pos), panel_rotation_facing(target_pos - camera_pos))
            ]
        best = None
        for centre, rot in candidates:
            self.set_pose(centre, rot)
            if not self._clear():
                continue
            v = self.visibility.visibility(self.data, target_geoms, (centre, rot, self.half))
            if v <= VISIBILITY_THRESHOLD:
                return centre, rot, v, False
            if best is None or v < best[2]:
                best = (centre, rot, v)
        if best is None:
            centre, rot = candidates[0]
            self.set_pose(centre, rot)
            best = (
                centre,
                rot,
                self.visibility.visibility(self.data, target_geoms, (centre, rot, self.half)),
            )
        self.set_pose(best[0], best[1])
        return best[0], best[1], best[2], True

    def place_decoy(self, rng: np.random.Generator, target_geoms, camera_id: int, avoid_centres,
                    fovy_deg: float) -> tuple[np.ndarray, np.ndarray] | None:
        """Place this panel as a decoy: a panel like the occluder, in view, that leaves the current target
        visible. Returns its (centre, rotation), or None (parked) when no draw qualifies.

        Why: the Stage occluder always lies on the line of sight to the current target, so a policy can read
        the target's position off the panel (docs/results/occluder_shortcut.md). A decoy is drawn where the
        target is not, so a panel in the cloud stops telling where the target is.

        Each of `DECOY_TRIES` draws aims at a point uniform in the workspace box (`DECOY_AIM_LOW`,
        `DECOY_AIM_HIGH`, base frame, metres) inside the camera's view cone (half-angle fovy / 2), and puts
        the panel on the line of sight to it, facing the camera, at one of `DECOY_DISTANCES` (metres from the
        camera; only those below `MAX_FRACTION_OF_TARGET_DISTANCE` of the aim's distance). A draw is
        accepted if the panel keeps the occluder's clearances, its centre is at least `DECOY_MIN_SEPARATION`
        from each of `avoid_centres` (the occluder's, the decoys placed before it) and the current target
        keeps V >= `DECOY_MIN_TARGET_VISIBILITY` with the decoy alone in the way. Every draw comes from
        `rng`; the number of draws used varies.
        """
        camera_pos = self.data.cam_xpos[camera_id].copy()
        view_axis = -self.data.cam_xmat[camera_id].reshape(3, 3)[:, 2]  # MuJoCo cameras look along -z
        cos_half = np.cos(np.deg2rad(fovy_deg) / 2)
        for _ in range(DECOY_TRIES):
            aim = rng.uniform(DECOY_AIM_LOW, DECOY_AIM_HIGH)
            d_choice = float(rng.choice(DECOY_DISTANCES))
            view = aim - camera_pos
            dist = float(np.linalg.norm(view))
            if (dist < 1e-6 or view @ view_axis / dist < cos_half
                    or d_choice > MAX_FRACTION_OF_TARGET_DISTANCE * dist):
                continue
            rot = panel_rotation_facing(view)
            centre = camera_pos + view / dist * d_choice
            if any(np.linalg.norm(centre - np.asarray(c)) < DECOY_MIN_SEPARATION for c in avoid_centres):
                continue
            self.set_pose(centre, rot)
            if not self._clear():
                continue
            if self.visibility.visibility(self.data, target_geoms, (centre, rot, self.half)) \
                    < DECOY_MIN_TARGET_VISIBILITY:
                continue
            return centre, rot
        self.park()
        return None

    def park(self) -> None:
        """Move the panel out of every view (`sim.scene.DECOY_PARKED_POS`)."""
        from lerobot_bavo.sim.scene import DECOY_PARKED_POS

        self.set_pose(np.asarray(DECOY_PARKED_POS, float), np.eye(3))


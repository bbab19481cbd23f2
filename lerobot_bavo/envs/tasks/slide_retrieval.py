"""Slide Retrieval: slide a flat spatula along a grooved platform until its handle sticks out
over the edge, then retrieve it by the handle with the left arm.

Task description:
    A low support platform (24 x 18 x 4 cm, static) stands in the middle of the table. A
    4 cm-high slab is cut by a 3 cm-wide, 2 cm-deep groove running along the platform's long
    axis (the platform's x, pointing from its right end to its left end = -x). On it lies an
    offset spatula (one free body): a wide thin blade resting flat on the platform top across
    the groove, and a narrower handle that hangs below the blade inside the groove, its top
    flush with the platform top and its tip just inside the platform's left (-x) edge. In the
    groove the handle cannot be grasped: there is 4 mm of clearance on each side (a finger pad
    is 8 mm thick) and the groove floor is under it. The right gripper presses down on the
    blade (the pads' friction 1.5 against 0.3 between spatula and platform) and drags the
    spatula towards the left arm until the handle overhangs the left edge; it then lets go,
    and the left gripper grasps the overhanging handle from above and lifts the spatula.

Objects (MjSpec primitives; metres, kilograms):
    platform (static, mocap-placed at reset): floor slab 0.24 x 0.18 x 0.02 plus two side
        slabs 0.24 x 0.075 x 0.02 on it, leaving a 0.03-wide, 0.02-deep groove; top at
        z = 0.04; friction 0.3.
    spatula (free body, 0.15 kg): blade box 0.08 (x) x 0.08 (y) x 0.008 (z), 0.10 kg; handle
        box 0.12 x 0.022 x 0.014, 0.05 kg, whose top touches the blade's underside and whose
        last 0.025 lies under the blade (9.5 cm of handle past the blade); friction 0.3.

Randomisations (uniform, from the env's RNG):
    platform centre x in [-0.04, 0.04] m, y in [-0.04, 0.10] m, yaw in [-pi/12, pi/12] rad;
    handle tip inset from the platform's left edge in [0.01, 0.03] m; spatula lateral offset
    in the groove in [-0.002, 0.002] m (aligned with the groove, resting on the platform).

Milestones (paper, App. A, Table "Task objectives and milestone progression"):
    M1 the right gripper contacts the blade (a contact between a right finger geom and the
        blade geom);
    M2 the handle is exposed by sliding: its tip is at least 4 cm past the platform's left edge
        (measured along the platform's axis) while the blade still rests on the platform;
    M3 the right gripper releases the object: M2's exposure holds and every right finger geom
        is at least 1 cm away from the spatula (no contact, and not a momentary loss of contact
        while pressing);
    M4 the left gripper contacts the exposed handle: a contact between a left finger geom and
        the handle geom whose contact point lies past the platform's left edge;
    M5 the left arm lifts the object from the support surface: both left pads touch the handle,
        no right finger touches the spatula, the spatula touches no platform geom and its lowest
        corner is at least 3 cm above the platform top. M5 is success.

Stage Occlusion targets: support platform, then blade after M1, then handle after M2.

Episode length: the nominal expert succeeds in 280-295 control steps (about 12 s) in Clean and
in 370-450 under Random-time Occlusion; `max_episode_steps` = 800 leaves room for up to seven
~45-step camera-recovery pauses and for a slower learned policy.
"""

from __future__ import annotations

import mujoco
import numpy as np

from lerobot_bavo.envs.tasks.base import (
    Task,
    contact_pairs,
    holds,
    touching,
)
from lerobot_bavo.sim import constants as C
from lerobot_bavo.sim.transforms import yaw_quat

# Platform, in its own frame: origin on the table top under the platform centre, x along the
# groove (the handle points to -x, towards the left arm; its "left edge" is at x = -0.12), z up.
PLATFORM_HALF = (0.12, 0.09, 0.02)  # overall half extents: 24 x 18 x 4 cm
FLOOR_HALF_HEIGHT = 0.01  # floor slab 2 cm thick: groove floor at z = 0.02
GROOVE_HALF_WIDTH = 0.015  # groove 3 cm wide
PLATFORM_TOP = 2 * PLATFORM_HALF[2]  # 0.04 m
PLATFORM_FRICTION = 0.3

# Spatula (object frame: origin at the blade centre, x towards the blade's far end, the handle
# pointing to -x).
BLADE_HALF = (0.04, 0.04, 0.004)
HANDLE_HALF = (0.06, 0.011, 0.007)
HANDLE_UNDER_BLADE = 0.025  # length of handle hidden under the blade
BLADE_MASS = 0.10
HANDLE_MASS = 0.05
SPATULA_FRICTION = 0.3
# Handle centre in the object frame: its +x end 2.5 cm under the blade, its top touching the
# blade's underside.
HANDLE_OFFSET = (
    -(BLADE_HALF[0] - HANDLE_UNDER_BLADE + HANDLE_HALF[0]),
    0.0,
    -(BLADE_HALF[2] + HANDLE_HALF[2]),
)
# Handle tip (its -x end) in the object frame.
HANDLE_TIP = (HANDLE_OFFSET[0] - HANDLE_HALF[0], 0.0, HANDLE_OFFSET[2])

PLATFORM_X = (-0.04, 0.04)
PLATFORM_Y = (-0.04, 0.10)
PLATFORM_YAW = (-np.pi / 12, np.pi / 12)
TIP_INSET = (0.01, 0.03)  # handle tip inside the left edge at reset
LATERAL_OFFSET = (-0.002, 0.002)

EXPOSED_LENGTH = 0.04  # m of handle past the edge for "exposed"
RELEASE_CLEARANCE = 0.01  # m between every right finger geom and the spatula for "released"
LIFT_CLEARANCE = 0.03  # m between the spatula's lowest corner and the platform top


def _box_corners(size) -> np.ndarray:
    s = np.asarray(size)
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
    return signs * s


class SlideRetrieval(Task):
    name = "slide_retrieval"
    description = "Slide the spatula to expose its handle, then lift it by the handle with the left arm."
    max_episode_steps = 800
    stage_targets = ("support_platform", "blade", "handle")
    stage_transitions = (1, 2)
    target_geom_names = {
        "support_platform": ("platform_floor", "platform_side_a", "platform_side_b"),
        "blade": ("blade_geom",),
        "handle": ("handle_geom",),
    }
    pose_bodies = {"spatula": "spatula", "platform": "platform"}
    order = 4

    def build(self, spec: mujoco.MjSpec) -> None:
        hx, hy, hz = PLATFORM_HALF
        platform = spec.worldbody.add_body(name="platform", pos=[0.0, 0.03, 0.0], mocap=True)
        rgba = [0.35, 0.5, 0.62, 1]
        friction = [PLATFORM_FRICTION, 0.005, 0.0001]
        platform.add_geom(name="platform_floor", type=mujoco.mjtGeom.mjGEOM_BOX,
                          size=[hx, hy, FLOOR_HALF_HEIGHT], pos=[0, 0, FLOOR_HALF_HEIGHT],
                          rgba=rgba, group=C.GROUP_OBJECT, friction=friction)
        side_half_y = 0.5 * (hy - GROOVE_HALF_WIDTH)
        side_half_z = hz - FLOOR_HALF_HEIGHT
        for name, sign in (("platform_side_a", 1.0), ("platform_side_b", -1.0)):
            platform.add_geom(
                name=name,
                type=mujoco.mjtGeom.mjGEOM_BOX,
                size=[hx, side_half_y, side_half_z],
                pos=[0, sign * (GROOVE_HALF_WIDTH + side_half_y), 2 * FLOOR_HALF_HEIGHT + side_half_z],
                rgba=rgba,
                group=C.GROUP_OBJECT,
                friction=friction,
            )

        spatula = spec.worldbody.add_body(name="spatula", pos=[0.0, 0.03, PLATFORM_TOP + BLADE_HALF[2]])
        spatula.add_freejoint(name="spatula_joint")
        sfriction = [SPATULA_FRICTION, 0.005, 0.0001]
        spatula.add_geom(name="blade_geom", type=mujoco.mjtGeom.mjGEOM_BOX, size=list(BLADE_HALF),
                         mass=BLADE_MASS, rgba=[0.78, 0.8, 0.84, 1], group=C.GROUP_OBJECT,
                         friction=sfriction, condim=4)
        spatula.add_geom(name="handle_geom", type=mujoco.mjtGeom.mjGEOM_BOX, size=list(HANDLE_HALF),
                         pos=list(HANDLE_OFFSET), mass=HANDLE_MASS, rgba=[0.75, 0.32, 0.1, 1],
                         group=C.GROUP_OBJECT, friction=sfriction, condim=4)

    def bind_objects(self, model: mujoco.MjModel) -> None:
        self.platform_body = model.body("platform").id
        self.platform_mocap = int(model.body_mocapid[self.platform_body])
        self.spatula_body = model.body("spatula").id
        self.spatula_joint = model.joint("spatula_joint").id
        self.blade_geom = model.geom("blade_geom").id
        self.handle_geom = model.geom("handle_geom").id
        self.spatula_geoms = (self.blade_geom, self.handle_geom)
        self.platform_geoms = self.target_geoms["support_platform"]

    def initialize_episode(self, model, data, rng: np.random.Generator) -> None:
        xy = rng.uniform([PLATFORM_X[0], PLATFORM_Y[0]], [PLATFORM_X[1], PLATFORM_Y[1]])
        yaw = rng.uniform(*PLATFORM_YAW)
        inset = rng.uniform(*TIP_INSET)
        lateral = rng.uniform(*LATERAL_OFFSET)
        quat = yaw_quat(yaw)
        data.mocap_pos[self.platform_mocap] = [xy[0], xy[1], 0.0]
        data.mocap_quat[self.platform_mocap] = quat
        # Spatula frame in the platform frame: tip `inset` inside the left edge, blade resting on
        # the platform top, axis along the groove.
        local = np.array([-PLATFORM_HALF[0] + inset - HANDLE_TIP[0], lateral, PLATFORM_TOP + BLADE_HALF[2]])
        c, s = np.cos(yaw), np.sin(yaw)
        world = np.array([xy[0] + c * local[0] - s * local[1], xy[1] + s * local[0] + c * local[1], local[2]])
        adr = model.jnt_qposadr[self.spatula_joint]
        dof = model.jnt_dofadr[self.spatula_joint]
        data.qpos[adr:adr + 3] = world
        data.qpos[adr + 3:adr + 7] = quat
        data.qvel[dof:dof + 6] = 0.0

    # -- geometry helpers (privileged state) ---------------------------------------------------
    def platform_frame(self, data) -> tuple[np.ndarray, np.ndarray]:
        """Platform origin (3,) and rotation (3, 3) in the base frame."""
        return data.xpos[self.platform_body].copy(), data.xmat[self.platform_body].reshape(3, 3).copy()

    def to_platform(self, data, points) -> np.ndarray:
        """Points (..., 3) from the base frame into the platform frame."""
        p, R = self.platform_frame(data)
        return (np.asarray(points) - p) @ R

    def handle_tip(self, data) -> np.ndarray:
        R = data.xmat[self.spatula_body].reshape(3, 3)
        return data.xpos[self.spatula_body] + R @ np.asarray(HANDLE_TIP)

    def exposed_length(self, data) -> float:
        """How far (m) the handle's tip is past the platform's left edge, along the platform x."""
        return float(-PLATFORM_HALF[0] - self.to_platform(data, self.handle_tip(data))[0])

    def lowest_point(self, model, data) -> float:
        """Lowest z (m) over the corners of the blade and handle boxes."""
        z = []
        for g in self.spatula_geoms:
            R = data.geom_xmat[g].reshape(3, 3)
            corners = data.geom_xpos[g] + _box_corners(model.geom_size[g]) @ R.T
            z.append(corners[:, 2].min())
        return float(min(z))

    def right_clearance(self, model, data) -> float:
        """Smallest distance (m) between a right finger geom and a spatula geom (capped at 5 cm)."""
        cap = 0.05
        return min(mujoco.mj_geomDistance(model, data, f, g, cap, None)
                   for f in sorted(self.right.all) for g in self.spatula_geoms)

    def _left_touches_exposed_handle(self, data) -> bool:
        n = data.ncon
        for i in range(n):
            g1, g2 = int(data.contact.geom1[i]), int(data.contact.geom2[i])
            touching = (g1 == self.handle_geom and g2 in self.left.all) or (
                g2 == self.handle_geom and g1 in self.left.all)
            if touching and self.to_platform(data, data.contact.pos[i])[0] < -PLATFORM_HALF[0]:
                return True
        return False

    def evaluate(self, model, data) -> dict[str, bool]:
        pairs = contact_pairs(data)
        right_blade = touching(pairs, self.right.all, (self.blade_geom,))
        right_any = touching(pairs, self.right.all, self.spatula_geoms)
        blade_supported = touching(pairs, (self.blade_geom,), self.platform_geoms)
        on_platform = touching(pairs, self.spatula_geoms, self.platform_geoms)
        exposed = bool(self.exposed_length(data) >= EXPOSED_LENGTH and blade_supported)
        left_hold = holds(pairs, self.left, (self.handle_geom,))
        lifted = (not on_platform) and self.lowest_point(model, data) >= PLATFORM_TOP + LIFT_CLEARANCE
        return {
            "m1": bool(right_blade),
            "m2": exposed,
            "m3": bool(exposed and not right_any and self.right_clearance(model, data) >= RELEASE_CLEARANCE),
            "m4": self._left_touches_exposed_handle(data),
            "m5": bool(left_hold and lifted and not right_any),
        }

    def view_points(self, model, data, depth: int) -> np.ndarray:
        p = data.xpos[self.platform_body] + [0.0, 0.0, PLATFORM_TOP]
        return np.stack([p, data.xpos[self.spatula_body], self.handle_tip(data)])

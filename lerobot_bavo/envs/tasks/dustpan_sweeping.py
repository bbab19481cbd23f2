"""Dustpan Sweeping: position the dustpan and sweep the target object into it.

Task description:
    A dustpan lies on the left half of the table, beside a small cube (the target object) in the
    middle, and a push broom lies on the right half. The left arm grasps the dustpan's handle
    and drags the pan along the table until its entrance faces the cube; it keeps holding it.
    The right arm then grasps the broom's handle and pushes the cube with the broom head, in
    the -x direction, over the pan's entrance ramp.

Objects (our own MjSpec primitives; frames: +x of the pan = its entrance direction, +x of the
broom = along its handle, +z up, body origins on the table surface):
    dustpan (free body, 0.25 kg): a 3 mm plate 11 x 13 cm; a 3 cm entrance ramp in front of it
        (a wedge from the table surface up to the plate top, 5.7 deg); 2.5 cm side walls and a
        3.5 cm back wall; a flat 9 x 2 x 1.2 cm handle cantilevered behind the back wall at
        2.6-3.8 cm height, grasped top-down. Pan-table friction 0.4. The ramp is modelled as a
        box whose lower part lies inside the table: its collision bits (contype = conaffinity
        = 2) skip the table (1/1) and keep contacts with the robot (2/1) and with the cube and
        the broom's bristles (contype 1, conaffinity 3), so it acts as a wedge flush with the
        table top (no step at the entrance lip).
    broom (free body, 0.22 kg): a bristle block 5 x 14 x 2.4 cm (friction 0.35), a wooden
        stock on top, and a round handle (radius 1 cm, 15 cm) rising from 3.6 to 6.0 cm height
        along +x; the centre of mass lies over the bristles, so it rests on them.
    target object (free body): a 3 cm cube, 20 g, friction 0.5.
    All objects collide with the table, each other and the robot; nothing is welded or moved
    kinematically; grasps hold by finger friction only.

Randomisations (uniform, from the env's RNG only):
    cube centre x in [-0.03, 0.03] m, y in [-0.02, 0.10] m, yaw in [-pi/4, pi/4] rad;
    dustpan plate centre x = cube x - 0.11 + [-0.03, 0.03] m, y = cube y + s [0.13, 0.17] m with
        the side s = +-1 drawn with equal probability, yaw in [-25, 25] deg (entrance roughly
        facing +x); this keeps the cube out of the sweep corridor at reset (M2 false);
    broom head centre x = cube x + [0.11, 0.15] m, y = cube y + [-0.05, 0.05] m, yaw in
        [-20, 20] deg (handle roughly along +x, towards the right arm).
    The ranges keep the footprints of every pair of objects at least 2 cm apart at reset.

Milestones (paper, App. A, Table "Task objectives and milestone progression"):
    M1 the left gripper contacts the dustpan handle (a left finger geom touches the handle geom);
    M2 the dustpan reaches a valid sweeping configuration: the pan lies flat on the table (tilt
       < 10 deg, plate origin < 1 cm above the table), it is nearly still (< 3 cm/s), and the
       cube lies in the sweep corridor in front of the entrance: in the pan's frame its centre
       is 0.01-0.12 m ahead of the entrance line and within 4 cm of the pan's axis. Holding
       the pan is not required (the expert keeps holding it, so sweeping cannot push it away);
    M3 the right gripper contacts the broom (a right finger geom touches any broom geom);
    M4 the broom contacts the target during sweeping: the broom head (bristles or stock) touches
       the cube while a right finger geom still touches the broom;
    M5 the cube reaches the dustpan entrance: its centre lies at least 1.5 cm (half the cube)
       past the entrance line (the ramp's front edge), so a square cube has wholly crossed it,
       between the side walls (|lateral| < 5.9 cm) and in front of the back wall, less than 4 cm
       above the table, with the pan still flat (tilt < 10 deg). M5 is success.

Stage Occlusion targets: dustpan, then broom after M2, then target object after M3.

Episode length: the nominal expert succeeds in about 375 control steps; `max_episode_steps`
= 800 leaves room for ~7 camera-recovery pauses of ~40 steps each under occlusion.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from lerobot_bavo.envs.tasks.base import (
    Task,
    contact_pairs,
    free_body_speed,
    set_free_body_pose,
    touching,
)
from lerobot_bavo.sim import constants as C

# --------------------------------------------------------------------------------------------
# Dustpan (pan frame: origin on the table under the plate centre, +x = entrance direction)
# --------------------------------------------------------------------------------------------
PLATE_HALF = (0.055, 0.065, 0.0015)  # m: 11 cm deep, 13 cm wide, 3 mm thick
PLATE_TOP = 2 * PLATE_HALF[2]
RAMP_LEN = 0.03  # m, horizontal length of the entrance wedge
RAMP_HALF_T = 0.0015  # m, half thickness of the ramp box
RAMP_ANGLE = math.atan2(PLATE_TOP, RAMP_LEN)
RAMP_BURY = 0.003  # m, the ramp's top face continues this far below the table top (contacts sink ~1 mm)
ENTRANCE_X = PLATE_HALF[0] + RAMP_LEN  # local x of the entrance line (ramp front edge)
WALL_T = 0.003  # m, half thickness of the walls
SIDE_WALL_H = 0.025
BACK_WALL_H = 0.035
HANDLE_HALF = (0.045, 0.010, 0.006)  # along x, across (grasp width 2 cm), vertical
HANDLE_POS = (-PLATE_HALF[0] - HANDLE_HALF[0], 0.0, PLATE_TOP + BACK_WALL_H - HANDLE_HALF[2])
PAN_FRICTION = (0.4, 0.01, 0.001)
PAN_MASSES = {"plate": 0.12, "ramp": 0.02, "side": 0.025, "back": 0.03, "handle": 0.03}
INNER_HALF_WIDTH = PLATE_HALF[1] - 2 * WALL_T  # m, between the side walls
BACK_INNER_X = -PLATE_HALF[0] + 2 * WALL_T

# --------------------------------------------------------------------------------------------
# Broom (broom frame: origin on the table under the head centre, +x = along the handle)
# --------------------------------------------------------------------------------------------
HEAD_HALF = (0.025, 0.07, 0.012)  # bristle block
STOCK_HALF = (0.027, 0.074, 0.006)  # wooden back on top of the bristles
HANDLE_RADIUS = 0.010
BROOM_HANDLE_FROM = (0.02, 0.0, 0.036)
BROOM_HANDLE_TO = (0.17, 0.0, 0.060)
BROOM_FRICTION = (0.35, 0.01, 0.001)
BROOM_MASSES = {"head": 0.14, "stock": 0.05, "handle": 0.025}

# --------------------------------------------------------------------------------------------
# Target object
# --------------------------------------------------------------------------------------------
TARGET_HALF = 0.015  # m, 3 cm cube
TARGET_MASS = 0.02  # kg
TARGET_FRICTION = (0.5, 0.01, 0.001)

# Collision bits: the ramp (2/2) touches the robot (contype 2) and geoms whose conaffinity has
# bit 2 (the cube and the broom head, 1/3), never the table (1/1).
RAMP_BITS = (2, 2)
RAMP_PARTNER_BITS = (1, 3)

# --------------------------------------------------------------------------------------------
# Reset distribution
# --------------------------------------------------------------------------------------------
TARGET_X = (-0.03, 0.03)
TARGET_Y = (-0.02, 0.10)
TARGET_YAW = (-np.pi / 4, np.pi / 4)
PAN_DX = (-0.14, -0.08)  # pan centre x minus cube x
PAN_DY = (0.13, 0.17)  # |pan centre y minus cube y|, side drawn at random
PAN_YAW = (-np.radians(25), np.radians(25))
BROOM_DX = (0.11, 0.15)  # broom head centre x minus cube x
BROOM_DY = (-0.05, 0.05)
BROOM_YAW = (-np.radians(20), np.radians(20))

# --------------------------------------------------------------------------------------------
# Milestone thresholds
# --------------------------------------------------------------------------------------------
MAX_TILT = np.radians(10)
ON_TABLE_Z = 0.01  # m, pan origin height
STILL_SPEED = 0.03  # m/s
CORRIDOR_AHEAD = (0.01, 0.12)  # m, cube centre ahead of the entrance line (M2)
CORRIDOR_HALF_WIDTH = 0.04  # m (M2)
IN_PAN_MAX_Z = 0.04  # m, cube centre height bound for M5
IN_PAN_DEPTH = TARGET_HALF  # m, cube centre past the entrance line for M5 (the whole cube, if square)


class DustpanSweeping(Task):
    name = "dustpan_sweeping"
    description = "Position the dustpan and sweep the target object into it."
    max_episode_steps = 800
    stage_targets = ("dustpan", "broom", "target_object")
    stage_transitions = (2, 3)
    target_geom_names = {
        "dustpan": (
            "dustpan_plate",
            "dustpan_ramp",
            "dustpan_wall_left",
            "dustpan_wall_right",
            "dustpan_wall_back",
            "dustpan_handle",
        ),
        "broom": ("broom_head", "broom_stock", "broom_handle"),
        "target_object": ("target_object_geom",),
    }
    pose_bodies = {"dustpan": "dustpan", "broom": "broom", "target_object": "target_object"}
    order = 5

    # ------------------------------------------------------------------ build
    def build(self, spec: mujoco.MjSpec) -> None:
        box = mujoco.mjtGeom.mjGEOM_BOX
        pan_rgba = [0.15, 0.55, 0.35, 1]
        pan = spec.worldbody.add_body(name="dustpan", pos=[-0.12, 0.2, 0.0])
        pan.add_freejoint(name="dustpan_joint")
        common = dict(group=C.GROUP_OBJECT, friction=list(PAN_FRICTION), priority=1, condim=4)
        pan.add_geom(name="dustpan_plate", type=box, size=list(PLATE_HALF), pos=[0, 0, PLATE_HALF[2]],
                     mass=PAN_MASSES["plate"], rgba=pan_rgba, **common)
        # Top face runs from (PLATE_HALF_x, PLATE_TOP) down through (ENTRANCE_X, 0) to RAMP_BURY
        # below the table top; the box centre lies half a thickness below the top face's
        # midpoint, along the face normal.
        drop = PLATE_TOP + RAMP_BURY
        run = drop / math.tan(RAMP_ANGLE)
        ramp_len = math.hypot(run, drop)
        normal = np.array([math.sin(RAMP_ANGLE), 0.0, math.cos(RAMP_ANGLE)])
        top_mid = np.array([PLATE_HALF[0] + run / 2, 0.0, PLATE_TOP - drop / 2])
        pan.add_geom(name="dustpan_ramp", type=box, size=[ramp_len / 2, PLATE_HALF[1], RAMP_HALF_T],
                     pos=list(top_mid - RAMP_HALF_T * normal),
                     quat=[math.cos(RAMP_ANGLE / 2), 0.0, math.sin(RAMP_ANGLE / 2), 0.0],
                     mass=PAN_MASSES["ramp"], rgba=pan_rgba, contype=RAMP_BITS[0], conaffinity=RAMP_BITS[1],
                     **common)
        for side, sign in (("left", 1.0), ("right", -1.0)):
            pan.add_geom(name=f"dustpan_wall_{side}", type=box, size=[PLATE_HALF[0], WALL_T, SIDE_WALL_H / 2],
                         pos=[0, sign * (PLATE_HALF[1] - WALL_T), PLATE_TOP + SIDE_WALL_H / 2],
                         mass=PAN_MASSES["side"], rgba=pan_rgba, **common)
        pan.add_geom(name="dustpan_wall_back", type=box, size=[WALL_T, PLATE_HALF[1], BACK_WALL_H / 2],
                     pos=[-PLATE_HALF[0] + WALL_T, 0, PLATE_TOP + BACK_WALL_H / 2],
                     mass=PAN_MASSES["back"], rgba=pan_rgba, **common)
        pan.add_geom(name="dustpan_handle", type=box, size=list(HANDLE_HALF), pos=list(HANDLE_POS),
                     mass=PAN_MASSES["handle"], rgba=[0.1, 0.3, 0.2, 1], **common)

        broom = spec.worldbody.add_body(name="broom", pos=[0.15, 0.05, 0.0])
        broom.add_freejoint(name="broom_joint")
        broom.add_geom(name="broom_head", type=box, size=list(HEAD_HALF), pos=[0, 0, HEAD_HALF[2]],
                       mass=BROOM_MASSES["head"], rgba=[0.85, 0.72, 0.35, 1], group=C.GROUP_OBJECT,
                       friction=list(BROOM_FRICTION), priority=1, condim=4,
                       contype=RAMP_PARTNER_BITS[0], conaffinity=RAMP_PARTNER_BITS[1])
        broom.add_geom(name="broom_stock", type=box, size=list(STOCK_HALF),
                       pos=[0, 0, 2 * HEAD_HALF[2] + STOCK_HALF[2]], mass=BROOM_MASSES["stock"],
                       rgba=[0.55, 0.33, 0.15, 1], group=C.GROUP_OBJECT, friction=list(BROOM_FRICTION))
        broom.add_geom(name="broom_handle", type=mujoco.mjtGeom.mjGEOM_CAPSULE,
                       fromto=[*BROOM_HANDLE_FROM, *BROOM_HANDLE_TO], size=[HANDLE_RADIUS, 0, 0],
                       mass=BROOM_MASSES["handle"], rgba=[0.2, 0.35, 0.75, 1], group=C.GROUP_OBJECT,
                       friction=[1.0, 0.01, 0.001], condim=4)

        target = spec.worldbody.add_body(name="target_object", pos=[0.0, 0.05, TARGET_HALF])
        target.add_freejoint(name="target_object_joint")
        target.add_geom(name="target_object_geom", type=box, size=[TARGET_HALF] * 3, mass=TARGET_MASS,
                        rgba=[0.9, 0.2, 0.15, 1], group=C.GROUP_OBJECT, friction=list(TARGET_FRICTION),
                        priority=1, condim=4, contype=RAMP_PARTNER_BITS[0], conaffinity=RAMP_PARTNER_BITS[1])

    # ------------------------------------------------------------------ bind
    def bind_objects(self, model: mujoco.MjModel) -> None:
        self.pan_body = model.body("dustpan").id
        self.broom_body = model.body("broom").id
        self.target_body = model.body("target_object").id
        self.pan_joint = model.joint("dustpan_joint").id
        self.broom_joint = model.joint("broom_joint").id
        self.target_joint = model.joint("target_object_joint").id
        self.pan_geoms = self.target_geoms["dustpan"]
        self.pan_handle_geoms = (model.geom("dustpan_handle").id,)
        self.broom_geoms = self.target_geoms["broom"]
        self.broom_head_geoms = (model.geom("broom_head").id, model.geom("broom_stock").id)
        self.object_geoms = self.target_geoms["target_object"]

    # ------------------------------------------------------------------ reset
    def initialize_episode(self, model, data, rng: np.random.Generator) -> None:
        target_xy = rng.uniform([TARGET_X[0], TARGET_Y[0]], [TARGET_X[1], TARGET_Y[1]])
        target_yaw = rng.uniform(*TARGET_YAW)
        side = 1.0 if rng.uniform() < 0.5 else -1.0
        pan_xy = target_xy + [rng.uniform(*PAN_DX), side * rng.uniform(*PAN_DY)]
        pan_yaw = rng.uniform(*PAN_YAW)
        broom_xy = target_xy + rng.uniform([BROOM_DX[0], BROOM_DY[0]], [BROOM_DX[1], BROOM_DY[1]])
        broom_yaw = rng.uniform(*BROOM_YAW)
        set_free_body_pose(model, data, self.target_joint, [*target_xy, TARGET_HALF], target_yaw)
        set_free_body_pose(model, data, self.pan_joint, [*pan_xy, 0.0], pan_yaw)
        set_free_body_pose(model, data, self.broom_joint, [*broom_xy, 0.0], broom_yaw)

    # ------------------------------------------------------------------ predicates
    def pan_frame(self, data) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Entrance-line centre (3,), horizontal entrance direction (2,) and lateral axis (2,)."""
        pos = data.xpos[self.pan_body]
        rot = data.xmat[self.pan_body].reshape(3, 3)
        fwd = rot[:2, 0] / max(np.linalg.norm(rot[:2, 0]), 1e-9)
        lat = np.array([-fwd[1], fwd[0]])
        entrance = pos + rot @ np.array([ENTRANCE_X, 0.0, 0.0])
        return entrance, fwd, lat

    def pan_tilt(self, data) -> float:
        return float(np.arccos(np.clip(data.xmat[self.pan_body].reshape(3, 3)[2, 2], -1.0, 1.0)))

    def target_in_pan_frame(self, data) -> tuple[float, float]:
        """Cube centre's (ahead of the entrance line, lateral offset from the pan axis), metres."""
        entrance, fwd, lat = self.pan_frame(data)
        d = data.xpos[self.target_body][:2] - entrance[:2]
        return float(d @ fwd), float(d @ lat)

    def evaluate(self, model, data) -> dict[str, bool]:
        pairs = contact_pairs(data)
        pan_speed, _ = free_body_speed(model, data, self.pan_joint)
        pan_flat = self.pan_tilt(data) < MAX_TILT and data.xpos[self.pan_body][2] < ON_TABLE_Z
        ahead, lateral = self.target_in_pan_frame(data)
        right_on_broom = touching(pairs, self.right.all, self.broom_geoms)
        in_corridor = CORRIDOR_AHEAD[0] <= ahead <= CORRIDOR_AHEAD[1] and abs(lateral) <= CORRIDOR_HALF_WIDTH
        in_pan = (
            BACK_INNER_X - ENTRANCE_X <= ahead <= -IN_PAN_DEPTH
            and abs(lateral) < INNER_HALF_WIDTH
            and data.xpos[self.target_body][2] < IN_PAN_MAX_Z
        )
        return {
            "m1": touching(pairs, self.left.all, self.pan_handle_geoms),
            "m2": bool(pan_flat and pan_speed < STILL_SPEED and in_corridor),
            "m3": right_on_broom,
            "m4": right_on_broom and touching(pairs, self.broom_head_geoms, self.object_geoms),
            "m5": bool(in_pan and pan_flat),
        }

    # ------------------------------------------------------------------ privileged state
    def view_points(self, model, data, depth: int) -> np.ndarray:
        head = data.xpos[self.broom_body]
        return np.stack([data.xpos[self.pan_body], head, data.xpos[self.target_body]])

"""Block Stacking: move the base block to the central workspace and stack the top block on it.

Task description:
    A flat 6 x 6 x 4 cm base block lies on the right half of the table and a 4.5 cm top block
    on the left half. A 12 x 12 cm square marker (visual only, no collision) shows the stacking
    region in the middle of the table. The right arm moves the base block into the stacking
    region and lets go; the left arm then lifts the top block above the base block and sets it
    down on it, so that the two blocks form a stable stack with both grippers released.

Objects (our own MjSpec boxes; grasps hold by pad friction only):
    base block: 6 x 6 x 4 cm box, 0.15 kg, friction 1.2 (sliding), blue;
    top block: 4.5 cm cube, 0.06 kg, friction 1.2, red;
    stacking region: 12 x 12 cm, 1 mm thick green square centred at (0.0, 0.0) m on the table
        top; contype = conaffinity = 0, geom group `GROUP_OBJECT` (rendered and counted as the
        "stacking_region" Stage-Occlusion target, never touched). The region is fixed: it *is*
        the central workspace, and the marker lies below the point cloud's 4 mm crop height,
        so a randomised region could not be perceived from the point cloud.

Randomisations (uniform, from the env's RNG only):
    base block centre x in [0.10, 0.20] m, y in [-0.08, 0.05] m, yaw in [-pi/6, pi/6] rad;
    top block centre x in [-0.20, -0.10] m, y in [-0.08, 0.05] m, yaw in [-pi/6, pi/6] rad.
    Both blocks start at rest on the table, outside the stacking region's tolerance.

Milestones (paper, App. A, Table "Task objectives and milestone progression"), all from
privileged state; contacts are checked by bound geom ids:
    M1 the right gripper contacts the base block (any right finger geom, pad or stem, touches it);
    M2 the base block is placed in the stacking region and released: its centre lies within
       4 cm (in x and in y) of the region centre, it is upright (tilt < 15 deg), it touches the
       table with its bottom below 5 mm, it is nearly still (< 0.05 m/s), and no finger of either
       gripper touches it;
    M3 the left gripper contacts the top block (any left finger geom touches it);
    M4 the top block is lifted into the pre-stacking region: the left gripper holds it (both
       left pads touch it) and it lies in the pre-stacking volume above the base block, i.e. its
       lowest point is 3 to 15 cm above the base block's highest point and its centre is within
       6 cm (horizontally) of the base block's centre, with the base block still in the region;
    M5 a stable stack is formed with both grippers released: the top block touches the base
       block and not the table, its lowest point is within 1 cm of the base block's top, its
       centre is within 2 cm (in the base block's own x and y) of the base block's axis, both
       blocks are upright and still (< 0.01 m/s, < 0.2 rad/s, so the landing rebound does not
       count), the base block is still placed in the region on the table, and no finger of
       either gripper touches either block.
       M5 is success.

Stage Occlusion targets (paper, App. A, Table "Stage Occlusion schedule"): base block, then the
top block after M2, then the stacking region after M4.

Episode length: the nominal expert finishes in about 390 control steps (16 s at 25 Hz); the
limit of 800 steps leaves room for camera-recovery pauses under occlusion (about 40 steps per
event, up to 7 events).
"""

from __future__ import annotations

import mujoco
import numpy as np

from lerobot_bavo.envs.tasks.base import (
    Task,
    contact_pairs,
    free_body_speed,
    holds,
    set_free_body_pose,
    touching,
)
from lerobot_bavo.sim import constants as C

BASE_HALF = (0.03, 0.03, 0.02)  # m, 6 x 6 x 4 cm
BASE_MASS = 0.15  # kg
TOP_HALF = (0.0225, 0.0225, 0.0225)  # m, 4.5 cm cube
TOP_MASS = 0.06  # kg
BLOCK_FRICTION = (1.2, 0.02, 0.002)

REGION_CENTER = (0.0, 0.0)  # m, centre of the stacking-region marker on the table
REGION_HALF = 0.06  # m, half side of the square marker
REGION_HALF_HEIGHT = 0.0005  # m
REGION_TOL = 0.04  # m, max |dx|, |dy| of the base block centre from the region centre

BASE_X = (0.10, 0.20)
BASE_Y = (-0.08, 0.05)
BASE_YAW = (-np.pi / 6, np.pi / 6)
TOP_X = (-0.20, -0.10)
TOP_Y = (-0.08, 0.05)
TOP_YAW = (-np.pi / 6, np.pi / 6)

ON_TABLE_HEIGHT = 0.005  # m, max height of the base block's lowest point when "on the table"
UPRIGHT_COS = float(np.cos(np.radians(15.0)))  # min cosine between a block's z axis and world z
PRESTACK_GAP = (0.03, 0.15)  # m, top-block bottom above the base-block top in the pre-stacking volume
PRESTACK_RADIUS = 0.06  # m, horizontal distance of the top block from the base block's axis
STACK_GAP_TOL = 0.01  # m, |top bottom - base top| for "resting on"
STACK_XY_TOL = 0.02  # m, top-block centre offset from the base block's axis (base frame x, y)
REST_SPEED = 0.05  # m/s, base block "placed" (M2)
# "Stable" (M5) is stricter: right after the top block lands it rebounds at a few cm/s while the
# contact is still compressed, and that instant must not count as a stack.
STABLE_SPEED = 0.01  # m/s
STABLE_ANGULAR_SPEED = 0.2  # rad/s


def box_z_extent(pos: np.ndarray, rot: np.ndarray, half) -> tuple[float, float]:
    """Lowest and highest z (m) of a box with centre `pos`, rotation `rot` and half sizes `half`."""
    reach = float(np.abs(rot[2]) @ np.asarray(half))
    return float(pos[2]) - reach, float(pos[2]) + reach


class BlockStacking(Task):
    name = "block_stacking"
    description = "Move the base block to the central workspace and stack the top block on it."
    max_episode_steps = 800
    stage_targets = ("base_block", "top_block", "stacking_region")
    stage_transitions = (2, 4)
    target_geom_names = {
        "base_block": ("base_block_geom",),
        "top_block": ("top_block_geom",),
        "stacking_region": ("stacking_region_geom",),
    }
    pose_bodies = {"base_block": "base_block", "top_block": "top_block"}
    order = 2

    def build(self, spec: mujoco.MjSpec) -> None:
        base = spec.worldbody.add_body(name="base_block", pos=[0.15, 0.04, BASE_HALF[2]])
        base.add_freejoint(name="base_block_joint")
        base.add_geom(name="base_block_geom", type=mujoco.mjtGeom.mjGEOM_BOX, size=list(BASE_HALF),
                      mass=BASE_MASS, rgba=[0.2, 0.4, 0.85, 1], group=C.GROUP_OBJECT,
                      friction=list(BLOCK_FRICTION), condim=4)
        top = spec.worldbody.add_body(name="top_block", pos=[-0.15, 0.04, TOP_HALF[2]])
        top.add_freejoint(name="top_block_joint")
        top.add_geom(name="top_block_geom", type=mujoco.mjtGeom.mjGEOM_BOX, size=list(TOP_HALF),
                     mass=TOP_MASS, rgba=[0.85, 0.15, 0.12, 1], group=C.GROUP_OBJECT,
                     friction=list(BLOCK_FRICTION), condim=4)
        spec.worldbody.add_geom(
            name="stacking_region_geom", type=mujoco.mjtGeom.mjGEOM_BOX,
            size=[REGION_HALF, REGION_HALF, REGION_HALF_HEIGHT],
            pos=[*REGION_CENTER, REGION_HALF_HEIGHT], rgba=[0.35, 0.72, 0.38, 1],
            group=C.GROUP_OBJECT, contype=0, conaffinity=0,
        )

    def bind_objects(self, model: mujoco.MjModel) -> None:
        self.base_body = model.body("base_block").id
        self.top_body = model.body("top_block").id
        self.base_joint = model.joint("base_block_joint").id
        self.top_joint = model.joint("top_block_joint").id
        self.base_geoms = self.target_geoms["base_block"]
        self.top_geoms = self.target_geoms["top_block"]
        self.region_geoms = self.target_geoms["stacking_region"]
        self.region_center = np.array([*REGION_CENTER, 0.0])

    def initialize_episode(self, model, data, rng: np.random.Generator) -> None:
        base_xy = rng.uniform([BASE_X[0], BASE_Y[0]], [BASE_X[1], BASE_Y[1]])
        base_yaw = rng.uniform(*BASE_YAW)
        top_xy = rng.uniform([TOP_X[0], TOP_Y[0]], [TOP_X[1], TOP_Y[1]])
        top_yaw = rng.uniform(*TOP_YAW)
        set_free_body_pose(model, data, self.base_joint, [*base_xy, BASE_HALF[2]], base_yaw)
        set_free_body_pose(model, data, self.top_joint, [*top_xy, TOP_HALF[2]], top_yaw)

    # ------------------------------------------------------------------ predicates
    def evaluate(self, model, data) -> dict[str, bool]:
        pairs = contact_pairs(data)
        base_pos, base_rot = data.xpos[self.base_body], data.xmat[self.base_body].reshape(3, 3)
        top_pos, top_rot = data.xpos[self.top_body], data.xmat[self.top_body].reshape(3, 3)
        base_low, base_high = box_z_extent(base_pos, base_rot, BASE_HALF)
        top_low, _ = box_z_extent(top_pos, top_rot, TOP_HALF)
        base_upright = base_rot[2, 2] > UPRIGHT_COS
        top_upright = top_rot[2, 2] > UPRIGHT_COS
        base_lin, base_ang = free_body_speed(model, data, self.base_joint)
        top_lin, top_ang = free_body_speed(model, data, self.top_joint)

        fingers = self.left.all | self.right.all
        base_touched = touching(pairs, fingers, self.base_geoms)
        top_touched = touching(pairs, fingers, self.top_geoms)

        offset = base_pos[:2] - self.region_center[:2]
        base_in_region = bool(np.all(np.abs(offset) <= REGION_TOL))
        base_on_table = touching(pairs, self.table_geoms, self.base_geoms) and base_low < ON_TABLE_HEIGHT
        base_placed = base_in_region and base_on_table and base_upright

        gap = top_low - base_high
        lateral = float(np.linalg.norm(top_pos[:2] - base_pos[:2]))
        in_prestack = PRESTACK_GAP[0] <= gap <= PRESTACK_GAP[1] and lateral <= PRESTACK_RADIUS

        top_in_base = base_rot.T @ (top_pos - base_pos)  # top-block centre in the base block's frame
        stacked = (
            touching(pairs, self.base_geoms, self.top_geoms)
            and not touching(pairs, self.table_geoms, self.top_geoms)
            and abs(gap) <= STACK_GAP_TOL
            and bool(np.all(np.abs(top_in_base[:2]) <= STACK_XY_TOL))
            and top_upright
        )
        still = (base_lin < STABLE_SPEED and base_ang < STABLE_ANGULAR_SPEED
                 and top_lin < STABLE_SPEED and top_ang < STABLE_ANGULAR_SPEED)
        return {
            "m1": touching(pairs, self.right.all, self.base_geoms),
            "m2": bool(base_placed and base_lin < REST_SPEED and not base_touched),
            "m3": touching(pairs, self.left.all, self.top_geoms),
            "m4": bool(holds(pairs, self.left, self.top_geoms) and in_prestack and base_in_region),
            "m5": bool(stacked and base_placed and still and not base_touched and not top_touched),
        }

    def view_points(self, model, data, depth: int) -> np.ndarray:
        return np.stack([data.xpos[self.base_body], data.xpos[self.top_body], self.region_center])

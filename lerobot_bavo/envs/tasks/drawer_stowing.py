"""Drawer Stowing: open the drawer, stow an object inside, and close the drawer.

Task description:
    A cabinet (20 x 17 x 11 cm, static boxes) stands at the back of the table, its front facing
    the operator (-y). It holds one drawer on a slide joint along -y (0 = closed, range 0..13 cm,
    damping 4 N s/m, friction loss 0.3 N). The drawer is an open box (inner 15.8 x 14.4 x 6.1 cm,
    floor top 1.9 cm above the table) behind a front panel that carries a bar handle (12 mm thick,
    9 cm long, 4.5 cm in front of the panel, 7.5 cm above the table). A 4 cm block lies on the
    left half of the table. The right arm grasps the handle and pulls the drawer open, the left
    arm picks the block and drops it into the open drawer, and the right arm pushes the drawer
    closed again.

Objects (our own MjSpec primitives):
    block: 4 x 4 x 4 cm box, 50 g, friction (1.2, 0.02, 0.002), condim 4;
    drawer: front panel, floor, two side walls, back wall and handle, 0.42 kg in all, friction 1;
    cabinet: a mocap body (static in the world during an episode; only its reset pose varies),
        whose contacts with the drawer are excluded (the slide joint alone guides the drawer).

Randomisations (uniform, from the env's RNG):
    cabinet front-edge centre x in [-0.03, 0.03] m, y in [0.09, 0.12] m (the drawer starts
    closed); block centre x in [-0.27, -0.17] m, y in [-0.10, 0.04] m, yaw in [-pi/4, pi/4] rad.
    The block always clears the opening drawer (>= 1.2 cm in x).

Milestones (paper, App. A, Table "Task objectives and milestone progression"):
    M1 the right gripper contacts the drawer handle (a right finger geom touches the bar or a
       post);
    M2 the drawer is opened (slide >= 8 cm);
    M3 the left gripper contacts the block (a left finger geom touches it);
    M4 the block is placed and released inside the drawer (its centre inside the drawer's inner
       box, resting on the drawer floor, speed < 5 cm/s, no finger of either gripper on it);
    M5 the drawer is closed with the block remaining inside (slide <= 1 cm, block centre inside
       the inner box and on the drawer floor, no finger on it). M5 is success.

Stage Occlusion targets: drawer front (panel + handle), then the block after M2, then the drawer
front after M3.

Episode length: the nominal scripted expert succeeds in about 390 control steps; with up to seven
occlusion events of about 40 recovery steps each that is about 670, so the limit is 800.
"""

from __future__ import annotations

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

# ---- block -----------------------------------------------------------------------------------
BLOCK_HALF = 0.02  # m
BLOCK_MASS = 0.05  # kg
BLOCK_FRICTION = (1.2, 0.02, 0.002)

# ---- cabinet (frame: origin at the centre of its front edge on the table, x right, y back) ----
CAB_HALF_W = 0.10  # outer half width (x)
CAB_DEPTH = 0.17  # outer depth (y)
CAB_HEIGHT = 0.11
CAB_WALL = 0.01  # wall / plate thickness (top plate 12 mm)
CAB_TOP_THICK = 0.012

# ---- drawer (frame: coincides with the cabinet frame when closed; slides along -y) ------------
PANEL_THICK = 0.012  # front panel, in front of the cabinet (y in [-0.012, 0])
PANEL_Z = (0.012, 0.090)
BOX_HALF_W = 0.085  # outer half width of the drawer box
BOX_DEPTH = 0.15
BOX_WALL = 0.006
FLOOR_Z = (0.013, 0.019)
WALL_TOP = 0.080
# Inner box (drawer frame): where the block must be.
INNER_X = BOX_HALF_W - BOX_WALL  # |x| <= 0.079
INNER_Y = (0.0, BOX_DEPTH - BOX_WALL)  # 0 .. 0.144
INNER_Z = (FLOOR_Z[1], WALL_TOP)  # 0.019 .. 0.080
HANDLE_STANDOFF = 0.045  # bar axis in front of the panel's front face
HANDLE_Z = 0.075
HANDLE_RADIUS = 0.006
HANDLE_HALF_LEN = 0.045
HANDLE_POST_X = 0.038
HANDLE_Y = -PANEL_THICK - HANDLE_STANDOFF  # bar axis y in the drawer frame (-0.057)

SLIDE_RANGE = (0.0, 0.13)  # m
SLIDE_DAMPING = 4.0  # N s / m
SLIDE_FRICTIONLOSS = 0.3  # N
OPEN_SLIDE = 0.08  # "opened" threshold, m
CLOSED_SLIDE = 0.01  # "closed" threshold, m

# ---- reset distribution ------------------------------------------------------------------------
CABINET_X = (-0.03, 0.03)
CABINET_Y = (0.09, 0.12)
BLOCK_X = (-0.27, -0.17)
BLOCK_Y = (-0.10, 0.04)
BLOCK_YAW = (-np.pi / 4, np.pi / 4)

REST_SPEED = 0.05  # m/s

_WOOD = (0.55, 0.38, 0.22, 1.0)
_WOOD_DARK = (0.45, 0.3, 0.17, 1.0)
_FRONT = (0.85, 0.78, 0.55, 1.0)
_METAL = (0.7, 0.72, 0.75, 1.0)


def _box(body, name: str, lo, hi, rgba, mass: float | None = None, group: int = C.GROUP_OBJECT):
    """Add a box geom spanning the axis-aligned corners `lo`..`hi` (body frame, m)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    kwargs = {"mass": mass} if mass is not None else {}
    return body.add_geom(name=name, type=mujoco.mjtGeom.mjGEOM_BOX, size=list((hi - lo) / 2),
                         pos=list((hi + lo) / 2), rgba=list(rgba), group=group, **kwargs)


class DrawerStowing(Task):
    name = "drawer_stowing"
    description = "Open the drawer, stow the block inside, and close the drawer."
    max_episode_steps = 800
    stage_targets = ("drawer_front", "object", "drawer_front")
    stage_transitions = (2, 3)
    target_geom_names = {
        "drawer_front": ("drawer_panel", "drawer_handle", "drawer_handle_post_0", "drawer_handle_post_1"),
        "object": ("block_geom",),
    }
    pose_bodies = {"block": "block", "drawer": "drawer", "cabinet": "cabinet"}
    order = 3

    def build(self, spec: mujoco.MjSpec) -> None:
        world = spec.worldbody
        cab = world.add_body(name="cabinet", pos=[0.0, 0.105, 0.0], mocap=True)
        w, d, h, t = CAB_HALF_W, CAB_DEPTH, CAB_HEIGHT, CAB_WALL
        _box(cab, "cabinet_bottom", [-w, 0, 0], [w, d, t], _WOOD)
        _box(cab, "cabinet_top", [-w, 0, h - CAB_TOP_THICK], [w, d, h], _WOOD)
        _box(cab, "cabinet_side_l", [-w, 0, t], [-w + t, d, h - CAB_TOP_THICK], _WOOD)
        _box(cab, "cabinet_side_r", [w - t, 0, t], [w, d, h - CAB_TOP_THICK], _WOOD)
        _box(cab, "cabinet_back", [-w + t, d - t, t], [w - t, d, h - CAB_TOP_THICK], _WOOD_DARK)

        drawer = cab.add_body(name="drawer", pos=[0, 0, 0])
        drawer.add_joint(name="drawer_slide", type=mujoco.mjtJoint.mjJNT_SLIDE, axis=[0, -1, 0],
                         range=list(SLIDE_RANGE), limited=mujoco.mjtLimited.mjLIMITED_TRUE,
                         damping=SLIDE_DAMPING, frictionloss=SLIDE_FRICTIONLOSS, armature=0.05)
        bw, bd, bt = BOX_HALF_W, BOX_DEPTH, BOX_WALL
        _box(drawer, "drawer_panel", [-w, -PANEL_THICK, PANEL_Z[0]], [w, 0, PANEL_Z[1]], _FRONT, 0.15)
        _box(drawer, "drawer_floor", [-bw, 0, FLOOR_Z[0]], [bw, bd, FLOOR_Z[1]], _WOOD, 0.10)
        _box(drawer, "drawer_side_l", [-bw, 0, FLOOR_Z[1]], [-bw + bt, bd, WALL_TOP], _WOOD, 0.04)
        _box(drawer, "drawer_side_r", [bw - bt, 0, FLOOR_Z[1]], [bw, bd, WALL_TOP], _WOOD, 0.04)
        _box(drawer, "drawer_back", [-bw + bt, bd - bt, FLOOR_Z[1]], [bw - bt, bd, WALL_TOP], _WOOD, 0.04)
        drawer.add_geom(name="drawer_handle", type=mujoco.mjtGeom.mjGEOM_CAPSULE,
                        fromto=[-HANDLE_HALF_LEN, HANDLE_Y, HANDLE_Z, HANDLE_HALF_LEN, HANDLE_Y, HANDLE_Z],
                        size=[HANDLE_RADIUS, 0, 0], mass=0.03, rgba=list(_METAL), group=C.GROUP_OBJECT)
        for i, sx in enumerate((-1, 1)):
            drawer.add_geom(
                name=f"drawer_handle_post_{i}",
                type=mujoco.mjtGeom.mjGEOM_CAPSULE,
                fromto=[sx * HANDLE_POST_X, -PANEL_THICK, HANDLE_Z, sx * HANDLE_POST_X, HANDLE_Y, HANDLE_Z],
                size=[0.005, 0, 0],
                mass=0.01,
                rgba=list(_METAL),
                group=C.GROUP_OBJECT,
            )
        spec.add_exclude(name="cabinet_drawer", bodyname1="cabinet", bodyname2="drawer")

        block = world.add_body(name="block", pos=[-0.22, -0.03, BLOCK_HALF])
        block.add_freejoint(name="block_joint")
        block.add_geom(name="block_geom", type=mujoco.mjtGeom.mjGEOM_BOX, size=[BLOCK_HALF] * 3,
                       mass=BLOCK_MASS, rgba=[0.15, 0.65, 0.25, 1], group=C.GROUP_OBJECT,
                       friction=list(BLOCK_FRICTION), condim=4)

    def bind_objects(self, model: mujoco.MjModel) -> None:
        self.cabinet_body = model.body("cabinet").id
        self.cabinet_mocap = int(model.body_mocapid[self.cabinet_body])
        self.drawer_body = model.body("drawer").id
        self.block_body = model.body("block").id
        self.block_joint = model.joint("block_joint").id
        slide = model.joint("drawer_slide").id
        self.slide_qadr = int(model.jnt_qposadr[slide])
        self.slide_dof = int(model.jnt_dofadr[slide])
        self.block_geoms = self.target_geoms["object"]
        self.handle_geoms = tuple(
            model.geom(n).id for n in ("drawer_handle", "drawer_handle_post_0", "drawer_handle_post_1")
        )
        self.panel_geoms = (model.geom("drawer_panel").id,)
        self.floor_geoms = (model.geom("drawer_floor").id,)

    def initialize_episode(self, model, data, rng: np.random.Generator) -> None:
        cab_xy = rng.uniform([CABINET_X[0], CABINET_Y[0]], [CABINET_X[1], CABINET_Y[1]])
        block_xy = rng.uniform([BLOCK_X[0], BLOCK_Y[0]], [BLOCK_X[1], BLOCK_Y[1]])
        block_yaw = rng.uniform(*BLOCK_YAW)
        data.mocap_pos[self.cabinet_mocap] = [cab_xy[0], cab_xy[1], 0.0]
        data.mocap_quat[self.cabinet_mocap] = [1.0, 0.0, 0.0, 0.0]
        data.qpos[self.slide_qadr] = 0.0
        data.qvel[self.slide_dof] = 0.0
        set_free_body_pose(model, data, self.block_joint, [*block_xy, BLOCK_HALF], block_yaw)

    # ---- privileged state ----------------------------------------------------------------------
    def slide(self, data) -> float:
        """Drawer opening in metres (0 = closed)."""
        return float(data.qpos[self.slide_qadr])

    def block_in_drawer_frame(self, data) -> np.ndarray:
        R = data.xmat[self.drawer_body].reshape(3, 3)
        return R.T @ (data.xpos[self.block_body] - data.xpos[self.drawer_body])

    def block_inside(self, data) -> bool:
        p = self.block_in_drawer_frame(data)
        return bool(
            abs(p[0]) <= INNER_X and INNER_Y[0] <= p[1] <= INNER_Y[1] and INNER_Z[0] <= p[2] <= INNER_Z[1]
        )

    def handle_pos(self, data) -> np.ndarray:
        """World position of the middle of the handle bar."""
        R = data.xmat[self.drawer_body].reshape(3, 3)
        return data.xpos[self.drawer_body] + R @ np.array([0.0, HANDLE_Y, HANDLE_Z])

    def interior_opening(self, data) -> tuple[np.ndarray, np.ndarray]:
        """World-frame xy corners (lo, hi) of the part of the drawer's inner box that sticks out of
        the cabinet (the part the block can be dropped into)."""
        drawer = data.xpos[self.drawer_body]
        front_edge = data.xpos[self.cabinet_body][1]
        lo = np.array([drawer[0] - INNER_X, drawer[1] + INNER_Y[0]])
        hi = np.array([drawer[0] + INNER_X, min(front_edge, drawer[1] + INNER_Y[1])])
        return lo, hi

    def evaluate(self, model, data) -> dict[str, bool]:
        pairs = contact_pairs(data)
        slide = self.slide(data)
        left_touch = touching(pairs, self.left.all, self.block_geoms)
        right_touch = touching(pairs, self.right.all, self.block_geoms)
        released = not left_touch and not right_touch
        inside = self.block_inside(data)
        on_floor = touching(pairs, self.floor_geoms, self.block_geoms)
        speed, _ = free_body_speed(model, data, self.block_joint)
        return {
            "m1": touching(pairs, self.right.all, self.handle_geoms),
            "m2": slide >= OPEN_SLIDE,
            "m3": left_touch,
            "m4": bool(inside and on_floor and released and speed < REST_SPEED),
            "m5": bool(slide <= CLOSED_SLIDE and inside and on_floor and released),
        }

    def view_points(self, model, data, depth: int) -> np.ndarray:
        front = data.xpos[self.drawer_body] + np.array([0.0, -PANEL_THICK, 0.5 * (PANEL_Z[0] + PANEL_Z[1])])
        return np.stack([front, data.xpos[self.block_body]])

"""Cube Handoff: hand a cube from the right arm to the left arm and place it on the target plate.

Task description:
    A 5 cm cube lies on the right half of the table and a round plate on the left half. The
    right arm picks the cube up, hands it over to the left arm above the middle of the table,
    and the left arm places it on the plate.

Randomisations (uniform, from the env's RNG):
    cube centre x in [0.08, 0.20] m, y in [-0.04, 0.12] m, yaw in [-pi/6, pi/6] rad;
    plate centre x in [-0.20, -0.10] m, y in [-0.04, 0.12] m.

Milestones (paper, App. A, Table "Task objectives and milestone progression"):
    M1 the right gripper contacts the cube;
    M2 the right arm lifts the cube (right grasp, cube bottom >= 3 cm above the table);
    M3 both grippers hold the cube (both pads of each gripper touch it) during the handoff;
    M4 the left gripper takes over and the right releases (left grasp, no right-finger contact,
       cube off the table);
    M5 the left arm places the cube on the plate (cube centre within the plate radius, resting on
       the plate top, nearly still, left fingers released). M5 is success.

Stage Occlusion targets: cube, then cube after M2, then plate after M4.
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

CUBE_HALF = 0.025  # m
CUBE_MASS = 0.08  # kg
PLATE_RADIUS = 0.07  # m
PLATE_HALF_HEIGHT = 0.005  # m
PLATE_MASS = 0.3  # kg

CUBE_X = (0.08, 0.20)
CUBE_Y = (-0.04, 0.12)
CUBE_YAW = (-np.pi / 6, np.pi / 6)
PLATE_X = (-0.20, -0.10)
PLATE_Y = (-0.04, 0.12)

LIFT_HEIGHT = 0.03  # m of clearance between cube bottom and table for "lifted"
REST_SPEED = 0.05  # m/s


class CubeHandoff(Task):
    name = "cube_handoff"
    description = "Hand the cube from the right arm to the left arm and place it on the plate."
    max_episode_steps = 800  # nominal expert ~345 steps; room for camera recovery under occlusion
    stage_targets = ("cube", "cube", "plate")
    stage_transitions = (2, 4)
    target_geom_names = {"cube": ("cube_geom",), "plate": ("plate_geom",)}
    pose_bodies = {"cube": "cube", "plate": "plate"}
    order = 1

    def build(self, spec: mujoco.MjSpec) -> None:
        cube = spec.worldbody.add_body(name="cube", pos=[0.15, 0.05, CUBE_HALF])
        cube.add_freejoint(name="cube_joint")
        cube.add_geom(name="cube_geom", type=mujoco.mjtGeom.mjGEOM_BOX, size=[CUBE_HALF] * 3,
                      mass=CUBE_MASS, rgba=[0.85, 0.15, 0.12, 1], group=C.GROUP_OBJECT,
                      friction=[1.2, 0.02, 0.002], condim=4)
        plate = spec.worldbody.add_body(name="plate", pos=[-0.15, 0.05, PLATE_HALF_HEIGHT])
        plate.add_freejoint(name="plate_joint")
        plate.add_geom(name="plate_geom", type=mujoco.mjtGeom.mjGEOM_CYLINDER,
                       size=[PLATE_RADIUS, PLATE_HALF_HEIGHT, 0], mass=PLATE_MASS,
                       rgba=[0.2, 0.45, 0.85, 1], group=C.GROUP_OBJECT, friction=[1.0, 0.01, 0.001])

    def bind_objects(self, model: mujoco.MjModel) -> None:
        self.cube_body = model.body("cube").id
        self.plate_body = model.body("plate").id
        self.cube_joint = model.joint("cube_joint").id
        self.plate_joint = model.joint("plate_joint").id
        self.cube_geoms = self.target_geoms["cube"]
        self.plate_geoms = self.target_geoms["plate"]

    def initialize_episode(self, model, data, rng: np.random.Generator) -> None:
        cube_xy = rng.uniform([CUBE_X[0], CUBE_Y[0]], [CUBE_X[1], CUBE_Y[1]])
        cube_yaw = rng.uniform(*CUBE_YAW)
        plate_xy = rng.uniform([PLATE_X[0], PLATE_Y[0]], [PLATE_X[1], PLATE_Y[1]])
        set_free_body_pose(model, data, self.cube_joint, [*cube_xy, CUBE_HALF], cube_yaw)
        set_free_body_pose(model, data, self.plate_joint, [*plate_xy, PLATE_HALF_HEIGHT], 0.0)

    def evaluate(self, model, data) -> dict[str, bool]:
        pairs = contact_pairs(data)
        cube_pos = data.xpos[self.cube_body]
        plate_pos = data.xpos[self.plate_body]
        cube_bottom = cube_pos[2] - CUBE_HALF  # approximate: the cube stays nearly upright
        right_touch = touching(pairs, self.right.all, self.cube_geoms)
        left_touch = touching(pairs, self.left.all, self.cube_geoms)
        right_hold = holds(pairs, self.right, self.cube_geoms)
        left_hold = holds(pairs, self.left, self.cube_geoms)
        off_table = not touching(pairs, self.table_geoms, self.cube_geoms) and cube_bottom > 0.01
        speed, _ = free_body_speed(model, data, self.cube_joint)
        plate_top = plate_pos[2] + PLATE_HALF_HEIGHT
        on_plate = (
            np.linalg.norm(cube_pos[:2] - plate_pos[:2]) < PLATE_RADIUS
            and abs(cube_bottom - plate_top) < 0.01
            and touching(pairs, self.plate_geoms, self.cube_geoms)
        )
        return {
            "m1": bool(right_touch),
            "m2": bool(right_hold and cube_bottom >= LIFT_HEIGHT),
            "m3": bool(right_hold and left_hold and off_table),
            "m4": bool(left_hold and not right_touch and off_table),
            "m5": bool(on_plate and speed < REST_SPEED and not left_touch and not right_touch),
        }

    def view_points(self, model, data, depth: int) -> np.ndarray:
        return np.stack([data.xpos[self.cube_body], data.xpos[self.plate_body]])

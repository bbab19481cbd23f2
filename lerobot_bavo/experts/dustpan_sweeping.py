"""Scripted expert for Dustpan Sweeping.

Phases: Left reach (top-down above the dustpan handle) -> Left descend -> Left grasp ->
Align (turn the pan to face +x and back it off) -> Slide (sideways into the cube's sweep line)
-> Advance (entrance 3.5 cm behind the cube) -> Right reach (top-down above the broom handle)
-> Right descend -> Right grasp -> Pre-sweep (turn the broom perpendicular to the pan's axis,
head behind the cube) -> Sweep (push the cube across the entrance) -> Hold.
The left arm keeps holding the pan while the right arm sweeps. Every phase recomputes its
targets from the objects' actual poses; held objects are moved by moving the gripper with the
grasp transform measured when the phase starts (objects slide on the table, never lifted).
"""

from __future__ import annotations

import numpy as np

from lerobot_bavo.envs.tasks.dustpan_sweeping import (
    BROOM_HANDLE_FROM,
    BROOM_HANDLE_TO,
    ENTRANCE_X,
    HANDLE_POS,
    HEAD_HALF,
    TARGET_HALF,
)
from lerobot_bavo.experts.base import ScriptedExpert
from lerobot_bavo.sim.transforms import rot_z, topdown_rot, yaw_of

PAN_GRASP = np.array([HANDLE_POS[0], 0.0, HANDLE_POS[2]])  # gripper centre in the pan frame
BROOM_GRASP_X = 0.075  # m along the broom handle from the head centre
_t = (BROOM_GRASP_X - BROOM_HANDLE_FROM[0]) / (BROOM_HANDLE_TO[0] - BROOM_HANDLE_FROM[0])
BROOM_GRASP = np.array(
    [BROOM_GRASP_X, 0.0, BROOM_HANDLE_FROM[2] + _t * (BROOM_HANDLE_TO[2] - BROOM_HANDLE_FROM[2])]
)
APPROACH_HEIGHT = 0.08  # m above the grasp point before descending
PAN_GAP = 0.035  # m, cube centre ahead of the entrance line once the pan is placed
PAN_BACKOFF = 0.03  # m, extra distance kept while the pan slides sideways
BROOM_GAP = 0.02  # m between the broom head and the cube before the sweep
SWEEP_DEPTH = 0.03  # m, cube centre pushed this far past the entrance line


def planar_pose(pos, yaw: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = rot_z(yaw)
    T[:3, 3] = pos
    return T


class DustpanSweepingExpert(ScriptedExpert):
    task_name = "dustpan_sweeping"
    contact_phases = frozenset({"left_descend", "left_grasp", "advance", "right_descend", "right_grasp",
                                "pre_sweep", "sweep"})

    # -- helpers ----------------------------------------------------------------------------
    def object_pose(self, name: str) -> np.ndarray:
        return planar_pose(self.body_pos(name), yaw_of(self.body_rot(name)))

    def carry(self, arm, body: str, goal_xy, goal_yaw: float, steps: int, phase: str):
        """Slide a held object so its body frame reaches (goal_xy, goal_yaw) on the table."""
        obj = self.object_pose(body)
        grip = np.eye(4)
        grip[:3, :3] = arm.rot
        grip[:3, 3] = arm.pos
        rel = np.linalg.inv(obj) @ grip  # commanded gripper pose in the object's frame
        goal = planar_pose([goal_xy[0], goal_xy[1], obj[2, 3]], goal_yaw) @ rel
        target = (goal[:3, 3], goal[:3, :3])
        yield from self.move(steps, **{"left" if arm is self.left else "right": target}, phase=phase)

    # -- script -----------------------------------------------------------------------------
    def script(self):
        # Left arm: grasp the dustpan handle from above.
        pan = self.object_pose("dustpan")
        pan_yaw = yaw_of(pan[:3, :3])
        l_rot = topdown_rot([0.0, 1.0, 0.0], pan_yaw)
        grasp = (pan @ np.append(PAN_GRASP, 1.0))[:3]
        yield from self.move(45, left=(grasp + [0, 0, APPROACH_HEIGHT], l_rot), phase="left_reach")
        yield from self.move(25, left=(grasp, l_rot), phase="left_descend")
        yield from self.grip(12, left=0.0, phase="left_grasp")
        yield from self.wait(5)

        # Drag the pan: face +x and back off, slide into the sweep line, advance.
        cube = self.body_pos("target_object")
        goal_x = cube[0] - PAN_GAP - ENTRANCE_X
        pan_pos = self.body_pos("dustpan")
        yield from self.carry(self.left, "dustpan", (goal_x - PAN_BACKOFF, pan_pos[1]), 0.0, 35, "align")
        yield from self.carry(self.left, "dustpan", (goal_x - PAN_BACKOFF, cube[1]), 0.0, 45, "slide")
        cube = self.body_pos("target_object")
        yield from self.carry(self.left, "dustpan", (cube[0] - PAN_GAP - ENTRANCE_X, cube[1]), 0.0, 25,
                              "advance")
        yield from self.wait(10, phase="pan_settle")

        # Right arm: grasp the broom handle from above.
        broom = self.object_pose("broom")
        r_rot = topdown_rot([0.0, -1.0, 0.0], yaw_of(broom[:3, :3]))
        grasp = (broom @ np.append(BROOM_GRASP, 1.0))[:3]
        yield from self.move(45, right=(grasp + [0, 0, APPROACH_HEIGHT], r_rot), phase="right_reach")
        yield from self.move(25, right=(grasp, r_rot), phase="right_descend")
        yield from self.grip(12, right=0.0, phase="right_grasp")
        yield from self.wait(5)

        # Sweep along the pan's axis: head perpendicular to it, behind the cube, then push.
        pan = self.object_pose("dustpan")
        fwd = pan[:2, 0]
        entrance = (pan @ np.array([ENTRANCE_X, 0.0, 0.0, 1.0]))[:2]
        cube = self.body_pos("target_object")
        ahead = float((cube[:2] - entrance) @ fwd)
        yaw = yaw_of(pan[:3, :3])
        behind = ahead + np.sqrt(2) * TARGET_HALF + BROOM_GAP + HEAD_HALF[0]
        yield from self.carry(self.right, "broom", entrance + behind * fwd, yaw, 40, "pre_sweep")
        end = -SWEEP_DEPTH + TARGET_HALF + HEAD_HALF[0]
        yield from self.carry(self.right, "broom", entrance + end * fwd, yaw, 60, "sweep")
        yield from self.wait(40, phase="hold")

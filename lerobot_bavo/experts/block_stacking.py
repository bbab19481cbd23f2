"""Scripted expert for Block Stacking.

Phases: Right reach (top-down, fingers across the base block's faces closest to the world x
axis) -> Descend -> Grasp -> Lift -> Carry over the stacking region (turning the block to yaw 0)
-> Lower -> Release -> Right lift-off, then the right arm moves aside while the left arm reaches
above the top block -> Left descend -> Left grasp -> Lift -> Carry into the pre-stacking volume
6 cm above the base block (turning the top block to the base block's yaw) -> Lower onto the base
block -> Release -> Retreat. Targets are recomputed from the blocks' actual poses at the start of
each phase, and the in-hand offsets (block centre in the gripper frame) are measured after each
grasp, so the released block lands where intended.
"""

from __future__ import annotations

import numpy as np

from lerobot_bavo.envs.tasks.block_stacking import BASE_HALF, REGION_CENTER, TOP_HALF
from lerobot_bavo.experts.base import ScriptedExpert
from lerobot_bavo.sim.transforms import face_yaw, rot_z, topdown_rot

# Gripper centre minus block centre for the top-down grasps, in the block's yaw frame (m).
RIGHT_GRASP_OFFSET = np.array([0.0, 0.0, 0.006])
LEFT_GRASP_OFFSET = np.array([0.0, 0.0, 0.006])
APPROACH_HEIGHT = 0.09  # m above the grasp pose before descending
CARRY_CLEARANCE = 0.07  # m, base block bottom above the table while carried
PLACE_DROP = 0.004  # m, height of a block's bottom above its support when released
RIGHT_LIFT_OFF = 0.07  # m, right gripper rise after releasing the base block
RIGHT_ASIDE = np.array([0.14, 0.0, 0.03])  # m, then its move out of the left arm's way
PRESTACK_GAP = 0.06  # m, top block bottom above the base block top in the pre-stacking pose


# Top-down grasps close the fingers along world x (turned by the block's face yaw): the pads go on the
# blocks' left and right faces as the active camera (at -y) sees them, so the grasped block's front
# face stays visible.
CLOSING = {"left": (1.0, 0.0, 0.0), "right": (-1.0, 0.0, 0.0)}


class BlockStackingExpert(ScriptedExpert):
    task_name = "block_stacking"
    contact_phases = frozenset({"descend", "grasp", "lower", "release", "left_descend", "left_grasp", "stack",
                                "left_release"})

    def in_hand(self, side: str, body: str) -> np.ndarray:
        """Block centre in the gripper-centre frame (m), measured from the simulator."""
        site = self.env.data.site(f"{side}_gripper_center")
        return site.xmat.reshape(3, 3).T @ (self.body_pos(body) - site.xpos)

    @staticmethod
    def gripper_target(block_target, rot: np.ndarray, in_hand: np.ndarray) -> np.ndarray:
        """Gripper-centre position that puts a held block's centre at `block_target`."""
        return np.asarray(block_target, float) - rot @ in_hand

    def script(self):
        # ---- right arm: base block -> stacking region --------------------------------------
        base = self.body_pos("base_block")
        yaw = face_yaw(self.body_rot("base_block"))
        r_down = topdown_rot(CLOSING["right"], yaw)
        grasp = base + rot_z(yaw) @ RIGHT_GRASP_OFFSET
        yield from self.move(45, right=(grasp + [0, 0, APPROACH_HEIGHT], r_down), phase="reach")
        yield from self.move(25, right=(grasp, r_down), phase="descend")
        yield from self.grip(12, right=0.0, phase="grasp")
        yield from self.wait(4)
        yield from self.move(20, right=(grasp + [0, 0, CARRY_CLEARANCE], r_down), phase="lift")

        r_place = topdown_rot(CLOSING["right"], 0.0)
        place = np.array([*REGION_CENTER, BASE_HALF[2] + PLACE_DROP])
        hand = self.in_hand("right", "base_block")
        above = self.gripper_target(place + [0, 0, CARRY_CLEARANCE], r_place, hand)
        yield from self.move(40, right=(above, r_place), phase="carry")
        hand = self.in_hand("right", "base_block")
        yield from self.move(25, right=(self.gripper_target(place, r_place, hand), r_place), phase="lower")
        yield from self.grip(10, right=1.0, phase="release")

        # ---- left arm: top block -> pre-stacking volume -> stack -----------------------------
        top = self.body_pos("top_block")
        t_yaw = face_yaw(self.body_rot("top_block"))
        l_down = topdown_rot(CLOSING["left"], t_yaw)
        l_grasp = top + rot_z(t_yaw) @ LEFT_GRASP_OFFSET
        # The right pads straddle the base block along x: lift them clear before moving aside.
        r_up = self.right.pos + [0.0, 0.0, RIGHT_LIFT_OFF]
        yield from self.move(15, right=(r_up, self.right.rot), phase="right_lift_off")
        yield from self.move(40, left=(l_grasp + [0, 0, APPROACH_HEIGHT], l_down),
                             right=(r_up + RIGHT_ASIDE, self.right.rot), phase="left_reach")
        yield from self.move(25, left=(l_grasp, l_down), phase="left_descend")
        yield from self.grip(12, left=0.0, phase="left_grasp")
        yield from self.wait(4)
        yield from self.move(20, left=(l_grasp + [0, 0, 0.10], l_down), phase="left_lift")

        base = self.body_pos("base_block")
        b_yaw = face_yaw(self.body_rot("base_block"))
        l_stack = topdown_rot(CLOSING["left"], b_yaw)
        base_top = base[2] + BASE_HALF[2]
        pre = np.array([base[0], base[1], base_top + PRESTACK_GAP + TOP_HALF[2]])
        hand = self.in_hand("left", "top_block")
        yield from self.move(45, left=(self.gripper_target(pre, l_stack, hand), l_stack), phase="prestack")
        yield from self.wait(6)
        hand = self.in_hand("left", "top_block")
        stack = np.array([base[0], base[1], base_top + PLACE_DROP + TOP_HALF[2]])
        yield from self.move(30, left=(self.gripper_target(stack, l_stack, hand), l_stack), phase="stack")
        yield from self.grip(10, left=1.0, phase="left_release")
        yield from self.move(25, left=(self.left.pos + [0, 0, 0.08], l_stack), phase="retreat")
        yield from self.wait(20, phase="done")

"""Scripted expert for Drawer Stowing.

Phases: Reach (right, top-down above the handle bar, fingers half open) -> Descend -> Grasp the
bar -> Pull the drawer open 11 cm (the left arm moves above the block meanwhile) -> Right release
(the right arm then parks out of the camera's way) -> Left descend -> Left grasp -> Lift -> Carry
over the part of the drawer outside the cabinet (turning the fingers to close along the drawer's
width) -> Lower -> Release (a 3 cm drop onto the drawer floor) -> Left retreat (up and to the
left) -> Right reach, descend and grasp the bar again -> Push the drawer closed -> Right release
and retreat. Targets are recomputed from the handle's, the block's and the drawer's actual poses
at the start of each phase. Nominal length: 397 control steps.
"""

from __future__ import annotations

import numpy as np

from lerobot_bavo.envs.tasks.drawer_stowing import BLOCK_HALF, FLOOR_Z
from lerobot_bavo.experts.base import ScriptedExpert
from lerobot_bavo.sim.transforms import face_yaw, rot_z, topdown_rot

HANDLE_OPENING = 0.45  # gripper command while straddling the bar (pad gap 35 mm, bar 12 mm)
PULL = 0.11  # m, how far the drawer is pulled open
BLOCK_GRASP_OFFSET = np.array([0.0, 0.0, 0.008])  # gripper centre minus block centre (top-down)
CARRY_Z = 0.17  # m, block centre height while carrying over the cabinet front
DROP_Z = FLOOR_Z[1] + BLOCK_HALF + 0.029  # m, block centre at release: 2.9 cm above the floor
RELEASE_OPENING = 0.7
LEFT_CLOSING = np.array([1.0, 0.0, 0.0])  # left finger closing axis over the drawer (world x)
RIGHT_PARK = np.array([0.24, -0.06, 0.20])  # right gripper while the left arm stows the block


class DrawerStowingExpert(ScriptedExpert):
    task_name = "drawer_stowing"
    # the right arm's handle grasps, releases and push, the left arm's block descent, grasp, lowering and
    # release; not the pull (the left arm's approach to above the block happens then)
    contact_phases = frozenset({"descend_handle", "grasp_handle", "right_release", "descend_block",
                                "grasp_block", "lower", "release", "descend_handle_again",
                                "grasp_handle_again", "push_closed"})

    def script(self):
        task = self.env.task
        data = self.env.data

        # -- right arm: grasp the handle bar from above, fingers closing along the drawer axis.
        r_rot = topdown_rot([0.0, -1.0, 0.0])
        handle = task.handle_pos(data)
        yield from self.move(40, right=(handle + [0, 0, 0.09], r_rot), phase="reach_handle")
        yield from self.grip(6, right=HANDLE_OPENING)
        handle = task.handle_pos(data)
        yield from self.move(22, right=(handle, r_rot), phase="descend_handle")
        yield from self.grip(10, right=0.0, phase="grasp_handle")
        yield from self.wait(3)

        # -- pull the drawer open; the left arm goes above the block meanwhile.
        block = self.body_pos("block")
        yaw = face_yaw(self.body_rot("block"))
        l_rot = topdown_rot(LEFT_CLOSING, yaw)
        grasp = block + rot_z(yaw) @ BLOCK_GRASP_OFFSET
        pull_to = self.right.pos + [0.0, -PULL, 0.0]
        yield from self.move(
            40, right=(pull_to, r_rot), left=(grasp + [0, 0, 0.10], l_rot), phase="pull_open"
        )
        yield from self.wait(4)
        # -- let go of the bar and park the right arm out of the camera's way.
        yield from self.grip(8, right=HANDLE_OPENING, phase="right_release")
        yield from self.move(8, right=(self.right.pos + [0.0, 0.0, 0.03], r_rot))

        # -- left arm: pick the block.
        block = self.body_pos("block")
        grasp = block + rot_z(yaw) @ BLOCK_GRASP_OFFSET
        yield from self.move(22, left=(grasp, l_rot), phase="descend_block")
        yield from self.grip(12, left=0.0, phase="grasp_block")
        yield from self.wait(4)
        yield from self.move(20, left=(grasp + [0, 0, 0.10], l_rot), right=(RIGHT_PARK, r_rot), phase="lift")

        # -- carry over the part of the drawer that sticks out of the cabinet, lower, release.
        lo, hi = task.interior_opening(data)
        drop_xy = 0.5 * (lo + hi)
        # Turn the block so the fingers close along the drawer's width (the palm then stays clear
        # of the cabinet top while the block is lowered into the drawer).
        g_rot = self.env.data.site("left_gripper_center").xmat.reshape(3, 3)
        in_hand = g_rot.T @ (self.body_pos("block") - self.gripper_pos("left"))  # gripper frame
        d_rot = topdown_rot(LEFT_CLOSING)
        carry = np.array([drop_xy[0], drop_xy[1], CARRY_Z]) - d_rot @ in_hand
        yield from self.move(45, left=(carry, d_rot), phase="carry")
        lower = np.array([drop_xy[0], drop_xy[1], DROP_Z]) - d_rot @ in_hand
        yield from self.move(22, left=(lower, d_rot), phase="lower")
        yield from self.grip(8, left=RELEASE_OPENING, phase="release")
        yield from self.wait(6)
        yield from self.move(10, left=(self.left.pos + [0.0, 0.0, 0.05], d_rot), phase="left_retreat")
        yield from self.move(15, left=(self.left.pos + [-0.12, -0.02, 0.05], d_rot))

        # -- grasp the bar again, push the drawer closed, then let go.
        handle = task.handle_pos(data)
        yield from self.move(30, right=(handle + [0, 0, 0.07], r_rot), phase="reach_handle_again")
        handle = task.handle_pos(data)
        yield from self.move(18, right=(handle, r_rot), phase="descend_handle_again")
        yield from self.grip(8, right=0.0, phase="grasp_handle_again")
        push_to = self.right.pos + [0.0, task.slide(data) + 0.004, 0.0]
        yield from self.move(40, right=(push_to, r_rot), phase="push_closed")
        yield from self.wait(8)
        yield from self.grip(8, right=HANDLE_OPENING, phase="right_release")
        yield from self.move(20, right=(self.right.pos + [0.0, 0.0, 0.08], r_rot), phase="right_retreat")
        yield from self.wait(20, phase="done")

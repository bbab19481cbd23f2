"""Scripted expert for Cube Handoff.

Phases: Reach (right, top-down above the cube) -> Grasp -> Lift to the handoff point ->
Left reach (side grasp, pitched down) -> Left grasp -> Right release and retreat ->
Carry over the plate -> Lower -> Release -> Retreat. Targets are recomputed from the cube's
and the plate's actual poses at the start of each phase. The right gripper grasps square to the
cube's faces, or with `square_grasps` square to the table's axes (yaw 0; the closing fingers turn
the cube, which lies within +-30 degrees).
"""

from __future__ import annotations

import numpy as np

from lerobot_bavo.envs.tasks.cube_handoff import CUBE_HALF, PLATE_HALF_HEIGHT
from lerobot_bavo.experts.base import ScriptedExpert
from lerobot_bavo.sim.transforms import face_yaw, rot_from_axes, rot_z, topdown_rot

HANDOFF_POINT = np.array([0.03, 0.04, 0.17])  # cube centre during the handoff, metres
RIGHT_GRASP_OFFSET = np.array([0.010, 0.0, 0.008])  # gripper centre minus cube centre (top-down)
LEFT_GRASP_OFFSET = np.array([-0.010, 0.0, -0.010])  # gripper centre minus cube centre (side)
LEFT_PITCH = 0.3  # rad, the left gripper points slightly downwards


def left_side_rot(pitch: float = LEFT_PITCH) -> np.ndarray:
    """Left gripper pointing along +x, pitched down by `pitch`, fingers closing along y."""
    return rot_from_axes([np.cos(pitch), 0.0, -np.sin(pitch)], [0.0, 1.0, 0.0])


class CubeHandoffExpert(ScriptedExpert):
    task_name = "cube_handoff"
    contact_phases = frozenset({"descend", "grasp", "left_approach", "left_grasp", "right_release", "lower",
                                "release"})
    supports_square_grasps = True

    def script(self):
        cube = self.body_pos("cube")
        yaw = 0.0 if self.square_grasps else face_yaw(self.body_rot("cube"))
        r_down = topdown_rot([0.0, -1.0, 0.0], yaw)
        grasp = cube + rot_z(yaw) @ RIGHT_GRASP_OFFSET

        yield from self.move(45, right=(grasp + [0, 0, 0.10], r_down), phase="reach")
        yield from self.move(25, right=(grasp, r_down), phase="descend")
        yield from self.grip(12, right=0.0, phase="grasp")
        yield from self.wait(4)

        # Lift straight up, then carry to the handoff point while turning the cube to yaw 0.
        yield from self.move(20, right=(grasp + [0, 0, 0.08], r_down), phase="lift")
        r_handoff = topdown_rot([0.0, -1.0, 0.0], 0.0)
        cube_now = self.body_pos("cube")
        in_hand = cube_now - self.gripper_pos("right")
        yield from self.move(40, right=(HANDOFF_POINT - in_hand, r_handoff), phase="carry")
        yield from self.wait(6)

        cube = self.body_pos("cube")
        l_rot = left_side_rot()
        l_grasp = cube + LEFT_GRASP_OFFSET
        approach = l_rot[:, 0]
        yield from self.move(40, left=(l_grasp - 0.09 * approach, l_rot), phase="left_reach")
        yield from self.move(25, left=(l_grasp, l_rot), phase="left_approach")
        yield from self.grip(12, left=0.0, phase="left_grasp")
        yield from self.wait(6)

        yield from self.grip(10, right=1.0, phase="right_release")
        r_up = self.right.pos + [0.05, 0.0, 0.08]
        yield from self.move(20, right=(r_up, self.right.rot), phase="right_retreat")

        plate = self.body_pos("plate")
        in_hand = self.body_pos("cube") - self.gripper_pos("left")
        place_cube = np.array([plate[0], plate[1], plate[2] + PLATE_HALF_HEIGHT + CUBE_HALF + 0.006])
        yield from self.move(45, left=(place_cube + [0, 0, 0.08] - in_hand, l_rot), phase="carry_to_plate")
        yield from self.move(25, left=(place_cube - in_hand, l_rot), phase="lower")
        yield from self.grip(10, left=1.0, phase="release")
        back = self.left.pos - 0.08 * approach + [0, 0, 0.06]
        yield from self.move(25, left=(back, l_rot), phase="retreat")
        yield from self.wait(20, phase="done")

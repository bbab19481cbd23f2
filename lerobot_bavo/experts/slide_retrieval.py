"""Scripted expert for Slide Retrieval.

Phases: Reach (right, top-down above the blade, fingers closed) -> Press (pad tips pushed
a few millimetres into the blade's top face) -> Slide (drag the spatula along the groove
towards the left arm until the handle overhangs the edge by 6.5 cm; a short correction slide if it
lagged) -> Release (right lifts straight up and retreats) -> Left reach (top-down above the
exposed handle, fingers across it) -> Descend -> Grasp -> Lift. Targets are recomputed from the
platform's and the spatula's actual poses at the start of each phase.
"""

from __future__ import annotations

import numpy as np

from lerobot_bavo.envs.tasks.slide_retrieval import BLADE_HALF, HANDLE_OFFSET, PLATFORM_HALF
from lerobot_bavo.experts.base import ScriptedExpert
from lerobot_bavo.sim.robot import FINGER_PAD_HALF
from lerobot_bavo.sim.transforms import topdown_rot, yaw_of

TARGET_EXPOSURE = 0.065  # m of handle past the edge after the slide
PRESS_DEPTH = 0.012  # m the commanded pad tips go below the blade's top face
SLIDE_LEAD = 0.004  # m of extra slide to absorb the lag of the dragged spatula
LEFT_GRASP_PAST_EDGE = 0.03  # m from the platform edge to the left grasp centre, along the handle
LIFT = 0.12  # m


class SlideRetrievalExpert(ScriptedExpert):
    task_name = "slide_retrieval"

    def platform_axes(self) -> tuple[np.ndarray, np.ndarray, float]:
        """Platform origin, its x axis (towards the far end; the handle points to -x) and yaw."""
        R = self.body_rot("platform")
        return self.body_pos("platform"), R[:, 0], yaw_of(R)

    def script(self):
        task = self.env.task
        data = self.env.data
        _, axis, yaw = self.platform_axes()
        r_rot = topdown_rot([0.0, -1.0, 0.0], yaw)

        # -- right: press on the blade and drag the spatula towards the left arm ------------------
        blade = self.body_pos("spatula")
        blade_top = blade[2] + BLADE_HALF[2]
        press = np.array([blade[0], blade[1], blade_top + FINGER_PAD_HALF[0] - PRESS_DEPTH])
        yield from self.move(45, right=(press + [0, 0, 0.08], r_rot), phase="reach")
        yield from self.grip(8, right=0.0, phase="close")
        yield from self.move(20, right=(press, r_rot), phase="press")
        yield from self.wait(4)

        for attempt in range(2):
            need = TARGET_EXPOSURE - task.exposed_length(data)
            if need < 0.01 and attempt > 0:
                break
            goal = self.right.pos - (need + SLIDE_LEAD) * axis
            yield from self.move(int(np.clip(need / 0.0015, 15, 70)), right=(goal, r_rot), phase="slide")
            yield from self.wait(4)

        yield from self.move(15, right=(self.right.pos + [0, 0, 0.06], r_rot), phase="release")
        yield from self.grip(6, right=1.0)
        yield from self.move(25, right=(self.right.pos + 0.16 * axis + [0, 0, 0.08], r_rot), phase="retreat")

        # -- left: grasp the exposed handle from above and lift -----------------------------------
        origin, axis, yaw = self.platform_axes()
        l_rot = topdown_rot([0.0, 1.0, 0.0], yaw)
        R = self.body_rot("spatula")
        handle_centre = self.body_pos("spatula") + R @ np.asarray(HANDLE_OFFSET)
        hand_axis = R[:, 0]
        edge = origin - PLATFORM_HALF[0] * axis
        # grasp point on the handle's centre line, LEFT_GRASP_PAST_EDGE beyond the edge
        along = (edge - handle_centre) @ hand_axis - LEFT_GRASP_PAST_EDGE
        grasp = handle_centre + along * hand_axis
        yield from self.move(45, left=(grasp + [0, 0, 0.10], l_rot), phase="left_reach")
        yield from self.move(25, left=(grasp + [0, 0, 0.002], l_rot), phase="left_descend")
        yield from self.grip(12, left=0.0, phase="left_grasp")
        yield from self.wait(6)
        yield from self.move(35, left=(self.left.pos + [0, 0, LIFT], l_rot), phase="lift")
        yield from self.wait(20, phase="hold")

"""Slide Retrieval: milestone predicates on hand-set simulator states, reset distribution, expert.

States are written straight into MjData (arm joints, finger openings, spatula pose in the
platform's frame), then `mujoco.mj_forward` (plus a few physics steps where contacts must
settle) and the task's `evaluate`. Gripper placements are solved with IK and checked against
the site position before use, so a failure here is about the predicates, not the placement.
Dimensions are read from the compiled model by geom name, not from the task module.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from _helpers import EditedScene, milestone_flags

from lerobot_bavo.envs.bavo_env import BavoEnv
from lerobot_bavo.envs.tasks import make_task
from lerobot_bavo.envs.tasks.base import MilestoneTracker
from lerobot_bavo.experts import make_expert
from lerobot_bavo.sim.constants import MANIPULATOR_HOME, MANIPULATOR_JOINTS
from lerobot_bavo.sim.kinematics import ArmKinematics
from lerobot_bavo.sim.transforms import rot_from_axes

PAD_DEPTH_HALF = 0.016  # finger pad half depth along the approach axis (robot.py)
PAD_THICKNESS = 0.008
CLOSED = 0.002
OPEN = 0.037
# Documented reset ranges (module docstring).
PLATFORM_X = (-0.04, 0.04)
PLATFORM_Y = (-0.04, 0.10)
PLATFORM_YAW = (-np.pi / 12, np.pi / 12)
TIP_INSET = (0.01, 0.03)
LATERAL = (-0.002, 0.002)


class Scene(EditedScene):
    """An env whose MjData is edited by hand, with positions given in the platform frame."""

    def __init__(self, env: BavoEnv, seed: int = 3):
        super().__init__(env, seed)
        self.P = self.d.body("platform").xpos.copy()
        self.R = self.d.body("platform").xmat.reshape(3, 3).copy()
        size = lambda n: self.m.geom_size[self.m.geom(n).id].copy()  # noqa: E731
        self.floor, self.side = size("platform_floor"), size("platform_side_a")
        self.blade, self.handle = size("blade_geom"), size("handle_geom")
        self.half_x = self.floor[0]
        self.top = 2 * self.floor[2] + 2 * self.side[2]
        # handle centre and tip in the spatula frame (body origin = blade centre)
        self.handle_off = self.m.geom_pos[self.m.geom("handle_geom").id].copy()
        self.tip_x = self.handle_off[0] - self.handle[0]

    def world(self, local) -> np.ndarray:
        return self.P + self.R @ np.asarray(local, float)

    def qadr(self, joint: str) -> int:
        return int(self.m.jnt_qposadr[self.m.joint(joint).id])

    def topdown(self, side: str) -> np.ndarray:
        """Pointing down, fingers closing across the groove (the arm's natural wrist roll)."""
        sign = 1.0 if side == "left" else -1.0
        return rot_from_axes([0, 0, -1], self.R @ [0, sign, 0])

    def place_gripper(self, side: str, pos, opening: float) -> None:
        rot = self.topdown(side)
        kin = ArmKinematics(self.m, [f"{side}_{j}" for j in MANIPULATOR_JOINTS], f"{side}_gripper_center",
                            MANIPULATOR_HOME)
        pre = kin.ik(np.asarray(pos) + [0, 0, 0.1], rot, max_iters=300, pos_tol=1e-4, rot_tol=1e-3)
        res = kin.ik(pos, rot, q_init=pre.qpos, max_iters=300, pos_tol=5e-5, rot_tol=1e-3)
        for j, v in zip(MANIPULATOR_JOINTS, res.qpos):
            self.d.qpos[self.qadr(f"{side}_{j}")] = v
            self.d.ctrl[self.m.actuator(f"{side}_{j}").id] = v
        for f in "ab":
            self.d.qpos[self.qadr(f"{side}_finger_{f}")] = opening
        self.d.ctrl[self.m.actuator(f"{side}_gripper").id] = opening
        mujoco.mj_kinematics(self.m, self.d)
        assert np.linalg.norm(self.d.site(f"{side}_gripper_center").xpos - pos) < 3e-4, (
            "test setup: IK failed"
        )

    def place_spatula(self, exposure: float, lift: float = 0.0, lateral: float = 0.0) -> None:
        """Spatula along the groove, its handle tip `exposure` past the left edge, raised `lift`."""
        local = [-self.half_x - exposure - self.tip_x, lateral, self.top + self.blade[2] + lift]
        quat = np.zeros(4)
        mujoco.mju_mat2Quat(quat, self.R.reshape(9))
        j = self.m.joint("spatula_joint")
        adr, dof = self.m.jnt_qposadr[j.id], self.m.jnt_dofadr[j.id]
        self.d.qpos[adr:adr + 3] = self.world(local)
        self.d.qpos[adr + 3:adr + 7] = quat
        self.d.qvel[dof:dof + 6] = 0.0

    def handle_point(self, past_edge: float, lift: float = 0.0) -> np.ndarray:
        """A point on the handle's centre line `past_edge` beyond the left edge (world frame)."""
        z = self.top + self.blade[2] + self.handle_off[2] + lift
        return self.world([-self.half_x - past_edge, 0.0, z])

    def blade_press_point(self, exposure: float, depth: float = 0.001) -> np.ndarray:
        """Gripper centre with the closed pads' tips `depth` into the blade's top face."""
        x = -self.half_x - exposure - self.tip_x
        return self.world([x, 0.0, self.top + 2 * self.blade[2] + PAD_DEPTH_HALF - depth])

    def park(self, side: str) -> None:
        self.place_gripper(
            side, self.world([0.0, 0.0, 0.30]) + [0.25 if side == "right" else -0.25, 0, 0], OPEN
        )

    def spatula_contacts(self) -> set[str]:
        ids = {self.m.geom("blade_geom").id, self.m.geom("handle_geom").id}
        out = set()
        for g1, g2 in zip(self.d.contact.geom1[:self.d.ncon], self.d.contact.geom2[:self.d.ncon]):
            if g1 in ids:
                out.add(self.m.geom(g2).name)
            if g2 in ids:
                out.add(self.m.geom(g1).name)
        return out



@pytest.fixture(scope="module")
def env():
    e = BavoEnv(task="slide_retrieval", image_height=32, image_width=32, n_points=8, render_mode=None)
    yield e
    e.close()


@pytest.fixture
def scene(env):
    return Scene(env)


# --------------------------------------------------------------------------------------------
# scene and predicates
# --------------------------------------------------------------------------------------------
def test_reset_state_is_at_rest_and_no_milestone(scene):
    assert scene.evaluate() == milestone_flags()
    assert scene.task.exposed_length(scene.d) < 0  # the tip starts inside the edge
    p0 = scene.d.body("spatula").xpos.copy()
    flags = scene.settle(500)
    assert flags == milestone_flags()
    assert np.linalg.norm(scene.d.body("spatula").xpos - p0) < 0.002
    # only the blade rests on the platform's top; the handle hangs free in the groove
    assert scene.spatula_contacts() <= {"platform_side_a", "platform_side_b"}


def test_handle_in_the_groove_leaves_no_room_for_a_finger(scene):
    groove_half = scene.floor[1] - 2 * scene.side[1]
    room = groove_half - scene.handle[1]  # beside the handle, each side
    assert 0 < room < PAD_THICKNESS
    handle_top = scene.top + scene.blade[2] + scene.handle_off[2] + scene.handle[2]
    assert abs(handle_top - scene.top) < 1e-9  # flush with the platform top
    # the handle's bottom is inside the groove, above its floor
    assert 2 * scene.floor[2] < handle_top - 2 * scene.handle[2] < scene.top


def test_right_press_on_blade_is_m1(scene):
    scene.place_gripper("right", scene.blade_press_point(exposure=-0.02), CLOSED)
    scene.park("left")
    flags = scene.settle(5)
    assert {"right_finger_a_pad", "right_finger_b_pad"} <= scene.spatula_contacts()
    assert flags == milestone_flags(m1=True), flags
    # 2 cm above the blade: no contact, no M1
    scene.place_gripper("right", scene.blade_press_point(exposure=-0.02, depth=-0.02), CLOSED)
    assert scene.evaluate() == milestone_flags()


def test_right_touching_only_the_platform_is_not_m1(scene):
    # pads pressed on the platform top beside the blade
    p = scene.world([0.09, 0.065, scene.top + PAD_DEPTH_HALF - 0.001])
    scene.place_gripper("right", p, CLOSED)
    flags = scene.evaluate()
    assert "right_finger_a_pad" not in scene.spatula_contacts()
    assert not flags["m1"], flags


def test_exposure_threshold_for_m2(scene):
    scene.park("right")
    scene.park("left")
    scene.place_spatula(exposure=0.05)
    flags = scene.settle(10)
    assert flags == milestone_flags(m2=True, m3=True), flags  # nothing touches it: also released
    scene.place_spatula(exposure=0.03)
    assert scene.settle(10) == milestone_flags()


def test_exposed_but_not_on_the_platform_is_not_m2(scene):
    scene.park("right")
    scene.place_spatula(exposure=0.05, lift=0.10)  # same x, 10 cm up, in free flight
    assert scene.evaluate() == milestone_flags()


def test_pressing_after_sliding_is_m2_not_m3(scene):
    scene.park("left")
    scene.place_spatula(exposure=0.06)
    scene.place_gripper("right", scene.blade_press_point(exposure=0.06), CLOSED)
    flags = scene.settle(5)
    assert flags == milestone_flags(m1=True, m2=True), flags
    # hovering 5 mm above the blade: no contact, but not clear of it yet
    scene.place_gripper("right", scene.blade_press_point(exposure=0.06, depth=-0.005), CLOSED)
    flags = scene.evaluate()
    assert "right_finger_a_pad" not in scene.spatula_contacts()
    assert flags == milestone_flags(m2=True), flags
    # 3 cm above it: released
    scene.place_gripper("right", scene.blade_press_point(exposure=0.06, depth=-0.03), CLOSED)
    assert scene.evaluate() == milestone_flags(m2=True, m3=True)


def test_left_grasp_of_the_exposed_handle_is_m4(scene):
    scene.park("right")
    scene.place_spatula(exposure=0.065)
    scene.place_gripper("left", scene.handle_point(0.03), scene.handle[1] - 0.0005)
    flags = scene.settle(3)
    assert {"left_finger_a_pad", "left_finger_b_pad"} <= scene.spatula_contacts()
    assert flags == milestone_flags(m2=True, m3=True, m4=True), flags
    # fingers open: no contact
    scene.place_gripper("left", scene.handle_point(0.03), OPEN)
    assert not scene.evaluate()["m4"]


def test_left_hold_of_handle_above_the_platform_is_not_m4(scene):
    """Contact with the handle counts only where the handle is past the edge."""
    scene.park("right")
    scene.place_spatula(exposure=-0.01, lift=0.06)
    p = scene.handle_point(-0.045, lift=0.06)  # 4.5 cm inside the edge, 6 cm up
    scene.place_gripper("left", p, scene.handle[1] - 0.0005)
    flags = scene.evaluate()
    assert {"left_finger_a_pad", "left_finger_b_pad"} <= scene.spatula_contacts()
    assert not flags["m4"], flags  # (m5's instantaneous flag may hold; the tracker needs m4 first)


def test_left_lift_is_m5(scene):
    scene.park("right")
    scene.place_spatula(exposure=0.065, lift=0.05)
    scene.place_gripper("left", scene.handle_point(0.03, lift=0.05), scene.handle[1] - 0.0005)
    flags = scene.settle(3)
    assert scene.spatula_contacts() == {"left_finger_a_pad", "left_finger_b_pad"}
    assert flags["m4"] and flags["m5"], flags
    # held only 2 cm up (under the 3 cm clearance): not lifted
    scene.place_spatula(exposure=0.065, lift=0.02)
    scene.place_gripper("left", scene.handle_point(0.03, lift=0.02), scene.handle[1] - 0.0005)
    assert not scene.settle(3)["m5"]


def test_lift_without_left_grasp_or_with_right_contact_is_not_m5(scene):
    scene.park("right")
    scene.park("left")
    scene.place_spatula(exposure=0.065, lift=0.05)  # in the air, nobody holds it
    assert not scene.evaluate()["m5"]
    scene.place_gripper("left", scene.handle_point(0.03, lift=0.05), scene.handle[1] - 0.0005)
    scene.place_gripper("right", scene.blade_press_point(0.065, depth=0.001) + [0, 0, 0.05], CLOSED)
    flags = scene.evaluate()
    assert "right_finger_a_pad" in scene.spatula_contacts()
    assert flags["m4"] and not flags["m5"], flags


def test_predicate_flags_drive_tracker_in_order(scene):
    tracker = MilestoneTracker()
    scene.park("left")
    scene.place_gripper("right", scene.blade_press_point(exposure=-0.02), CLOSED)
    assert tracker.update(scene.settle(3), 1) == 1
    scene.place_spatula(exposure=0.065)
    scene.place_gripper("right", scene.blade_press_point(exposure=0.065), CLOSED)
    assert tracker.update(scene.settle(3), 2) == 2
    scene.park("right")
    assert tracker.update(scene.settle(3), 3) == 3
    scene.place_gripper("left", scene.handle_point(0.03), scene.handle[1] - 0.0005)
    assert tracker.update(scene.settle(3), 4) == 4
    scene.place_spatula(exposure=0.065, lift=0.05)
    scene.place_gripper("left", scene.handle_point(0.03, lift=0.05), scene.handle[1] - 0.0005)
    assert tracker.update(scene.settle(3), 5) == 5
    assert tracker.success and tracker.reached_at == [1, 2, 3, 4, 5]


def test_stage_targets_are_bound_geoms(env):
    task = env.task
    assert task.stage_targets == ("support_platform", "blade", "handle")
    assert task.stage_transitions == (1, 2)
    names = {k: {env.model.geom(g).name for g in v} for k, v in task.target_geoms.items()}
    assert names == {"support_platform": {"platform_floor", "platform_side_a", "platform_side_b"},
                     "blade": {"blade_geom"}, "handle": {"handle_geom"}}


# --------------------------------------------------------------------------------------------
# reset distribution
# --------------------------------------------------------------------------------------------
def test_reset_distribution_respects_documented_ranges(env):
    rows = []
    for seed in range(30):
        _, info = env.reset(seed=seed)
        P = env.data.body("platform")
        R = P.xmat.reshape(3, 3)
        sp = info["object_poses"]["spatula"]
        yaw = np.arctan2(R[1, 0], R[0, 0])
        np.testing.assert_allclose(sp[3:], info["object_poses"]["platform"][3:], atol=1e-9)  # aligned
        local = R.T @ (sp[:3] - P.xpos)
        tip = env.task.exposed_length(env.data)
        rows.append([P.xpos[0], P.xpos[1], P.xpos[2], yaw, -tip, local[1], local[2]])
    x, y, z, yaw, inset, lateral, h = np.array(rows).T

    def check(values, lo, hi, spread=True):
        assert values.min() >= lo - 1e-9 and values.max() <= hi + 1e-9, (values.min(), values.max(), lo, hi)
        if spread:  # 30 uniform draws reach the outer 20 % of the range
            width = hi - lo
            assert values.min() < lo + 0.2 * width and values.max() > hi - 0.2 * width

    check(x, *PLATFORM_X)
    check(y, *PLATFORM_Y)
    check(yaw, *PLATFORM_YAW)
    check(inset, *TIP_INSET)
    check(lateral, *LATERAL)
    np.testing.assert_allclose(z, 0.0, atol=1e-12)
    np.testing.assert_allclose(h, 0.044, atol=1e-9)  # blade resting on the 4 cm platform top


def test_initialize_episode_uses_only_the_given_generator(env):
    task, m, d = env.task, env.model, env.data

    def layout(seed):
        task.initialize_episode(m, d, np.random.default_rng(seed))
        mujoco.mj_forward(m, d)
        return np.concatenate([d.body("spatula").xpos, d.body("spatula").xquat, d.body("platform").xpos])

    np.random.seed(0)
    a = layout(42)
    np.random.seed(1)
    np.random.rand(10)
    np.testing.assert_array_equal(a, layout(42))
    assert not np.allclose(a, layout(43))


def test_registry_builds_the_task():
    task = make_task("slide_retrieval")
    assert task.name == "slide_retrieval" and task.max_episode_steps == 800


# --------------------------------------------------------------------------------------------
# expert
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("seed", [0, 11])
def test_expert_reaches_m5(env, seed):
    obs, info = env.reset(seed=seed)
    expert = make_expert(env)
    expert.reset()
    for _ in range(env.max_episode_steps):
        obs, reward, terminated, truncated, info = env.step(expert.act(obs, info))
        if terminated or truncated:
            break
    assert info["is_success"], (info["progress"], expert.phase)
    assert reward == 1.0

"""Cube Handoff: milestone predicates on hand-set simulator states, reset distribution, tracker.

States are written straight into MjData (arm joints, finger openings, cube pose), then
`mujoco.mj_forward` (plus a few physics steps where the scene must settle) and the task's
`evaluate`. Gripper placements are solved with a posture-free IK and checked against the site
position before use, so a failure here is about the predicates, not the placement.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from _helpers import EditedScene, milestone_flags

from lerobot_bavo.envs.bavo_env import BavoEnv
from lerobot_bavo.envs.tasks import TASKS, make_task
from lerobot_bavo.envs.tasks.base import MilestoneTracker
from lerobot_bavo.sim.constants import MANIPULATOR_HOME, MANIPULATOR_JOINTS
from lerobot_bavo.sim.kinematics import ArmKinematics
from lerobot_bavo.sim.transforms import rot_from_axes

CUBE_HALF = 0.025
PLATE_RADIUS = 0.07
PLATE_HALF_H = 0.005
GRIP = 0.0245  # finger slide (m): pads' inner faces 0.5 mm inside the 5 cm cube's faces
OPEN = 0.037


# Pointing down, fingers closing along world -y (the right arm's natural top-down grasp; +y
# would need wrist_rotate = pi, just outside its +-3.14158 limit).
DOWN_CLOSE_Y = rot_from_axes([0, 0, -1], [0, -1, 0])
DOWN_CLOSE_X = rot_from_axes([0, 0, -1], [1, 0, 0])  # pointing down, fingers close along world x


class Scene(EditedScene):
    """An env whose MjData is edited by hand."""

    def place_gripper(self, side: str, pos, rot, opening: float) -> np.ndarray:
        kin = ArmKinematics(self.m, [f"{side}_{j}" for j in MANIPULATOR_JOINTS], f"{side}_gripper_center",
                            MANIPULATOR_HOME)
        # Approach from 10 cm above, then solve at the target from there (local DLS converges
        # reliably from a nearby start).
        pre = kin.ik(np.asarray(pos) + [0, 0, 0.1], rot, max_iters=300, pos_tol=1e-4, rot_tol=1e-3)
        res = kin.ik(pos, rot, q_init=pre.qpos, max_iters=300, pos_tol=5e-5, rot_tol=1e-3)
        for j, v in zip(MANIPULATOR_JOINTS, res.qpos):
            self.d.qpos[self.qadr(f"{side}_{j}")] = v
        for f in "ab":
            self.d.qpos[self.qadr(f"{side}_finger_{f}")] = opening
        # Hold the arm there if the physics is stepped.
        for j, v in zip(MANIPULATOR_JOINTS, res.qpos):
            self.d.ctrl[self.m.actuator(f"{side}_{j}").id] = v
        self.d.ctrl[self.m.actuator(f"{side}_gripper").id] = opening
        mujoco.mj_kinematics(self.m, self.d)
        site = self.d.site(f"{side}_gripper_center")
        assert np.linalg.norm(site.xpos - pos) < 3e-4, "test setup: gripper placement failed"
        return site.xmat.reshape(3, 3).copy()

    def place_free(self, joint_id: int, pos, rot=None, vel=(0, 0, 0)) -> None:
        rot = np.eye(3) if rot is None else rot
        quat = np.zeros(4)
        mujoco.mju_mat2Quat(quat, np.ascontiguousarray(rot, dtype=np.float64).reshape(9))
        adr = self.m.jnt_qposadr[joint_id]
        dof = self.m.jnt_dofadr[joint_id]
        self.d.qpos[adr:adr + 3] = pos
        self.d.qpos[adr + 3:adr + 7] = quat
        self.d.qvel[dof:dof + 6] = 0.0
        self.d.qvel[dof:dof + 3] = vel

    def place_cube(self, pos, rot=None, vel=(0, 0, 0)) -> None:
        self.place_free(self.task.cube_joint, pos, rot, vel)

    def plate_xyz(self) -> np.ndarray:
        return self.d.body("plate").xpos.copy()

    def table_top(self) -> float:
        g = self.m.geom("table").id
        return float(self.m.geom_pos[g][2] + self.m.geom_size[g][2])

    def cube_contacts(self) -> set[str]:
        """Names of the geoms currently in contact with the cube."""
        cube = self.m.geom("cube_geom").id
        out = set()
        for g1, g2 in zip(self.d.contact.geom1[:self.d.ncon], self.d.contact.geom2[:self.d.ncon]):
            if cube in (g1, g2):
                out.add(self.m.geom(g2 if g1 == cube else g1).name)
        return out



@pytest.fixture(scope="module")
def env():
    e = BavoEnv(image_height=32, image_width=32, n_points=8, render_mode=None)
    yield e
    e.close()


@pytest.fixture
def scene(env):
    return Scene(env)


# --------------------------------------------------------------------------------------------
# predicates
# --------------------------------------------------------------------------------------------
def test_reset_state_has_no_milestone(scene):
    assert scene.evaluate() == milestone_flags()
    # the reset layout is at rest: a second of physics barely moves the objects
    cube0 = scene.d.body("cube").xpos.copy()
    plate0 = scene.plate_xyz()
    scene.settle(500)
    assert np.linalg.norm(scene.d.body("cube").xpos - cube0) < 0.003
    assert np.linalg.norm(scene.plate_xyz() - plate0) < 0.003


def test_cube_resting_on_table_is_no_milestone(scene):
    scene.place_cube([0.15, 0.0, scene.table_top() + CUBE_HALF])
    flags = scene.settle(50)
    assert flags == milestone_flags()


def test_cube_in_the_air_is_no_milestone(scene):
    scene.place_cube([0.0, 0.0, 0.25])
    assert scene.evaluate() == milestone_flags()


def test_cube_at_rest_on_plate_is_m5(scene):
    plate = scene.plate_xyz()
    top = plate[2] + PLATE_HALF_H
    scene.place_cube([plate[0] + 0.01, plate[1] - 0.01, top + CUBE_HALF])
    flags = scene.settle(25)
    assert flags["m5"], flags
    assert not any(flags[f"m{i}"] for i in range(1, 5))

    # The same cube lifted above the plate: no longer placed.
    scene.place_cube([plate[0], plate[1], top + CUBE_HALF + 0.08])
    assert not scene.evaluate()["m5"]


def test_cube_moving_over_plate_is_not_m5(scene):
    plate = scene.plate_xyz()
    top = plate[2] + PLATE_HALF_H
    scene.place_cube([plate[0], plate[1], top + CUBE_HALF])
    assert scene.settle(25)["m5"]
    dof = scene.m.jnt_dofadr[scene.task.cube_joint]
    scene.d.qvel[dof:dof + 3] = [0.3, 0.0, 0.0]  # well above any "at rest" speed
    assert not scene.evaluate()["m5"]


def test_cube_on_table_beside_plate_is_not_m5(scene):
    plate = scene.plate_xyz()
    scene.place_cube([plate[0], plate[1] - PLATE_RADIUS - CUBE_HALF - 0.02, scene.table_top() + CUBE_HALF])
    assert not scene.settle(25)["m5"]


def test_cube_on_plate_still_held_by_left_gripper_is_not_m5(scene):
    plate = scene.plate_xyz()
    centre = np.array([plate[0], plate[1], plate[2] + PLATE_HALF_H + CUBE_HALF])
    rot = scene.place_gripper("left", centre, DOWN_CLOSE_Y, GRIP)
    scene.place_cube(centre, rot)
    flags = scene.evaluate()
    assert {"left_finger_a_pad", "left_finger_b_pad", "plate_geom"} <= scene.cube_contacts()
    assert not flags["m5"], flags
    # ... and fingers opened wide again (arm still above it): placed.
    for f in "ab":
        scene.d.qpos[scene.qadr(f"left_finger_{f}")] = OPEN
    scene.d.ctrl[scene.m.actuator("left_gripper").id] = OPEN
    assert scene.settle(25)["m5"]


def test_right_grasp_on_table_is_m1_not_m2(scene):
    centre = np.array([0.14, 0.02, scene.table_top() + CUBE_HALF])
    rot = scene.place_gripper("right", centre, DOWN_CLOSE_Y, GRIP)
    scene.place_cube(centre, rot)
    flags = scene.evaluate()
    assert flags == milestone_flags(m1=True), flags


def test_right_grasp_lifted_is_m1_m2(scene):
    centre = np.array([0.05, 0.04, 0.15])
    rot = scene.place_gripper("right", centre, DOWN_CLOSE_Y, GRIP)
    scene.place_cube(centre, rot)
    assert scene.evaluate() == milestone_flags(m1=True, m2=True)
    # Lifted just below the 3 cm clearance: not lifted yet.
    low = np.array([0.05, 0.04, scene.table_top() + CUBE_HALF + 0.02])
    rot = scene.place_gripper("right", low, DOWN_CLOSE_Y, GRIP)
    scene.place_cube(low, rot)
    assert scene.evaluate() == milestone_flags(m1=True)


def test_evaluate_returns_python_bools(scene):
    import json

    centre = np.array([0.05, 0.04, 0.15])
    rot = scene.place_gripper("right", centre, DOWN_CLOSE_Y, GRIP)
    scene.place_cube(centre, rot)
    mujoco.mj_forward(scene.m, scene.d)
    flags = scene.task.evaluate(scene.m, scene.d)
    assert flags["m2"]
    assert all(type(v) is bool for v in flags.values()), {k: type(v) for k, v in flags.items()}
    json.dumps(flags)


def test_single_finger_touch_is_m1_but_not_a_grasp(scene):
    centre = np.array([0.05, 0.04, 0.15])
    rot = scene.place_gripper("right", centre, DOWN_CLOSE_Y, 0.026)
    # Shift the cube 3 mm along the closing axis (the site's y): only finger a touches.
    scene.place_cube(centre + 0.003 * rot[:, 1], rot)
    flags = scene.evaluate()
    names = scene.cube_contacts()
    assert "right_finger_a_pad" in names and "right_finger_b_pad" not in names, names
    assert flags == milestone_flags(m1=True), flags


def test_both_grippers_hold_lifted_cube_is_m3(scene):
    centre = np.array([0.02, 0.04, 0.16])
    rot = scene.place_gripper("right", centre, DOWN_CLOSE_Y, GRIP)
    scene.place_gripper("left", centre, DOWN_CLOSE_X, GRIP)
    scene.place_cube(centre, rot)
    flags = scene.evaluate()
    assert {
        "left_finger_a_pad",
        "left_finger_b_pad",
        "right_finger_a_pad",
        "right_finger_b_pad",
    } <= scene.cube_contacts()
    # Right still touches the cube, so the handoff (M4) is not complete.
    assert flags == milestone_flags(m1=True, m2=True, m3=True), flags


def test_left_only_hold_lifted_is_m4(scene):
    centre = np.array([-0.03, 0.04, 0.16])
    rot = scene.place_gripper("left", centre, DOWN_CLOSE_X, GRIP)
    scene.place_cube(centre, rot)
    assert scene.evaluate() == milestone_flags(m4=True)


def test_left_hold_on_table_is_not_m4(scene):
    centre = np.array([-0.03, 0.04, scene.table_top() + CUBE_HALF])
    rot = scene.place_gripper("left", centre, DOWN_CLOSE_X, GRIP)
    scene.place_cube(centre, rot)
    flags = scene.settle(3)
    assert {"left_finger_a_pad", "left_finger_b_pad", "table"} <= scene.cube_contacts()
    assert not flags["m4"], flags


def test_predicate_flags_drive_tracker_in_order(scene):
    """Hand-set states in task order advance the tracker one milestone at a time."""
    tracker = MilestoneTracker()
    plate = scene.plate_xyz()
    lift = np.array([0.02, 0.04, 0.16])
    rot = scene.place_gripper(
        "right", np.array([0.14, 0.02, scene.table_top() + CUBE_HALF]), DOWN_CLOSE_Y, GRIP
    )
    scene.place_cube(np.array([0.14, 0.02, scene.table_top() + CUBE_HALF]), rot)
    assert tracker.update(scene.evaluate(), 1) == 1
    rot = scene.place_gripper("right", lift, DOWN_CLOSE_Y, GRIP)
    scene.place_cube(lift, rot)
    assert tracker.update(scene.evaluate(), 2) == 2
    scene.place_gripper("left", lift, DOWN_CLOSE_X, GRIP)
    assert tracker.update(scene.evaluate(), 3) == 3
    scene.place_gripper("right", lift + [0.1, 0.0, 0.1], DOWN_CLOSE_Y, OPEN)
    assert tracker.update(scene.evaluate(), 4) == 4
    # Back to a state with no flags: depth is kept.
    scene.place_gripper("left", np.array([-0.3, 0.0, 0.25]), DOWN_CLOSE_X, OPEN)
    scene.place_cube(np.array([plate[0], plate[1], plate[2] + PLATE_HALF_H + CUBE_HALF]))
    assert tracker.update(scene.settle(25), 5) == 5
    assert tracker.success and tracker.reached_at == [1, 2, 3, 4, 5]


# --------------------------------------------------------------------------------------------
# reset distribution
# --------------------------------------------------------------------------------------------
def test_reset_distribution_respects_documented_ranges(env):
    cube, plate, yaws = [], [], []
    for seed in range(50):
        _, info = env.reset(seed=seed)
        c, p = info["object_poses"]["cube"], info["object_poses"]["plate"]
        cube.append(c[:3])
        plate.append(p[:3])
        w, x, y, z = c[3:]
        assert abs(x) < 1e-9 and abs(y) < 1e-9, "the cube starts upright"
        yaws.append(2 * np.arctan2(z, w))
        np.testing.assert_allclose(p[3:], [1, 0, 0, 0], atol=1e-9)
    cube, plate, yaws = np.array(cube), np.array(plate), np.array(yaws)
    yaws = (yaws + np.pi) % (2 * np.pi) - np.pi

    def check(values, lo, hi):
        assert values.min() >= lo and values.max() <= hi, (values.min(), values.max(), lo, hi)
        # spread over the range, not a constant (50 uniform draws reach the outer 15 %)
        width = hi - lo
        assert values.min() < lo + 0.15 * width and values.max() > hi - 0.15 * width

    check(cube[:, 0], 0.08, 0.20)
    check(cube[:, 1], -0.04, 0.12)
    check(yaws, -np.pi / 6, np.pi / 6)
    check(plate[:, 0], -0.20, -0.10)
    check(plate[:, 1], -0.04, 0.12)
    np.testing.assert_allclose(cube[:, 2], CUBE_HALF, atol=1e-9)
    np.testing.assert_allclose(plate[:, 2], PLATE_HALF_H, atol=1e-9)
    # cube and plate never overlap
    assert np.min(np.linalg.norm(cube[:, :2] - plate[:, :2], axis=1)) > PLATE_RADIUS + CUBE_HALF * np.sqrt(2)


def test_initialize_episode_uses_only_the_given_generator(env):
    task = env.task
    m, d = env.model, env.data

    def layout(seed):
        task.initialize_episode(m, d, np.random.default_rng(seed))
        mujoco.mj_forward(m, d)
        return np.concatenate([d.body("cube").xpos, d.body("cube").xquat, d.body("plate").xpos])

    np.random.seed(0)
    a = layout(42)
    np.random.seed(1)
    np.random.rand(10)
    b = layout(42)
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, layout(43))


def test_task_registry():
    assert make_task("cube_handoff").name == "cube_handoff"
    with pytest.raises(
        ValueError, match="unknown task 'cube_stack'; registered: cube_handoff, block_stacking"
    ):
        make_task("cube_stack")
    for name in TASKS:
        assert make_task(name).name == name


# --------------------------------------------------------------------------------------------
# MilestoneTracker
# --------------------------------------------------------------------------------------------
def test_tracker_requires_order():
    t = MilestoneTracker()
    assert t.update(milestone_flags(m2=True, m3=True, m5=True), 1) == 0
    assert t.reached_at == [] and not t.success
    assert t.update(milestone_flags(m1=True), 2) == 1
    assert t.update(milestone_flags(m1=True, m3=True), 3) == 1  # m3 without m2
    assert t.reached_at == [2]


def test_tracker_depth_never_decreases():
    t = MilestoneTracker()
    t.update(milestone_flags(m1=True, m2=True), 0)
    for step, flags in enumerate(
        [milestone_flags(), milestone_flags(m1=True), milestone_flags(m5=True), milestone_flags()], start=1
    ):
        assert t.update(flags, step) == 2
    assert t.depth == 2 and t.reached_at == [0, 0]


def test_tracker_several_milestones_in_one_update():
    t = MilestoneTracker()
    assert t.update(milestone_flags(m1=True, m2=True, m3=True), 7) == 3
    assert t.reached_at == [7, 7, 7]
    assert t.update(milestone_flags(m4=True, m5=True), 9) == 5
    assert t.success and t.reached_at == [7, 7, 7, 9, 9]
    assert t.update(milestone_flags(), 10) == 5  # stays at success

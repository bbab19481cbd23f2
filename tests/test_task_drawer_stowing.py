"""Drawer Stowing: milestone predicates on hand-set simulator states, reset distribution, expert.

States are written straight into MjData (arm joints, finger openings, drawer slide, block pose),
then `mujoco.mj_forward` (plus a few physics steps where the scene must settle) and the task's
`evaluate`. Gripper placements are solved with a posture-free IK and checked against the site
position before use, so a failure here is about the predicates, not the placement.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from _helpers import EditedScene, milestone_flags

from lerobot_bavo.envs.bavo_env import BavoEnv
from lerobot_bavo.envs.tasks import drawer_stowing as T
from lerobot_bavo.envs.tasks import make_task
from lerobot_bavo.envs.tasks.base import MilestoneTracker
from lerobot_bavo.experts import make_expert
from lerobot_bavo.experts.drawer_stowing import DrawerStowingExpert
from lerobot_bavo.sim.constants import MANIPULATOR_HOME, MANIPULATOR_JOINTS
from lerobot_bavo.sim.kinematics import ArmKinematics
from lerobot_bavo.sim.transforms import rot_from_axes, yaw_quat

OPEN = 0.037  # finger slide (m), fully open
BAR_GRIP = T.HANDLE_RADIUS - 0.0005  # pads 0.5 mm inside the bar's surface
BLOCK_GRIP = T.BLOCK_HALF - 0.0005


DOWN_CLOSE_Y = rot_from_axes([0, 0, -1], [0, -1, 0])  # pointing down, fingers close along world y
DOWN_CLOSE_X = rot_from_axes([0, 0, -1], [1, 0, 0])  # pointing down, fingers close along world x


class Scene(EditedScene):
    """An env whose MjData is edited by hand."""

    def place_gripper(self, side: str, pos, rot, opening: float) -> None:
        kin = ArmKinematics(self.m, [f"{side}_{j}" for j in MANIPULATOR_JOINTS], f"{side}_gripper_center",
                            MANIPULATOR_HOME)
        res = kin.ik(pos, rot, max_iters=300, pos_tol=1e-4, rot_tol=1e-3)
        for j, v in zip(MANIPULATOR_JOINTS, res.qpos):
            self.d.qpos[self.qadr(f"{side}_{j}")] = v
            self.d.ctrl[self.m.actuator(f"{side}_{j}").id] = v  # hold the arm there when stepped
        for f in "ab":
            self.d.qpos[self.qadr(f"{side}_finger_{f}")] = opening
        self.d.ctrl[self.m.actuator(f"{side}_gripper").id] = opening
        mujoco.mj_kinematics(self.m, self.d)
        assert np.linalg.norm(self.d.site(f"{side}_gripper_center").xpos - pos) < 1e-3, (
            "test setup: IK failed"
        )

    def set_slide(self, value: float) -> None:
        self.d.qpos[self.task.slide_qadr] = value
        self.d.qvel[self.task.slide_dof] = 0.0
        mujoco.mj_kinematics(self.m, self.d)

    def drawer_to_world(self, p) -> np.ndarray:
        return self.d.body("drawer").xpos + np.asarray(p, float)

    def place_block(self, pos, yaw: float = 0.0, vel=(0, 0, 0)) -> None:
        adr = self.m.jnt_qposadr[self.task.block_joint]
        dof = self.m.jnt_dofadr[self.task.block_joint]
        self.d.qpos[adr:adr + 3] = pos
        self.d.qpos[adr + 3:adr + 7] = yaw_quat(yaw)
        self.d.qvel[dof:dof + 6] = 0.0
        self.d.qvel[dof:dof + 3] = vel

    def block_in_drawer(self, y: float = 0.05) -> np.ndarray:
        """World position of a block resting on the drawer floor, `y` behind the panel."""
        return self.drawer_to_world([0.0, y, T.FLOOR_Z[1] + T.BLOCK_HALF])



@pytest.fixture(scope="module")
def env():
    e = BavoEnv(task="drawer_stowing", image_height=32, image_width=32, n_points=8, render_mode=None)
    yield e
    e.close()


@pytest.fixture
def scene(env):
    return Scene(env)


# --------------------------------------------------------------------------------------------
# predicates
# --------------------------------------------------------------------------------------------
def test_reset_state_has_no_milestone_and_is_at_rest(scene):
    assert scene.evaluate() == milestone_flags()
    block0 = scene.d.body("block").xpos.copy()
    assert scene.task.slide(scene.d) == 0.0
    assert scene.settle(500) == milestone_flags()
    assert np.linalg.norm(scene.d.body("block").xpos - block0) < 0.003
    assert abs(scene.task.slide(scene.d)) < 1e-3


def test_right_fingers_on_handle_is_m1(scene):
    handle = scene.task.handle_pos(scene.d)
    scene.place_gripper("right", handle, DOWN_CLOSE_Y, BAR_GRIP)
    assert scene.evaluate() == milestone_flags(m1=True)
    # Straddling the bar with the fingers half open: no contact yet.
    scene.place_gripper("right", handle, DOWN_CLOSE_Y, 0.017)
    assert scene.evaluate() == milestone_flags()
    # The left gripper on the handle is not M1.
    scene.place_gripper("right", handle + [0.15, -0.05, 0.15], DOWN_CLOSE_Y, OPEN)
    scene.place_gripper("left", handle, DOWN_CLOSE_Y, BAR_GRIP)
    assert scene.evaluate() == milestone_flags()


def test_right_fingers_on_block_is_not_m1(scene):
    block = np.array([0.2, -0.1, T.BLOCK_HALF])  # on the right half, within the right arm's reach
    scene.place_block(block, 0.0)
    scene.place_gripper("right", block, DOWN_CLOSE_X, BLOCK_GRIP)
    flags = scene.evaluate()
    assert not flags["m1"] and not flags["m3"], flags


def test_drawer_opened_beyond_threshold_is_m2(scene):
    scene.set_slide(T.OPEN_SLIDE + 0.01)
    assert scene.evaluate() == milestone_flags(m2=True)
    scene.set_slide(T.OPEN_SLIDE - 0.01)
    assert scene.evaluate() == milestone_flags()
    # The drawer stops at its range: pulled "too far" it stays at the limit.
    scene.set_slide(T.SLIDE_RANGE[1])
    scene.d.qvel[scene.task.slide_dof] = -0.5  # moving outwards
    scene.settle(50)
    assert scene.task.slide(scene.d) <= T.SLIDE_RANGE[1] + 0.002


def test_left_fingers_on_block_is_m3(scene):
    block = scene.d.body("block").xpos.copy()
    scene.place_block(block, 0.0)
    scene.place_gripper("left", block, DOWN_CLOSE_X, BLOCK_GRIP)
    assert scene.evaluate() == milestone_flags(m3=True)
    scene.place_gripper("left", block, DOWN_CLOSE_X, 0.03)  # open around it
    assert scene.evaluate() == milestone_flags()


def test_block_resting_in_open_drawer_is_m4(scene):
    scene.set_slide(0.11)
    scene.place_block(scene.block_in_drawer(0.05), 0.3)
    flags = scene.settle(50)
    assert flags == milestone_flags(m2=True, m4=True), flags


def test_block_moving_in_drawer_is_not_m4(scene):
    scene.set_slide(0.11)
    scene.place_block(scene.block_in_drawer(0.05))
    assert scene.settle(50)["m4"]
    dof = scene.m.jnt_dofadr[scene.task.block_joint]
    scene.d.qvel[dof:dof + 3] = [0.2, 0.0, 0.0]
    assert not scene.evaluate()["m4"]


def test_block_falling_into_drawer_is_not_m4(scene):
    scene.set_slide(0.11)
    scene.place_block(scene.block_in_drawer(0.05) + [0, 0, 0.03])  # inside the box, not on the floor
    assert not scene.evaluate()["m4"]


def test_block_held_in_drawer_is_not_m4(scene):
    scene.set_slide(0.11)
    pos = scene.block_in_drawer(0.05)
    scene.place_block(pos)
    scene.place_gripper("left", pos + [0, 0, 0.005], DOWN_CLOSE_X, BLOCK_GRIP)
    flags = scene.evaluate()
    assert flags["m3"] and not flags["m4"], flags
    # Fingers opened wide (arm still there): placed and released.
    for f in "ab":
        scene.d.qpos[scene.qadr(f"left_finger_{f}")] = 0.03
    scene.d.ctrl[scene.m.actuator("left_gripper").id] = 0.03
    assert scene.settle(30)["m4"]


def test_block_outside_drawer_is_not_m4(scene):
    scene.set_slide(0.11)
    lo, hi = scene.task.interior_opening(scene.d)
    # On the table in front of the open drawer.
    scene.place_block([0.5 * (lo[0] + hi[0]), lo[1] - 0.08, T.BLOCK_HALF])
    assert not scene.settle(30)["m4"]
    # On the cabinet top, above the drawer's inner box.
    top = scene.d.body("cabinet").xpos + [0.0, 0.08, T.CAB_HEIGHT + T.BLOCK_HALF]
    scene.place_block(top)
    flags = scene.settle(30)
    assert not flags["m4"] and not flags["m5"], flags


def test_drawer_closed_with_block_inside_is_m5(scene):
    scene.set_slide(0.0)
    scene.place_block(scene.block_in_drawer(0.07))
    flags = scene.settle(50)
    assert flags == milestone_flags(m4=True, m5=True), flags
    # Half closed: stowed but not closed.
    scene.set_slide(0.05)
    scene.place_block(scene.block_in_drawer(0.07))
    flags = scene.settle(50)
    assert flags["m4"] and not flags["m5"], flags


def test_drawer_closed_with_block_outside_is_not_m5(scene):
    scene.set_slide(0.0)
    assert scene.settle(20) == milestone_flags()


def test_drawer_nearly_closed_with_block_still_held_is_not_m5(scene):
    scene.set_slide(T.CLOSED_SLIDE - 0.002)
    pos = scene.block_in_drawer(0.03)
    scene.place_block(pos)
    scene.place_gripper("left", pos + [0, 0, 0.005], DOWN_CLOSE_X, BLOCK_GRIP)
    flags = scene.evaluate()
    assert flags["m3"] and not flags["m5"], flags


def test_predicate_flags_drive_tracker_in_order(scene):
    tracker = MilestoneTracker()
    handle = scene.task.handle_pos(scene.d)
    scene.place_gripper("right", handle, DOWN_CLOSE_Y, BAR_GRIP)
    assert tracker.update(scene.evaluate(), 1) == 1
    scene.set_slide(0.11)
    # M2 alone: the fingers are no longer on the bar after the slide moved it.
    assert tracker.update(scene.evaluate(), 2) == 2
    block = scene.d.body("block").xpos.copy()
    scene.place_gripper("left", block, DOWN_CLOSE_X, BLOCK_GRIP)
    scene.place_block(block)
    assert tracker.update(scene.evaluate(), 3) == 3
    scene.place_gripper("left", block + [0, 0, 0.15], DOWN_CLOSE_X, OPEN)
    scene.place_block(scene.block_in_drawer(0.05))
    assert tracker.update(scene.settle(40), 4) == 4
    scene.set_slide(0.0)
    scene.place_block(scene.block_in_drawer(0.05))
    assert tracker.update(scene.settle(40), 5) == 5
    assert tracker.success and tracker.reached_at == [1, 2, 3, 4, 5]


# --------------------------------------------------------------------------------------------
# task contract
# --------------------------------------------------------------------------------------------
def test_stage_targets_map_to_geoms(env):
    task = env.task
    assert isinstance(make_task("drawer_stowing"), T.DrawerStowing)
    assert task.stage_targets == ("drawer_front", "object", "drawer_front")
    assert task.stage_transitions == (2, 3)
    names = {k: {env.model.geom(g).name for g in ids} for k, ids in task.target_geoms.items()}
    assert set(names) == {"drawer_front", "object"}
    assert names["object"] == {"block_geom"}
    assert {"drawer_panel", "drawer_handle"} <= names["drawer_front"]
    assert env.max_episode_steps == 800


def test_reset_distribution_respects_documented_ranges(env):
    cab, block, yaws = [], [], []
    for seed in range(30):
        _, info = env.reset(seed=seed)
        b, c, d = (
            info["object_poses"]["block"],
            info["object_poses"]["cabinet"],
            info["object_poses"]["drawer"],
        )
        cab.append(c[:3])
        block.append(b[:3])
        w, x, y, z = b[3:]
        assert abs(x) < 1e-9 and abs(y) < 1e-9, "the block starts upright"
        yaws.append(2 * np.arctan2(z, w))
        np.testing.assert_allclose(c[3:], [1, 0, 0, 0], atol=1e-9)
        np.testing.assert_allclose(d[:3], c[:3], atol=1e-9)  # the drawer starts closed
        assert env.task.slide(env.data) == 0.0
    cab, block, yaws = np.array(cab), np.array(block), np.array(yaws)
    yaws = (yaws + np.pi) % (2 * np.pi) - np.pi

    def check(values, lo, hi):
        assert values.min() >= lo and values.max() <= hi, (values.min(), values.max(), lo, hi)
        width = hi - lo  # spread over the range, not a constant
        assert values.min() < lo + 0.25 * width and values.max() > hi - 0.25 * width

    check(cab[:, 0], *T.CABINET_X)
    check(cab[:, 1], *T.CABINET_Y)
    check(block[:, 0], *T.BLOCK_X)
    check(block[:, 1], *T.BLOCK_Y)
    check(yaws, *T.BLOCK_YAW)
    np.testing.assert_allclose(cab[:, 2], 0.0, atol=1e-9)
    np.testing.assert_allclose(block[:, 2], T.BLOCK_HALF, atol=1e-9)
    # The block's footprint never reaches the opening drawer (panel spans the cabinet width).
    assert np.all(block[:, 0] + T.BLOCK_HALF * np.sqrt(2) < cab[:, 0] - T.CAB_HALF_W)


def test_initialize_episode_uses_only_the_given_generator(env):
    task, m, d = env.task, env.model, env.data

    def layout(seed):
        task.initialize_episode(m, d, np.random.default_rng(seed))
        mujoco.mj_forward(m, d)
        return np.concatenate([d.body("block").xpos, d.body("block").xquat, d.body("cabinet").xpos])

    np.random.seed(0)
    a = layout(42)
    np.random.seed(1)
    np.random.rand(10)
    b = layout(42)
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, layout(43))


# --------------------------------------------------------------------------------------------
# expert
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("seed", [0, 7])
def test_expert_reaches_m5(env, seed):
    obs, info = env.reset(seed=seed)
    expert = make_expert(env)
    assert isinstance(expert, DrawerStowingExpert)
    expert.reset()
    progress, phases = [info["progress"]], set()
    terminated = truncated = False
    while not (terminated or truncated):
        action = expert.act(obs, info)
        phases.add(expert.phase)
        assert env.action_space.contains(action.astype(np.float32))
        obs, _, terminated, truncated, info = env.step(action)
        progress.append(info["progress"])
    assert info["is_success"] and terminated, (seed, progress[-1], expert.phase)
    assert set(progress) == {0, 1, 2, 3, 4, 5}
    assert all(b >= a for a, b in zip(progress, progress[1:]))
    assert expert.contact_phases <= phases, expert.contact_phases - phases  # each declared one is run
    assert len(progress) - 1 < env.max_episode_steps - 7 * 40  # room for camera recovery
    assert env.task.block_inside(env.data) and env.task.slide(env.data) <= T.CLOSED_SLIDE

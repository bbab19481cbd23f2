"""Block Stacking: milestone predicates driven into and out of their conditions, reset ranges,
stage targets, and the scripted expert.

States are set directly in the simulator (free-joint qpos/qvel of the blocks; arm joints from
IK so that the finger pads straddle a block, with their actuator targets set to match), then
`mj_forward` and, where contacts or velocities matter, a few `mj_step` calls.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from lerobot_bavo.envs.bavo_env import BavoEnv
from lerobot_bavo.envs.tasks import make_task
from lerobot_bavo.envs.tasks.block_stacking import (
    BASE_HALF,
    BASE_X,
    BASE_Y,
    BASE_YAW,
    REGION_CENTER,
    TOP_HALF,
    TOP_X,
    TOP_Y,
    TOP_YAW,
    BlockStacking,
)
from lerobot_bavo.experts import make_expert
from lerobot_bavo.experts.block_stacking import CLOSING
from lerobot_bavo.sim import constants as C
from lerobot_bavo.sim.transforms import topdown_rot, yaw_quat

SMALL = dict(image_height=96, image_width=128, n_points=64, render_mode=None)
REGION = np.array([*REGION_CENTER, 0.0])
SQUEEZE = 0.0025  # m, pads pressed this far into a block's faces for a "touch"
SETTLE = 150  # physics steps (0.3 s) for a freshly placed stack to come to rest on its soft contacts


@pytest.fixture(scope="module")
def env():
    env = BavoEnv(task="block_stacking", **SMALL)
    yield env
    env.close()


# --------------------------------------------------------------------------------------------
# state-setting helpers
# --------------------------------------------------------------------------------------------
def _fresh(env) -> None:
    env.reset(seed=0)


def _set_block(env, name: str, pos, yaw: float = 0.0, vel=(0.0, 0.0, 0.0)) -> None:
    m, d = env.model, env.data
    j = m.joint(f"{name}_joint").id
    adr, dof = m.jnt_qposadr[j], m.jnt_dofadr[j]
    d.qpos[adr:adr + 3] = pos
    d.qpos[adr + 3:adr + 7] = yaw_quat(yaw)
    d.qvel[dof:dof + 6] = 0.0
    d.qvel[dof:dof + 3] = vel


def _set_arm(env, side: str, q_arm, finger: float) -> None:
    """Arm joints and finger slide (m) in qpos, with the actuators holding that configuration."""
    m, d = env.model, env.data
    for joint, q in zip(C.MANIPULATOR_JOINTS, q_arm):
        d.qpos[m.jnt_qposadr[m.joint(f"{side}_{joint}").id]] = q
        d.ctrl[m.actuator(f"{side}_{joint}").id] = q
    for f in "ab":
        d.qpos[m.jnt_qposadr[m.joint(f"{side}_finger_{f}").id]] = finger
    d.ctrl[m.actuator(f"{side}_gripper").id] = finger


def _grip_at(env, side: str, center, half_width: float, closed: bool = True) -> None:
    """Top-down gripper centred on `center`; pads pressed into (or clear of) a block's faces."""
    ik = env.kinematics[side].ik(center, topdown_rot(CLOSING[side], 0.0), q_init=np.array(C.MANIPULATOR_HOME),
                                 max_iters=300)
    assert ik.converged
    _set_arm(env, side, ik.qpos, half_width - SQUEEZE if closed else C.FINGER_CTRL_RANGE[1])


def _home_arm(env, side: str) -> None:
    _set_arm(env, side, C.MANIPULATOR_HOME, C.FINGER_CTRL_RANGE[1])


def _flags(env, steps: int = 0) -> dict[str, bool]:
    for _ in range(steps):
        mujoco.mj_step(env.model, env.data)
    mujoco.mj_forward(env.model, env.data)
    return env.task.evaluate(env.model, env.data)


def _base_on_table(x=REGION[0], y=REGION[1]):
    return [x, y, BASE_HALF[2] - 0.0009]  # the table top is at z = -0.9 mm


def _top_on_base(base_xy, dx=0.0, dy=0.0):
    return [base_xy[0] + dx, base_xy[1] + dy, 2 * BASE_HALF[2] - 0.0009 + TOP_HALF[2]]


# --------------------------------------------------------------------------------------------
# task contract
# --------------------------------------------------------------------------------------------
def test_class_attributes_targets_and_region_marker(env):
    task = env.task
    assert isinstance(task, BlockStacking) and task.name == "block_stacking"
    assert task.stage_targets == ("base_block", "top_block", "stacking_region")
    assert task.stage_transitions == (2, 4)
    assert set(task.target_geoms) == set(task.stage_targets)
    m = env.model
    (region,) = task.target_geoms["stacking_region"]
    assert m.geom_contype[region] == 0 and m.geom_conaffinity[region] == 0
    assert m.geom_group[region] == C.GROUP_OBJECT
    for name in ("base_block", "top_block"):
        (g,) = task.target_geoms[name]
        assert m.geom_group[g] == C.GROUP_OBJECT and m.geom_contype[g] == 1
    # Physically honest: the only equality constraints are the two finger couplings (no welds).
    assert m.neq == 2 and all(m.eq_type[i] == mujoco.mjtEq.mjEQ_JOINT for i in range(m.neq))
    assert task.max_episode_steps == 800


def test_reset_distribution_respects_ranges_and_starts_with_no_milestone(env):
    layouts = []
    for seed in range(30):
        _, info = env.reset(seed=seed)
        assert not any(info["milestones"].values()), seed
        assert info["progress"] == 0
        poses = info["object_poses"]
        for name, xr, yr, yawr, half in (("base_block", BASE_X, BASE_Y, BASE_YAW, BASE_HALF),
                                         ("top_block", TOP_X, TOP_Y, TOP_YAW, TOP_HALF)):
            p, q = poses[name][:3], poses[name][3:]
            assert xr[0] <= p[0] <= xr[1] and yr[0] <= p[1] <= yr[1], (seed, name, p)
            assert abs(p[2] - half[2]) < 2e-3
            yaw = 2 * np.arctan2(q[3], q[0])
            assert yawr[0] - 1e-9 <= yaw <= yawr[1] + 1e-9 and abs(q[1]) < 1e-9 and abs(q[2]) < 1e-9
        layouts.append(np.concatenate([poses["base_block"], poses["top_block"]]))
    layouts = np.array(layouts)
    assert np.all(layouts.std(axis=0)[[0, 1, 7, 8]] > 0.02)  # the layouts really vary
    _, info = env.reset(seed=7)
    np.testing.assert_array_equal(info["object_poses"]["base_block"][:3], layouts[7][:3])


# --------------------------------------------------------------------------------------------
# milestone predicates
# --------------------------------------------------------------------------------------------
def test_m1_right_gripper_contacts_base_block(env):
    _fresh(env)
    base = np.array([0.15, 0.04, BASE_HALF[2]])
    _set_block(env, "base_block", base)
    _grip_at(env, "right", base + [0, 0, 0.006], BASE_HALF[1])
    assert _flags(env)["m1"]
    _grip_at(env, "right", base + [0, 0, 0.006], BASE_HALF[1], closed=False)  # open: no contact
    assert not _flags(env)["m1"]
    _home_arm(env, "right")  # the left gripper touching it does not count
    _set_block(env, "base_block", [-0.15, 0.04, BASE_HALF[2]])
    _grip_at(env, "left", np.array([-0.15, 0.04, BASE_HALF[2] + 0.006]), BASE_HALF[1])
    assert not _flags(env)["m1"]


def test_m2_base_block_placed_in_region_and_released(env):
    _fresh(env)
    _set_block(env, "base_block", _base_on_table())
    assert _flags(env, 5)["m2"]
    # Still held by the right gripper: not released.
    _grip_at(env, "right", np.array(_base_on_table()) + [0, 0, 0.006], BASE_HALF[1])
    assert not _flags(env)["m2"]
    _grip_at(env, "right", np.array(_base_on_table()) + [0, 0, 0.006], BASE_HALF[1], closed=False)
    assert _flags(env)["m2"]
    _home_arm(env, "right")
    # Outside the region tolerance (4.5 cm from the centre, still overlapping the marker).
    _set_block(env, "base_block", _base_on_table(x=REGION[0] + 0.045))
    assert not _flags(env, 5)["m2"]
    _set_block(env, "base_block", _base_on_table(y=REGION[1] - 0.045))
    assert not _flags(env, 5)["m2"]
    # Above the region but not on the table.
    _set_block(env, "base_block", np.array(_base_on_table()) + [0, 0, 0.03])
    assert not _flags(env)["m2"]
    # On the table in the region but sliding.
    _set_block(env, "base_block", _base_on_table(), vel=(0.1, 0.0, 0.0))
    assert not _flags(env)["m2"]
    _set_block(env, "base_block", _base_on_table(x=REGION[0] + 0.035))
    assert _flags(env, 5)["m2"]


def test_m3_left_gripper_contacts_top_block(env):
    _fresh(env)
    top = np.array([-0.15, 0.04, TOP_HALF[2]])
    _set_block(env, "top_block", top)
    _grip_at(env, "left", top + [0, 0, 0.006], TOP_HALF[1])
    assert _flags(env)["m3"]
    _grip_at(env, "left", top + [0, 0, 0.006], TOP_HALF[1], closed=False)
    assert not _flags(env)["m3"]
    _home_arm(env, "left")  # the right gripper touching it does not count
    _set_block(env, "top_block", [0.15, 0.04, TOP_HALF[2]])
    _grip_at(env, "right", np.array([0.15, 0.04, TOP_HALF[2] + 0.006]), TOP_HALF[1])
    assert not _flags(env)["m3"]


def test_m4_top_block_held_in_prestacking_volume(env):
    _fresh(env)
    base = np.array(_base_on_table())
    _set_block(env, "base_block", base)
    base_top = base[2] + BASE_HALF[2]

    def held_at(xy, gap, closed=True):
        centre = np.array([xy[0], xy[1], base_top + gap + TOP_HALF[2]])
        _set_block(env, "top_block", centre)
        _grip_at(env, "left", centre, TOP_HALF[1], closed=closed)
        return _flags(env)["m4"]

    assert held_at(base[:2], 0.06)
    assert held_at(base[:2] + [0.04, 0.03], 0.04)  # 5 cm off the axis, 4 cm up
    assert not held_at(base[:2], 0.06, closed=False)  # not held
    assert not held_at(base[:2], 0.015)  # too low
    assert not held_at(base[:2], 0.20)  # too high
    assert not held_at(base[:2] + [0.07, 0.0], 0.06)  # beside, not above
    _set_block(env, "base_block", _base_on_table(x=REGION[0] + 0.08))  # base left the region
    assert not held_at(np.array(_base_on_table(x=REGION[0] + 0.08))[:2], 0.06)


def test_m5_stable_stack_with_both_grippers_released(env):
    _fresh(env)
    base = np.array(_base_on_table())
    _set_block(env, "base_block", base)
    _set_block(env, "top_block", _top_on_base(base))
    assert _flags(env, SETTLE)["m5"]
    # Held by the left gripper: not released.
    top = np.array(_top_on_base(base))
    _grip_at(env, "left", top + [0, 0, 0.006], TOP_HALF[1])
    assert not _flags(env)["m5"]
    _grip_at(env, "left", top + [0, 0, 0.006], TOP_HALF[1], closed=False)
    assert _flags(env)["m5"]
    _home_arm(env, "left")
    # Right fingers on the base block: not released.
    _grip_at(env, "right", base + [0, 0, 0.006], BASE_HALF[1])
    assert not _flags(env)["m5"]
    _home_arm(env, "right")
    # Still moving (just landed / sliding): not stable.
    _set_block(env, "top_block", _top_on_base(base), vel=(0.03, 0.0, 0.0))
    assert not _flags(env)["m5"]
    # Hovering 2 cm above the base block: no support contact.
    _set_block(env, "top_block", np.array(_top_on_base(base)) + [0, 0, 0.02])
    assert not _flags(env)["m5"]
    # Resting on the base block but 2.5 cm off its axis (beyond the 2 cm tolerance).
    _set_block(env, "top_block", _top_on_base(base, dx=0.025))
    assert not _flags(env, SETTLE)["m5"]
    # On the table beside the base block.
    _set_block(env, "top_block", [base[0] + 0.08, base[1], TOP_HALF[2] - 0.0009])
    assert not _flags(env, SETTLE)["m5"]
    # A stack formed outside the stacking region does not count.
    off = np.array(_base_on_table(x=REGION[0] + 0.07))
    _set_block(env, "base_block", off)
    _set_block(env, "top_block", _top_on_base(off))
    assert not _flags(env, SETTLE)["m5"]
    # Back to a clean stack in the region.
    _set_block(env, "base_block", base)
    _set_block(env, "top_block", _top_on_base(base, dx=0.01, dy=-0.01))
    assert _flags(env, SETTLE)["m5"]


def test_m5_does_not_fire_at_the_landing_impact(env):
    """A top block dropped from 6 mm touches the base block while still moving: not yet stable."""
    _fresh(env)
    base = np.array(_base_on_table())
    _set_block(env, "base_block", base)
    _set_block(env, "top_block", np.array(_top_on_base(base)) + [0, 0, 0.006])
    m, d = env.model, env.data
    base_geom, top_geom = env.task.target_geoms["base_block"][0], env.task.target_geoms["top_block"][0]
    for _ in range(100):
        mujoco.mj_step(m, d)
        if any({d.contact.geom1[i], d.contact.geom2[i]} == {base_geom, top_geom} for i in range(d.ncon)):
            break
    else:
        pytest.fail("the top block never landed")
    assert not _flags(env)["m5"]
    assert _flags(env, 200)["m5"]  # settled


# --------------------------------------------------------------------------------------------
# scripted expert
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("seed", [0, 1])
def test_expert_reaches_m5_in_order(env, seed):
    obs, info = env.reset(seed=seed)
    expert = make_expert(env)
    expert.reset()
    first_step = {}  # milestone depth -> control step at which it was first reached
    phases = set()
    while True:
        action = expert.act(obs, info)
        phases.add(expert.phase)
        obs, reward, terminated, truncated, info = env.step(action)
        first_step.setdefault(info["progress"], env.elapsed_steps)
        if terminated or truncated:
            break
    assert info["is_success"] and info["progress"] == 5
    # Each milestone is reached at its own step (none fires together with the previous one).
    assert [d for d in sorted(first_step) if d > 0] == [1, 2, 3, 4, 5]
    assert expert.contact_phases <= phases, expert.contact_phases - phases  # each declared one is run
    assert env.elapsed_steps < 0.6 * env.task.max_episode_steps


def test_make_task_gives_a_fresh_instance():
    assert isinstance(make_task("block_stacking"), BlockStacking)

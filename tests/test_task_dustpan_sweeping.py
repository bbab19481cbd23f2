"""Dustpan Sweeping: milestone predicates driven into and out of their conditions by setting
simulator state directly, the reset distribution's documented ranges, and the scripted expert.

Expected geometry is recomputed here from the documented numbers (plain numpy), not taken from
the predicates under test.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from lerobot_bavo.envs.bavo_env import BavoEnv
from lerobot_bavo.envs.tasks.dustpan_sweeping import (
    BROOM_HANDLE_FROM,
    BROOM_HANDLE_TO,
    ENTRANCE_X,
    HANDLE_POS,
    HEAD_HALF,
    PLATE_TOP,
    TARGET_HALF,
    DustpanSweeping,
)
from lerobot_bavo.experts.dustpan_sweeping import DustpanSweepingExpert
from lerobot_bavo.sim.transforms import topdown_rot, yaw_quat

SMALL = dict(image_height=48, image_width=64, n_points=16, render_mode=None)


@pytest.fixture(scope="module")
def env():
    e = BavoEnv(task="dustpan_sweeping", **SMALL)
    yield e
    e.close()


# --------------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------------
def quat_x(angle: float) -> np.ndarray:
    return np.array([math.cos(angle / 2), math.sin(angle / 2), 0.0, 0.0])


def yaw_of_quat(q) -> float:
    w, x, y, z = q
    return math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def set_body(env, name: str, pos, quat=(1, 0, 0, 0), linvel=(0, 0, 0)) -> None:
    j = env.model.joint(f"{name}_joint")
    adr, dof = j.qposadr[0], j.dofadr[0]
    env.data.qpos[adr:adr + 3] = pos
    env.data.qpos[adr + 3:adr + 7] = quat
    env.data.qvel[dof:dof + 6] = 0.0
    env.data.qvel[dof:dof + 3] = linvel


def set_arm(env, side: str, q_arm, finger: float) -> None:
    for name, q in zip(("waist", "shoulder", "elbow", "forearm_roll", "wrist_angle", "wrist_rotate"), q_arm):
        env.data.qpos[env.model.joint(f"{side}_{name}").qposadr[0]] = q
    for f in "ab":
        env.data.qpos[env.model.joint(f"{side}_finger_{f}").qposadr[0]] = finger


def flags(env, settle_steps: int = 0) -> dict[str, bool]:
    mujoco.mj_forward(env.model, env.data)
    for _ in range(settle_steps):
        mujoco.mj_step(env.model, env.data)
    return env.task.evaluate(env.model, env.data)


def local_to_world(pos_xy, yaw, local) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array(
        [pos_xy[0] + c * local[0] - s * local[1], pos_xy[1] + s * local[0] + c * local[1], local[2]]
    )


def grasp_arm(env, side: str, point, yaw: float, finger: float) -> None:
    """Place `side`'s gripper centre at `point`, pointing down, fingers across heading `yaw`."""
    kin = env.kinematics[side]
    res = kin.ik(point, topdown_rot([0.0, 1.0 if side == "left" else -1.0, 0.0], yaw))
    assert res.converged, (side, point)
    set_arm(env, side, res.qpos, finger)


CUBE = np.array([0.0, 0.05])


def valid_layout(env, pan_gap: float = 0.05, lateral: float = 0.0) -> np.ndarray:
    """Pan facing +x with the cube `pan_gap` ahead of its entrance line; broom parked away."""
    env.reset(seed=0)
    set_body(env, "target_object", [CUBE[0], CUBE[1], TARGET_HALF])
    pan_xy = np.array([CUBE[0] - pan_gap - ENTRANCE_X, CUBE[1] - lateral])
    set_body(env, "dustpan", [*pan_xy, 0.0])
    set_body(env, "broom", [0.2, 0.05, 0.0])
    return pan_xy


# --------------------------------------------------------------------------------------------
# milestone predicates
# --------------------------------------------------------------------------------------------
def test_m1_left_contact_with_dustpan_handle(env):
    pan_xy = valid_layout(env)
    handle = local_to_world(pan_xy, 0.0, HANDLE_POS)
    grasp_arm(env, "left", handle, 0.0, finger=0.0095)  # pads 0.5 mm into the 2 cm handle
    assert flags(env)["m1"]
    grasp_arm(env, "left", handle, 0.0, finger=0.03)  # open: pads 2 cm clear of the handle
    assert not flags(env)["m1"]
    # Closed on the pan's back wall (6 mm thick, at local x -0.052) instead of the handle.
    wall = local_to_world(pan_xy, 0.0, (-0.052, 0.03, 0.03))
    grasp_arm(env, "left", wall, math.pi / 2, finger=0.0025)
    f = flags(env)
    assert not f["m1"]
    assert any(env.model.geom(g).name == "dustpan_wall_back"
               for i in range(env.data.ncon) for g in (env.data.contact.geom1[i], env.data.contact.geom2[i]))


def test_m2_valid_sweeping_configuration(env):
    valid_layout(env, pan_gap=0.05)
    assert flags(env)["m2"]
    assert flags(env, settle_steps=20)["m2"]  # and it stays valid at rest

    valid_layout(env, pan_gap=0.05, lateral=0.06)  # cube outside the 4 cm corridor
    assert not flags(env)["m2"]
    valid_layout(env, pan_gap=0.005)  # cube at the entrance, not in front of it
    assert not flags(env)["m2"]
    valid_layout(env, pan_gap=0.15)  # too far ahead
    assert not flags(env)["m2"]

    pan_xy = valid_layout(env)
    set_body(env, "dustpan", [*pan_xy, 0.0], yaw_quat(math.pi))  # entrance facing away
    assert not flags(env)["m2"]
    set_body(env, "dustpan", [*pan_xy, 0.005], quat_x(math.radians(15)))  # tilted 15 deg
    assert not flags(env)["m2"]
    set_body(env, "dustpan", [*pan_xy, 0.05])  # lifted 5 cm
    assert not flags(env)["m2"]
    set_body(env, "dustpan", [*pan_xy, 0.0], linvel=(0.1, 0.0, 0.0))  # still being dragged
    assert not flags(env)["m2"]
    # Turned by 20 deg about the cube so that the cube stays on the pan's axis: still valid.
    yaw = math.radians(20)
    d = 0.05 + ENTRANCE_X
    set_body(env, "dustpan", [CUBE[0] - d * math.cos(yaw), CUBE[1] - d * math.sin(yaw), 0.0], yaw_quat(yaw))
    assert flags(env)["m2"]


def broom_grasp_point(broom_xy, yaw: float) -> np.ndarray:
    x = 0.075
    t = (x - BROOM_HANDLE_FROM[0]) / (BROOM_HANDLE_TO[0] - BROOM_HANDLE_FROM[0])
    z = BROOM_HANDLE_FROM[2] + t * (BROOM_HANDLE_TO[2] - BROOM_HANDLE_FROM[2])
    return local_to_world(broom_xy, yaw, (x, 0.0, z))


def test_m3_right_contact_with_broom(env):
    valid_layout(env)
    broom_xy = (0.12, 0.05)
    set_body(env, "broom", [*broom_xy, 0.0])
    grasp = broom_grasp_point(broom_xy, 0.0)
    grasp_arm(env, "right", grasp, 0.0, finger=0.0095)  # handle radius 1 cm
    assert flags(env)["m3"]
    grasp_arm(env, "right", grasp, 0.0, finger=0.03)
    assert not flags(env)["m3"]
    grasp_arm(env, "right", grasp + [0.0, 0.0, 0.05], 0.0, finger=0.0095)  # closed, 5 cm above
    assert not flags(env)["m3"]
    # The left gripper on the broom does not count.
    valid_layout(env)
    broom_xy = (-0.15, -0.15)
    set_body(env, "broom", [*broom_xy, 0.0])
    grasp_arm(env, "left", broom_grasp_point(broom_xy, 0.0), 0.0, finger=0.0095)
    f = flags(env)
    assert not f["m3"] and env.task.evaluate(env.model, env.data) == f


def test_m4_broom_head_contacts_target_while_held(env):
    valid_layout(env)
    broom_xy = (0.12, 0.05)
    set_body(env, "broom", [*broom_xy, 0.0])
    grasp = broom_grasp_point(broom_xy, 0.0)
    touching_x = broom_xy[0] - HEAD_HALF[0] - TARGET_HALF + 0.0005
    grasp_arm(env, "right", grasp, 0.0, finger=0.0095)
    set_body(env, "target_object", [touching_x, 0.05, TARGET_HALF])
    assert flags(env)["m4"]
    set_body(env, "target_object", [touching_x - 0.03, 0.05, TARGET_HALF])  # 3 cm gap
    assert not flags(env)["m4"]
    set_body(env, "target_object", [touching_x, 0.05, TARGET_HALF])
    grasp_arm(env, "right", grasp, 0.0, finger=0.03)  # broom touches the cube, but not held
    assert not flags(env)["m4"]
    # The right gripper itself touching the cube is not the broom touching it.
    grasp_arm(env, "right", grasp, 0.0, finger=0.0095)
    set_body(env, "target_object", [grasp[0], grasp[1] + 0.03, grasp[2]])
    f = flags(env)
    assert f["m3"] and not f["m4"]


def test_m5_target_inside_entrance(env):
    pan_xy = valid_layout(env)

    def put_cube(ahead: float, lateral: float = 0.0, z: float = PLATE_TOP + TARGET_HALF):
        set_body(env, "target_object", [pan_xy[0] + ENTRANCE_X + ahead, pan_xy[1] + lateral, z])

    put_cube(-0.03)  # fully past the entrance line, on the plate
    assert flags(env)["m5"]
    assert flags(env, settle_steps=20)["m5"]
    put_cube(-0.005, z=TARGET_HALF + 0.0005)  # only a sliver past the line
    assert not flags(env)["m5"]
    put_cube(0.03, z=TARGET_HALF)  # in front of the pan
    assert not flags(env)["m5"]
    put_cube(-0.03, lateral=0.08, z=TARGET_HALF)  # beside the pan, outside its side wall
    assert not flags(env)["m5"]
    put_cube(-0.03, z=0.08)  # held above the pan
    assert not flags(env)["m5"]
    put_cube(-0.03)
    set_body(env, "dustpan", [*pan_xy, 0.008], quat_x(math.radians(15)))  # pan tipped over
    assert not flags(env)["m5"]


def test_stage_targets_and_geoms(env):
    task = env.task
    assert task.stage_targets == ("dustpan", "broom", "target_object")
    assert task.stage_transitions == (2, 3)
    m = env.model
    for name, ids in task.target_geoms.items():
        assert ids and all(m.geom_group[i] == 2 for i in ids), name
    bodies = {name: {m.body(m.geom_bodyid[i]).name for i in ids} for name, ids in task.target_geoms.items()}
    assert bodies == {"dustpan": {"dustpan"}, "broom": {"broom"}, "target_object": {"target_object"}}
    assert task.max_episode_steps == 800


# --------------------------------------------------------------------------------------------
# reset distribution
# --------------------------------------------------------------------------------------------
PAN_RECT = ((-0.145, ENTRANCE_X), (-0.065, 0.065))  # footprint in the pan frame (x, y ranges)
BROOM_RECTS = (((-0.027, 0.027), (-0.074, 0.074)), ((0.01, 0.18), (-0.01, 0.01)))
CUBE_RECT = ((-TARGET_HALF, TARGET_HALF), (-TARGET_HALF, TARGET_HALF))


def corners(rect, xy, yaw) -> np.ndarray:
    (x0, x1), (y0, y1) = rect
    c, s = math.cos(yaw), math.sin(yaw)
    pts = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
    return pts @ np.array([[c, s], [-s, c]]) + xy


def separation(a: np.ndarray, b: np.ndarray) -> float:
    """Largest gap along any edge normal of two convex polygons (> 0: disjoint by that much)."""
    best = -np.inf
    for poly in (a, b):
        for i in range(len(poly)):
            e = poly[(i + 1) % len(poly)] - poly[i]
            n = np.array([-e[1], e[0]]) / np.linalg.norm(e)
            pa, pb = a @ n, b @ n
            best = max(best, pb.min() - pa.max(), pa.min() - pb.max())
    return best


def test_reset_distribution_ranges(env):
    sides = set()
    for seed in range(30):
        _, info = env.reset(seed=seed)
        poses = info["object_poses"]
        cube, pan, broom = poses["target_object"], poses["dustpan"], poses["broom"]
        cube_yaw, pan_yaw, broom_yaw = (yaw_of_quat(p[3:]) for p in (cube, pan, broom))
        assert -0.03 <= cube[0] <= 0.03 and -0.02 <= cube[1] <= 0.10
        assert abs(cube_yaw) <= math.pi / 4 + 1e-9
        assert -0.14 <= pan[0] - cube[0] <= -0.08
        assert 0.13 <= abs(pan[1] - cube[1]) <= 0.17
        sides.add(np.sign(pan[1] - cube[1]))
        assert abs(pan_yaw) <= math.radians(25) + 1e-9
        assert 0.11 <= broom[0] - cube[0] <= 0.15 and abs(broom[1] - cube[1]) <= 0.05
        assert abs(broom_yaw) <= math.radians(20) + 1e-9
        assert pan[2] == 0.0 and broom[2] == 0.0 and cube[2] == TARGET_HALF
        # Footprints at least 1 cm apart; no milestone holds at reset.
        cube_p = corners(CUBE_RECT, cube[:2], cube_yaw)
        pan_p = corners(PAN_RECT, pan[:2], pan_yaw)
        broom_ps = [corners(r, broom[:2], broom_yaw) for r in BROOM_RECTS]
        assert separation(pan_p, cube_p) >= 0.01
        assert all(separation(b, cube_p) >= 0.01 and separation(b, pan_p) >= 0.01 for b in broom_ps)
        assert not any(info["milestones"].values())
        assert info["progress"] == 0
    assert sides == {-1.0, 1.0}


def test_reset_is_seeded_and_settles(env):
    _, a = env.reset(seed=7)
    _, b = env.reset(seed=7)
    _, c = env.reset(seed=8)
    for name in a["object_poses"]:
        assert np.array_equal(a["object_poses"][name], b["object_poses"][name])
    assert not np.array_equal(a["object_poses"]["target_object"], c["object_poses"]["target_object"])
    # Objects rest where they were placed: nothing falls, tips or gets pushed by the robot.
    env.reset(seed=7)
    for _ in range(100):
        mujoco.mj_step(env.model, env.data)
    for name, pose in env.task.object_poses(env.model, env.data).items():
        start = a["object_poses"][name]
        assert np.linalg.norm(pose[:3] - start[:3]) < 0.003, name
        rot = np.zeros(9)
        mujoco.mju_quat2Mat(rot, pose[3:])
        assert rot[8] > math.cos(math.radians(2)), name  # still upright
        assert abs(yaw_of_quat(pose[3:]) - yaw_of_quat(start[3:])) < 0.02, name


# --------------------------------------------------------------------------------------------
# expert
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("seed", [3, 11])
def test_expert_reaches_success(env, seed):
    obs, info = env.reset(seed=seed)
    expert = DustpanSweepingExpert(env)
    expert.reset()
    reached, phases = [], set()
    while True:
        action = expert.act(obs, info)
        phases.add(expert.phase)
        obs, reward, terminated, truncated, info = env.step(action)
        if info["progress"] > len(reached):
            reached.extend([env.elapsed_steps] * (info["progress"] - len(reached)))
        if terminated or truncated:
            break
    assert info["is_success"] and terminated and reward == 1.0
    assert env.elapsed_steps < env.task.max_episode_steps - 280  # room for 7 recovery pauses
    assert reached == sorted(reached) and len(set(reached)) == 5  # milestones one after another
    assert expert.contact_phases <= phases, expert.contact_phases - phases  # each declared one is run
    assert isinstance(env.task, DustpanSweeping)

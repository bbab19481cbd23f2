"""MjSpec builders for the two ViperX-300-S-like manipulators and the 7-DoF camera arm.

Our own primitive geometry (capsules and boxes); kinematic offsets and joint dynamics mirror the
public AV-ALOHA numbers in `constants.py`. Every element is prefixed (`left_`, `right_`, `cam_`)
so names never collide, and code binds ids once instead of matching name prefixes at run time.

Arm frame: x points from the base towards the workspace, z up. Manipulator joints: waist (z),
shoulder (y), elbow (y), forearm_roll (x), wrist_angle (y), wrist_rotate (x). The camera arm
replaces the last two with wrist_1 (pitch, y), wrist_2 (roll, x), wrist_3 (yaw, z).

Collision policy (documented simplification): robot geoms collide with the table and the task
objects but not with each other (no self- or arm-arm contacts), so scripted motions cannot
jam the arms into each other; grasps are still held purely by finger friction.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from lerobot_bavo.sim import constants as C
from lerobot_bavo.sim.transforms import quat_from_axis_angle, quat_from_matrix

# Collision bitmasks: world/objects use 1; robot geoms use contype 2, conaffinity 1, so they
# touch world and objects but never each other.
ROBOT_CONTYPE = 2
ROBOT_CONAFFINITY = 1

_LINK_RGBA = (0.18, 0.18, 0.2, 1.0)
_JOINT_RGBA = (0.35, 0.35, 0.38, 1.0)
_CAM_RGBA = (0.25, 0.25, 0.3, 1.0)
_PAD_RGBA = (0.1, 0.1, 0.1, 1.0)

FINGER_PAD_HALF = (0.016, 0.004, 0.011)  # x (depth), y (thickness), z (height), metres


def _add_hinge(body, name: str, axis, cls: C.JointClass) -> None:
    body.add_joint(
        name=name,
        type=mujoco.mjtJoint.mjJNT_HINGE,
        axis=list(axis),
        range=list(cls.range),
        limited=mujoco.mjtLimited.mjLIMITED_TRUE,
        damping=cls.damping,
        armature=cls.armature,
        frictionloss=cls.frictionloss,
    )


def _add_position_actuator(spec: mujoco.MjSpec, name: str, joint: str, kp: float, kv: float,
                           ctrlrange, forcerange=None) -> None:
    act = spec.add_actuator(name=name, target=joint, trntype=mujoco.mjtTrn.mjTRN_JOINT)
    act.gaintype = mujoco.mjtGain.mjGAIN_FIXED
    act.biastype = mujoco.mjtBias.mjBIAS_AFFINE
    gain = np.zeros(10)
    gain[0] = kp
    bias = np.zeros(10)
    bias[1] = -kp
    bias[2] = -kv
    act.gainprm = gain
    act.biasprm = bias
    act.ctrlrange = list(ctrlrange)
    act.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
    if forcerange is not None:
        act.forcerange = list(forcerange)
        act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE


def _robot_geom(body, name: str, rgba=_LINK_RGBA, **kwargs):
    return body.add_geom(
        name=name,
        group=C.GROUP_ROBOT,
        contype=ROBOT_CONTYPE,
        conaffinity=ROBOT_CONAFFINITY,
        rgba=list(rgba),
        **kwargs,
    )


def _capsule_between(body, name: str, start, end, radius: float, mass: float, rgba=_LINK_RGBA):
    return _robot_geom(
        body,
        name,
        rgba=rgba,
        type=mujoco.mjtGeom.mjGEOM_CAPSULE,
        fromto=[*start, *end],
        size=[radius, 0, 0],
        mass=mass,
    )


def _build_shoulder_chain(spec: mujoco.MjSpec, mount: C.ArmMount):
    """Base, waist, shoulder, elbow and forearm-roll links shared by all three arms.

    Returns the forearm-roll body, whose frame the wrist is attached to.
    """
    p = mount.prefix
    base = spec.worldbody.add_body(
        name=f"{p}base", pos=list(mount.pos), quat=list(quat_from_axis_angle((0, 0, 1), mount.yaw))
    )
    _robot_geom(
        base,
        f"{p}base_geom",
        type=mujoco.mjtGeom.mjGEOM_CYLINDER,
        size=[0.06, 0.035, 0],
        pos=[0, 0, 0.035],
        mass=1.0,
        rgba=_JOINT_RGBA,
    )

    waist = base.add_body(name=f"{p}waist_link", pos=list(C.WAIST_OFFSET), gravcomp=1.0)
    _add_hinge(waist, f"{p}waist", (0, 0, 1), C.WAIST)
    _robot_geom(
        waist,
        f"{p}waist_geom",
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=[0.035, 0.045, 0.025],
        pos=[0, 0, 0.02],
        mass=0.4,
        rgba=_JOINT_RGBA,
    )

    shoulder = waist.add_body(name=f"{p}upper_arm_link", pos=list(C.SHOULDER_OFFSET), gravcomp=1.0)
    _add_hinge(shoulder, f"{p}shoulder", (0, 1, 0), C.SHOULDER)
    _capsule_between(shoulder, f"{p}upper_arm_geom", (0, 0, 0), C.ELBOW_OFFSET, 0.025, 0.8)

    elbow = shoulder.add_body(name=f"{p}forearm_link", pos=list(C.ELBOW_OFFSET), gravcomp=1.0)
    _add_hinge(elbow, f"{p}elbow", (0, 1, 0), C.ELBOW)
    _capsule_between(elbow, f"{p}forearm_geom", (0, 0, 0), C.FOREARM_ROLL_OFFSET, 0.022, 0.5)

    roll = elbow.add_body(name=f"{p}lower_forearm_link", pos=list(C.FOREARM_ROLL_OFFSET), gravcomp=1.0)
    _add_hinge(roll, f"{p}forearm_roll", (1, 0, 0), C.FOREARM_ROLL)
    _capsule_between(roll, f"{p}lower_forearm_geom", (0, 0, 0), C.WRIST_ANGLE_OFFSET, 0.02, 0.3)
    return roll


def add_manipulator(spec: mujoco.MjSpec, mount: C.ArmMount) -> None:
    """Add one 6-DoF manipulator with a parallel gripper and its 7 position actuators.

    The site `<prefix>gripper_center` sits midway between the finger pads; its x axis points out
    of the gripper, its y axis is the finger closing direction, and it is the IK end effector.
    """
    p = mount.prefix
    roll = _build_shoulder_chain(spec, mount)

    wrist = roll.add_body(name=f"{p}wrist_link", pos=list(C.WRIST_ANGLE_OFFSET), gravcomp=1.0)
    _add_hinge(wrist, f"{p}wrist_angle", (0, 1, 0), C.WRIST_ANGLE)
    _capsule_between(wrist, f"{p}wrist_geom", (0, 0, 0), C.WRIST_ROTATE_OFFSET, 0.02, 0.15, rgba=_JOINT_RGBA)

    gripper = wrist.add_body(name=f"{p}gripper_link", pos=list(C.WRIST_ROTATE_OFFSET), gravcomp=1.0)
    _add_hinge(gripper, f"{p}wrist_rotate", (1, 0, 0), C.WRIST_ROTATE)
    cx = C.GRIPPER_CENTER_OFFSET[0]
    palm_x = cx - FINGER_PAD_HALF[0] - 0.03
    _robot_geom(
        gripper,
        f"{p}palm_geom",
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=[0.02, 0.05, 0.018],
        pos=[palm_x, 0, 0],
        mass=0.2,
    )
    gripper.add_site(
        name=f"{p}gripper_center", pos=[cx, 0, 0], size=[0.006, 0, 0], group=C.GROUP_HIDDEN, rgba=[1, 0, 0, 1]
    )

    for side, sign in (("a", 1.0), ("b", -1.0)):
        finger = gripper.add_body(name=f"{p}finger_{side}", pos=[cx, 0, 0], gravcomp=1.0)
        finger.add_joint(
            name=f"{p}finger_{side}",
            type=mujoco.mjtJoint.mjJNT_SLIDE,
            axis=[0, sign, 0],
            range=list(C.FINGER_RANGE),
            limited=mujoco.mjtLimited.mjLIMITED_TRUE,
            damping=C.FINGER_DAMPING,
            armature=C.FINGER_ARMATURE,
        )
        # The pad's inner face lies exactly at the finger's slide position (gap = 2 q).
        _robot_geom(
            finger,
            f"{p}finger_{side}_pad",
            rgba=_PAD_RGBA,
            type=mujoco.mjtGeom.mjGEOM_BOX,
            size=list(FINGER_PAD_HALF),
            pos=[0, sign * FINGER_PAD_HALF[1], 0],
            mass=0.04,
            friction=[1.5, 0.02, 0.002],
            condim=4,
            solref=[0.005, 1],
            priority=1,
        )
        # Finger stem connecting the pad to the palm (visual + collision with objects).
        _robot_geom(
            finger,
            f"{p}finger_{side}_stem",
            type=mujoco.mjtGeom.mjGEOM_BOX,
            size=[0.015, 0.004, 0.011],
            pos=[-FINGER_PAD_HALF[0] - 0.015, sign * (FINGER_PAD_HALF[1] + 0.002), 0],
            mass=0.02,
        )

    spec.add_equality(
        name=f"{p}finger_coupling",
        type=mujoco.mjtEq.mjEQ_JOINT,
        name1=f"{p}finger_b",
        name2=f"{p}finger_a",
        data=np.array([0, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0]),
    )

    for joint, cls in zip(C.MANIPULATOR_JOINTS, C.MANIPULATOR_CLASSES):
        _add_position_actuator(spec, f"{p}{joint}", f"{p}{joint}", cls.kp, 0.0, cls.range, cls.forcerange)
    _add_position_actuator(
        spec, f"{p}gripper", f"{p}finger_a", C.FINGER_KP, C.FINGER_KV, C.FINGER_CTRL_RANGE,
        (-C.FINGER_FORCE_LIMIT, C.FINGER_FORCE_LIMIT),
    )


def camera_mount_quat() -> np.ndarray:
    """Orientation of the active camera in the wrist_3 frame (MuJoCo camera looks along -z).

    The optical axis is the wrist_3 frame's +x pitched down by `CAM_MOUNT_PITCH`; image up is
    the correspondingly pitched +z; image right is -y.
    """
    pitch = C.CAM_MOUNT_PITCH
    fwd = np.array([math.cos(pitch), 0.0, -math.sin(pitch)])
    up = np.array([math.sin(pitch), 0.0, math.cos(pitch)])
    right = np.cross(fwd, up)
    return quat_from_matrix(np.column_stack([right, up, -fwd]))


def add_camera_arm(spec: mujoco.MjSpec, fovy: float = C.ACTIVE_CAMERA_FOVY) -> None:
    """Add the 7-DoF camera arm carrying the active RGB-D camera and its 7 position actuators.

    The camera and the IK site `cam_camera_center` share one frame (MuJoCo camera convention).
    """
    mount = C.CAMERA_MOUNT
    p = mount.prefix
    roll = _build_shoulder_chain(spec, mount)

    w1 = roll.add_body(name=f"{p}wrist_1_link", pos=list(C.CAM_WRIST_1_OFFSET), gravcomp=1.0)
    _add_hinge(w1, f"{p}wrist_1", (0, 1, 0), C.CAM_WRIST_1)
    _capsule_between(w1, f"{p}wrist_1_geom", (0, 0, 0), C.CAM_WRIST_2_OFFSET, 0.018, 0.1, rgba=_JOINT_RGBA)

    w2 = w1.add_body(name=f"{p}wrist_2_link", pos=list(C.CAM_WRIST_2_OFFSET), gravcomp=1.0)
    _add_hinge(w2, f"{p}wrist_2", (1, 0, 0), C.CAM_WRIST_2)
    _capsule_between(w2, f"{p}wrist_2_geom", (0, 0, 0), C.CAM_WRIST_3_OFFSET, 0.016, 0.08, rgba=_JOINT_RGBA)

    w3 = w2.add_body(name=f"{p}wrist_3_link", pos=list(C.CAM_WRIST_3_OFFSET), gravcomp=1.0)
    _add_hinge(w3, f"{p}wrist_3", (0, 0, 1), C.CAM_WRIST_3)
    cam_pos = list(C.CAM_CENTER_OFFSET)
    cam_quat = camera_mount_quat()
    # Camera housing (a stereo-camera-sized box) sits behind the optical centre.
    _robot_geom(w3, f"{p}housing_geom", rgba=_CAM_RGBA, type=mujoco.mjtGeom.mjGEOM_BOX,
                size=[0.015, 0.09, 0.015], pos=[cam_pos[0] - 0.012, 0, cam_pos[2]],
                quat=list(quat_from_axis_angle((0, 1, 0), C.CAM_MOUNT_PITCH)), mass=0.1)
    w3.add_camera(name=C.ACTIVE_CAMERA, pos=cam_pos, quat=list(cam_quat), fovy=fovy)
    w3.add_site(
        name=f"{p}camera_center", pos=cam_pos, quat=list(cam_quat), size=[0.005, 0, 0], group=C.GROUP_HIDDEN
    )

    for joint, cls in zip(C.CAMERA_ARM_JOINTS, C.CAMERA_ARM_CLASSES):
        _add_position_actuator(spec, f"{p}{joint}", f"{p}{joint}", cls.kp, 0.0, cls.range, cls.forcerange)

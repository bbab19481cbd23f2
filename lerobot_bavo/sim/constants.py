"""Robot constants mirrored from the public AV-ALOHA / ALOHA 2 numbers (their MJCF models and docs).

Only numbers carry over; the model itself is built by our own MjSpec code in `robot.py` and
`scene.py`. Units: metres, radians, kilograms, seconds. Frames: the base frame B is the world
frame, origin on the table top, +z up, +y away from the operator (the camera arm sits at -y).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# --------------------------------------------------------------------------------------------
# Timing
# --------------------------------------------------------------------------------------------
PHYSICS_DT = 0.002  # s, MuJoCo timestep
CONTROL_SUBSTEPS = 20  # physics steps per control step
CONTROL_DT = PHYSICS_DT * CONTROL_SUBSTEPS  # 0.04 s
CONTROL_HZ = 25  # 1 / CONTROL_DT

# --------------------------------------------------------------------------------------------
# Table (collision box; the top surface is z = 0)
# --------------------------------------------------------------------------------------------
TABLE_HALF_SIZE = (0.61, 0.37, 0.1)
TABLE_CENTER_Z = -TABLE_HALF_SIZE[2]  # top exactly at z = 0 (AV-ALOHA: -0.1009, top at -0.9 mm)


@dataclass(frozen=True)
class JointClass:
    """Dynamics of one joint class (Menagerie ALOHA 2 system-identified values)."""

    range: tuple[float, float]
    kp: float
    damping: float
    armature: float = 0.0
    frictionloss: float = 0.0
    forcerange: tuple[float, float] | None = None


WAIST = JointClass((-3.14158, 3.14158), kp=43, damping=5.76, forcerange=(-35, 35))
SHOULDER = JointClass(
    (-1.5, 1.25664), kp=265, damping=20, armature=0.395, frictionloss=2.0, forcerange=(-144, 144)
)
ELBOW = JointClass(
    (-1.76278, 1.6057), kp=227, damping=18.49, armature=0.383, frictionloss=1.15, forcerange=(-59, 59)
)
FOREARM_ROLL = JointClass((-1.57, 1.57), kp=78, damping=6.78, armature=0.14, forcerange=(-22, 22))
WRIST_ANGLE = JointClass((-1.8675, 2.23402), kp=37, damping=6.28, armature=0.008, forcerange=(-35, 35))
WRIST_ROTATE = JointClass((-3.14158, 3.14158), kp=10.4, damping=1.2, forcerange=(-35, 35))

# Parallel-jaw finger (slide joint, metres). Each finger's pad sits `q` from the gripper's centre
# plane, so the gap between pads is 2 q minus the pad thickness overlap defined in robot.py.
FINGER_RANGE = (0.0, 0.041)
FINGER_CTRL_RANGE = (0.002, 0.037)
FINGER_KP = 2000.0
FINGER_KV = 124.0
FINGER_DAMPING = 40.0
FINGER_ARMATURE = 0.243
FINGER_FORCE_LIMIT = 60.0  # N; keeps the grip firm without crushing through contacts


def gripper_to_finger(g: np.ndarray | float) -> np.ndarray | float:
    """Normalised gripper command g in [0, 1] (1 = open) -> finger slide position in metres."""
    return FINGER_CTRL_RANGE[0] + (FINGER_CTRL_RANGE[1] - FINGER_CTRL_RANGE[0]) * g


def finger_to_gripper(q: np.ndarray | float) -> np.ndarray | float:
    """Finger slide position in metres -> normalised gripper opening (1 = open)."""
    return (q - FINGER_CTRL_RANGE[0]) / (FINGER_CTRL_RANGE[1] - FINGER_CTRL_RANGE[0])


# --------------------------------------------------------------------------------------------
# Kinematics (each offset is from the previous joint's frame, in that frame, metres)
# --------------------------------------------------------------------------------------------
WAIST_OFFSET = (0.0, 0.0, 0.079)
SHOULDER_OFFSET = (0.0, 0.0, 0.04805)
ELBOW_OFFSET = (0.05955, 0.0, 0.3)
FOREARM_ROLL_OFFSET = (0.2, 0.0, 0.0)
WRIST_ANGLE_OFFSET = (0.1, 0.0, 0.0)
WRIST_ROTATE_OFFSET = (0.069744, 0.0, 0.0)
# Gripper centre (the point midway between the finger pads) past the wrist_rotate joint.
GRIPPER_CENTER_OFFSET = (0.12, 0.0, 0.0)

# Camera-arm wrist (AV-ALOHA 7-DoF arm): a pitch, a roll and a yaw joint after forearm_roll.
CAM_WRIST_1_OFFSET = (0.1, 0.0, 0.0)  # pitch (axis +y of the arm frame)
CAM_WRIST_2_OFFSET = (0.07, 0.000161, 0.0)  # roll (axis +x)
CAM_WRIST_3_OFFSET = (0.04125, 0.0, 0.02475)  # yaw (axis +z)
CAM_CENTER_OFFSET = (0.0, 0.0, 0.04325)  # camera centre along wrist_3's axis
# Our camera mount tilts the optical axis down by this angle relative to the wrist_3 frame's
# +x so that the home pose looks at the middle of the workspace (our own design choice).
CAM_MOUNT_PITCH = 0.55

CAM_WRIST_1 = WRIST_ANGLE
CAM_WRIST_2 = WRIST_ROTATE
CAM_WRIST_3 = WRIST_ROTATE


@dataclass(frozen=True)
class ArmMount:
    """Where an arm's base sits in the base frame."""

    prefix: str
    pos: tuple[float, float, float]
    yaw: float  # rad, about +z


LEFT_MOUNT = ArmMount("left_", (-0.469, 0.032, 0.02), 0.0)
RIGHT_MOUNT = ArmMount("right_", (0.469, 0.032, 0.02), math.pi)
CAMERA_MOUNT = ArmMount("cam_", (0.0, -0.513, 0.02), math.pi / 2)

MANIPULATOR_JOINTS = ("waist", "shoulder", "elbow", "forearm_roll", "wrist_angle", "wrist_rotate")
CAMERA_ARM_JOINTS = ("waist", "shoulder", "elbow", "forearm_roll", "wrist_1", "wrist_2", "wrist_3")
MANIPULATOR_CLASSES = (WAIST, SHOULDER, ELBOW, FOREARM_ROLL, WRIST_ANGLE, WRIST_ROTATE)
CAMERA_ARM_CLASSES = (WAIST, SHOULDER, ELBOW, FOREARM_ROLL, CAM_WRIST_1, CAM_WRIST_2, CAM_WRIST_3)

# --------------------------------------------------------------------------------------------
# State / action layout (21): left 6 + gripper, right 6 + gripper, camera arm 7
# --------------------------------------------------------------------------------------------
ACTION_DIM = 21
LEFT_ARM = slice(0, 6)
LEFT_GRIPPER = 6
RIGHT_ARM = slice(7, 13)
RIGHT_GRIPPER = 13
CAMERA_ARM = slice(14, 21)
GRIPPER_INDICES = (LEFT_GRIPPER, RIGHT_GRIPPER)
# Names of the 21 state / action entries, in order (the datasets' `names`; policies recognise BAVO's action by
# them).
ACTION_NAMES = tuple(
    [f"left_{j}" for j in (*MANIPULATOR_JOINTS, "gripper")]
    + [f"right_{j}" for j in (*MANIPULATOR_JOINTS, "gripper")]
    + [f"cam_{j}" for j in CAMERA_ARM_JOINTS]
)

MANIPULATOR_HOME = (0.0, -0.082, 1.06, 0.0, -0.953, 0.0)
GRIPPER_HOME = 1.0
CAMERA_ARM_HOME = (0.0, -0.6, 0.5, 0.0, 0.5, 0.0, 0.0)  # AV-ALOHA MIDDLE_POSE
HOME_ACTION = np.array(
    [*MANIPULATOR_HOME, GRIPPER_HOME, *MANIPULATOR_HOME, GRIPPER_HOME, *CAMERA_ARM_HOME], dtype=np.float64
)


def action_bounds() -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper bounds of the 21-dim absolute joint-target action (true joint limits)."""
    man_lo = [c.range[0] for c in MANIPULATOR_CLASSES]
    man_hi = [c.range[1] for c in MANIPULATOR_CLASSES]
    cam_lo = [c.range[0] for c in CAMERA_ARM_CLASSES]
    cam_hi = [c.range[1] for c in CAMERA_ARM_CLASSES]
    lo = np.array([*man_lo, 0.0, *man_lo, 0.0, *cam_lo], dtype=np.float32)
    hi = np.array([*man_hi, 1.0, *man_hi, 1.0, *cam_hi], dtype=np.float32)
    return lo, hi


# --------------------------------------------------------------------------------------------
# Active camera (RGB-D). Intrinsics are versioned with the env id (v0: fovy 66.21 deg).
# --------------------------------------------------------------------------------------------
ACTIVE_CAMERA = "cam_active"
ACTIVE_CAMERA_FOVY = 66.21  # degrees, AV-ALOHA 2024 ZED mini vertical field of view
THIRD_PERSON_CAMERA = "third_person"

# Geom groups: 0 static world, 1 robot, 2 task objects, 4 benchmark occluder (dropped in
# counterfactual renders), 5 hidden markers/regions (never rendered).
GROUP_WORLD = 0
GROUP_ROBOT = 1
GROUP_OBJECT = 2
GROUP_OCCLUDER = 4
GROUP_HIDDEN = 5
# Every geom group MuJoCo has (mjNGROUP = 6) but the robot's: hidden, they leave a render of the robot model
# alone (the self-filter, `envs.pointcloud.robot_pixel_mask`).
NON_ROBOT_GROUPS = tuple(g for g in range(6) if g != GROUP_ROBOT)

"""Operator input -> end-effector targets -> the env's 21 joint targets, through our IK.

Everything here is deterministic: the same sequence of per-tick inputs, from the same env state,
gives the same actions bit for bit. That is what makes an input log replayable (`replay.py`).

Frames: the base (world) frame, metres. The operator stands on the camera arm's side of the
table (y < 0) looking along +y, as the third-person view does: +x is the operator's right,
+y away from the operator, +z up.

One tick's input (`TickInput`, what the page sends and the log stores):
    keys: keyboard keys held now (lower-case `KeyboardEvent.key`, " " for space, "shift");
    taps: keys / gamepad buttons pressed since the previous tick (edge events: arm selection,
        gripper toggle, look-at toggle), in order;
    pad: the first gamepad's axes (4 floats, standard mapping) or None;
    xr: the WebXR poses (`head`, `left`, `right`: [x, y, z, qx, qy, qz, qw] in the XR reference
        space, y up) and `left_trigger` / `right_trigger` in [0, 1], or None.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import mujoco
import numpy as np

from lerobot_bavo.sim import constants as C

ARMS = ("left", "right", "camera")
LINEAR_SPEED = 0.15  # m/s at full command
FINE_FACTOR = 0.3  # with shift held (or the gamepad's B button)
YAW_SPEED = 1.0  # rad/s
PITCH_SPEED = 0.8  # rad/s (camera arm, free mode)
GRIPPER_SPEED = 4.0  # gripper opening units per second (analog triggers)
PAD_DEADZONE = 0.15
CAMERA_MAX_JOINT_SPEED = 1.5  # rad/s, as the experts' camera controller
# Commanded end-effector positions stay inside this box (base frame, m): above the table top,
# within the table's extent plus a margin.
REACH_LOW = np.array([-0.75, -0.6, 0.01])
REACH_HIGH = np.array([0.75, 0.5, 0.8])
LOOK_AT_MIN_DISTANCE = 0.12  # m, the viewpoint never comes closer than this to its look-at point

# Held key -> (axis, sign) of the commanded velocity: x, y, z, yaw, pitch.
MOTION_KEYS = {
    "d": (0, 1.0), "a": (0, -1.0),
    "w": (1, 1.0), "s": (1, -1.0),
    "r": (2, 1.0), "f": (2, -1.0),
    "q": (3, 1.0), "e": (3, -1.0),
    "t": (4, 1.0), "g": (4, -1.0),
}
ARM_KEYS = {"1": "left", "2": "right", "3": "camera"}
GRIPPER_KEY = " "
LOOK_AT_KEY = "l"
# Gamepad (standard mapping) buttons, sent as taps "pad<i>" / held as "pad<i>".
PAD_GRIPPER, PAD_FINE, PAD_LOOK_AT, PAD_PREV_ARM, PAD_NEXT_ARM = "pad0", "pad1", "pad3", "pad4", "pad5"

CONTROLS_HELP = """\
Controls (one arm at a time; the base frame as seen from the operator side / third-person view):
  1 / 2 / 3      select the left arm, the right arm, the camera arm
  W / S          move away from / towards you (+y / -y)
  A / D          move left / right (-x / +x)
  R / F          move up / down (+z / -z)
  Q / E          yaw left / right (about the vertical); camera in look-at mode: orbit the look-at point
  T / G          camera arm in free mode: pitch up / down
  Space          toggle the selected gripper (open / closed)
  L              camera arm: toggle look-at mode (keeps looking at the workspace point under the image centre)
  Shift (held)   fine motion (x0.3)
  N  start an episode     Enter  save it     Backspace  discard it     Z  discard and re-record the same seed
  X  stop the episode here (then save or discard)
Gamepad (browser Gamepad API, standard mapping): left stick x/y, right stick y = z, right stick x = yaw,
  A = gripper, B (held) = fine, Y = look-at mode, LB / RB = previous / next arm.
WebXR (where the browser offers it): the headset pose drives the camera arm, the controllers the
  left and right arms (relative to their poses when the session started), triggers close the grippers."""


@dataclass
class TickInput:
    """One control tick's operator input (see the module docstring)."""

    keys: tuple[str, ...] = ()
    taps: tuple[str, ...] = ()
    pad: tuple[float, ...] | None = None
    xr: dict | None = None
    seq: int = 0  # the page's input sequence number (latency measurement only; never affects the action)
    stop: bool = False  # the operator ended the episode at this tick

    def to_json(self) -> dict:
        out = {"keys": list(self.keys), "taps": list(self.taps), "seq": self.seq}
        if self.stop:
            out["stop"] = True
        if self.pad is not None:
            out["pad"] = list(self.pad)
        if self.xr is not None:
            out["xr"] = self.xr
        return out

    @classmethod
    def from_json(cls, d: dict) -> TickInput:
        keys = tuple(sorted(str(k).lower() for k in d.get("keys", ())))
        taps = tuple(str(k).lower() for k in d.get("taps", ()))
        pad = d.get("pad")
        pad = None if pad is None else tuple(float(v) for v in list(pad)[:4])
        xr = d.get("xr")
        return cls(
            keys=keys,
            taps=taps,
            pad=pad,
            xr=xr if isinstance(xr, dict) else None,
            seq=int(d.get("seq", 0)),
            stop=bool(d.get("stop", False)),
        )


def motion_command(inp: TickInput) -> np.ndarray:
    """Commanded velocity fractions (5,): x, y, z, yaw, pitch in [-1, 1] (keys and gamepad sticks)."""
    v = np.zeros(5)
    for k in inp.keys:
        if k in MOTION_KEYS:
            axis, sign = MOTION_KEYS[k]
            v[axis] += sign
    if inp.pad is not None and len(inp.pad) >= 4:
        lx, ly, rx, ry = (float(a) if abs(a) > PAD_DEADZONE else 0.0 for a in inp.pad[:4])
        v += [lx, -ly, -ry, -rx, 0.0]  # stick up is negative in the Gamepad API
    v = np.clip(v, -1.0, 1.0)
    if "shift" in inp.keys or PAD_FINE in inp.keys:
        v *= FINE_FACTOR
    return v


def rot_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rot_axis(axis, angle: float) -> np.ndarray:
    """Rotation matrix of `angle` about the unit vector `axis` (Rodrigues)."""
    k = np.asarray(axis, float)
    k = k / np.linalg.norm(k)
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * K @ K


def look_rotation(pos, target) -> np.ndarray:
    """Camera-site rotation (MuJoCo camera axes: x right, y up, -z forward) looking from `pos` at `target`."""
    fwd = np.asarray(target, float) - np.asarray(pos, float)
    fwd = fwd / np.linalg.norm(fwd)
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    if np.linalg.norm(right) < 1e-6:  # looking straight down / up
        right = np.array([1.0, 0.0, 0.0])
    right = right / np.linalg.norm(right)
    up = np.cross(right, fwd)
    return np.column_stack([right, up, -fwd])


def quat_to_mat(q_xyzw) -> np.ndarray:
    x, y, z, w = (float(v) for v in q_xyzw)
    out = np.zeros(9)
    mujoco.mju_quat2Mat(out, np.array([w, x, y, z]) / np.linalg.norm([w, x, y, z]))
    return out.reshape(3, 3)


# WebXR reference space (x right, y up, -z forward, the user facing -z) -> base frame (x right, y away, z up).
XR_TO_BASE = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def xr_pose_to_base(pose) -> tuple[np.ndarray, np.ndarray]:
    """A WebXR pose [x, y, z, qx, qy, qz, qw] -> (position, rotation) expressed in base-frame axes."""
    p = XR_TO_BASE @ np.asarray(pose[:3], float)
    R = XR_TO_BASE @ quat_to_mat(pose[3:7]) @ XR_TO_BASE.T
    return p, R


def yaw_of(R: np.ndarray) -> float:
    """Heading of a rotation's x axis about the vertical."""
    return float(np.arctan2(R[1, 0], R[0, 0]))


@dataclass
class ArmTarget:
    """Commanded end-effector pose, joint target and gripper of one arm."""

    pos: np.ndarray
    rot: np.ndarray
    q: np.ndarray
    gripper: float = 1.0
    look_at: np.ndarray | None = None  # camera arm in look-at mode
    goal_q: np.ndarray | None = None  # camera arm: IK solution still being approached (joint-rate limit)


@dataclass
class TeleopController:
    """Turns per-tick operator input into the env's 21-dim action through our IK.

    Create it with `TeleopController.from_env(env)` right after `env.reset()`. `step(inp)` applies
    one tick: arm selection and toggles from `inp.taps`, then the selected arm's motion (position
    and yaw; pitch and look-at for the camera arm), or the WebXR poses when `inp.xr` is given.
    An arm whose target leaves its reach stops at the IK's best pose (no wind-up).
    """

    env: object
    arms: dict[str, ArmTarget] = field(default_factory=dict)
    active: str = "right"
    look_at_mode: bool = False
    xr_reference: dict | None = None
    camera_moved: bool = False  # the camera arm was commanded to move this tick

    @classmethod
    def from_env(cls, env, active: str = "right") -> TeleopController:
        env = env.unwrapped
        q = env.joint_state()
        kin = env.kinematics
        arms = {}
        for name, sl, grip in (("left", C.LEFT_ARM, C.LEFT_GRIPPER), ("right", C.RIGHT_ARM, C.RIGHT_GRIPPER),
                               ("camera", C.CAMERA_ARM, None)):
            qa = q[sl].copy()
            pos, rot = kin[name].fk(qa)
            arms[name] = ArmTarget(pos, rot, qa, 1.0 if grip is None else float(np.clip(q[grip], 0.0, 1.0)))
        return cls(env=env, arms=arms, active=active)

    # ------------------------------------------------------------------ one tick
    def step(self, inp: TickInput) -> np.ndarray:
        self.camera_moved = False
        for tap in inp.taps:
            self._tap(tap)
        if inp.xr is not None:
            self._xr(inp.xr)
        else:
            self.xr_reference = None
            v = motion_command(inp)
            if np.any(v != 0.0):
                self._move(self.active, v)
        cam = self.arms["camera"]
        if cam.goal_q is not None and not self.camera_moved:  # keep approaching the last camera goal
            self._rate_limit_camera(cam.goal_q)
        return self.action()

    def action(self) -> np.ndarray:
        a = np.empty(C.ACTION_DIM)
        a[C.LEFT_ARM] = self.arms["left"].q
        a[C.LEFT_GRIPPER] = self.arms["left"].gripper
        a[C.RIGHT_ARM] = self.arms["right"].q
        a[C.RIGHT_GRIPPER] = self.arms["right"].gripper
        a[C.CAMERA_ARM] = self.arms["camera"].q
        return a

    def _tap(self, tap: str) -> None:
        if tap in ARM_KEYS:
            self.active = ARM_KEYS[tap]
        elif tap in (PAD_PREV_ARM, PAD_NEXT_ARM):
            step = 1 if tap == PAD_NEXT_ARM else -1
            self.active = ARMS[(ARMS.index(self.active) + step) % len(ARMS)]
        elif tap in (GRIPPER_KEY, PAD_GRIPPER) and self.active != "camera":
            arm = self.arms[self.active]
            arm.gripper = 0.0 if arm.gripper > 0.5 else 1.0
        elif tap in (LOOK_AT_KEY, PAD_LOOK_AT):
            self.set_look_at(not self.look_at_mode)

    def set_look_at(self, on: bool) -> None:
        """Enter (at the workspace point under the image centre) or leave the camera's look-at mode."""
        cam = self.arms["camera"]
        self.look_at_mode = bool(on)
        cam.look_at = self.point_under_image_centre() if on else None
        if on:
            self.active = "camera"

    def point_under_image_centre(self) -> np.ndarray:
        """First surface hit by the ray through the active image's centre (the table plane, or 0.5 m ahead,
        else)."""
        env = self.env
        cam_id = env.model.camera(C.ACTIVE_CAMERA).id
        origin = env.data.cam_xpos[cam_id].copy()
        fwd = -env.data.cam_xmat[cam_id].reshape(3, 3)[:, 2]
        geomid = np.zeros(1, dtype=np.int32)
        groups = np.zeros(6, dtype=np.uint8)
        groups[[C.GROUP_WORLD, C.GROUP_OBJECT]] = 1  # not the robot, not the occluder
        dist = mujoco.mj_ray(env.model, env.data, origin, fwd, groups, 1, -1, geomid)
        if dist < 0 or dist > 2.0:
            dist = -origin[2] / fwd[2] if fwd[2] < -1e-3 else 0.5
        return origin + min(float(dist), 2.0) * fwd

    def _move(self, name: str, v: np.ndarray) -> None:
        dt = C.CONTROL_DT
        arm = self.arms[name]
        pos = np.clip(arm.pos + LINEAR_SPEED * dt * v[:3], REACH_LOW, REACH_HIGH)
        dyaw = YAW_SPEED * dt * v[3]
        if name != "camera":
            self._solve(name, pos, rot_z(dyaw) @ arm.rot)
            return
        self.camera_moved = True
        if self.look_at_mode and arm.look_at is not None:
            p = arm.look_at
            pos = p + rot_z(dyaw) @ (pos - p)
            off = pos - p
            if np.linalg.norm(off) < LOOK_AT_MIN_DISTANCE:
                pos = p + off / max(np.linalg.norm(off), 1e-9) * LOOK_AT_MIN_DISTANCE
            self._solve(name, pos, look_rotation(pos, p))
        else:
            rot = rot_z(dyaw) @ arm.rot
            rot = rot_axis(rot[:, 0], PITCH_SPEED * dt * v[4]) @ rot
            self._solve(name, pos, rot)

    def _solve(self, name: str, pos: np.ndarray, rot: np.ndarray) -> None:
        arm = self.arms[name]
        kin = self.env.kinematics[name]
        if name == "camera":
            res = kin.ik(pos, rot, q_init=arm.goal_q if arm.goal_q is not None else arm.q, rot_weight=0.5,
                         nullspace_gain=0.2)
            self._rate_limit_camera(res.qpos)
        else:
            res = kin.ik(pos, rot, q_init=arm.q)
            arm.q = res.qpos
        if res.converged:
            arm.pos, arm.rot = np.asarray(pos, float), np.asarray(rot, float)
        else:  # out of reach: the target is where the arm can really be (no wind-up)
            arm.pos, arm.rot = kin.fk(res.qpos)

    def _rate_limit_camera(self, goal_q: np.ndarray) -> None:
        """Step the camera arm's joint target towards `goal_q` at most CAMERA_MAX_JOINT_SPEED."""
        cam = self.arms["camera"]
        max_delta = CAMERA_MAX_JOINT_SPEED * C.CONTROL_DT
        cam.q = cam.q + np.clip(goal_q - cam.q, -max_delta, max_delta)
        cam.goal_q = None if np.array_equal(cam.q, goal_q) else goal_q

    # ------------------------------------------------------------------ WebXR
    def _xr(self, xr: dict) -> None:
        """Headset -> camera arm, controllers -> left / right arms, each relative to its pose at the first
        XR tick (a clutch: the robot keeps its pose when the session starts)."""
        poses = {
            dev: xr_pose_to_base(xr[dev]) for dev in ("head", "left", "right") if xr.get(dev) is not None
        }
        if self.xr_reference is None:
            self.xr_reference = {
                dev: (poses[dev], self.arms[arm].pos.copy(), self.arms[arm].rot.copy())
                for dev, arm in (("head", "camera"), ("left", "left"), ("right", "right")) if dev in poses}
        for dev, arm in (("head", "camera"), ("left", "left"), ("right", "right")):
            if dev not in poses or dev not in self.xr_reference:
                continue
            (p0, R0), arm_p0, arm_R0 = self.xr_reference[dev]
            p, R = poses[dev]
            pos = np.clip(arm_p0 + (p - p0), REACH_LOW, REACH_HIGH)
            if arm == "camera":
                rot = (R @ R0.T) @ arm_R0  # the head's rotation since the start, applied to the camera
                self.camera_moved = True
            else:
                rot = rot_z(yaw_of(R) - yaw_of(R0)) @ arm_R0  # position and yaw, as with the keyboard
            self._solve(arm, pos, rot)
        for side in ("left", "right"):
            trig = xr.get(f"{side}_trigger")
            if trig is not None:
                self.arms[side].gripper = float(np.clip(1.0 - float(trig), 0.0, 1.0))

"""Forward kinematics and damped-least-squares IK for each arm, using MuJoCo's own Jacobians.

All poses are in the base (world) frame, metres. Each `ArmKinematics` owns a scratch `MjData`,
so FK/IK never touches the live simulation state.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from lerobot_bavo.sim import constants as C


def rotation_error(target_rot: np.ndarray, current_rot: np.ndarray) -> np.ndarray:
    """Axis-angle vector (base frame, radians) rotating `current_rot` onto `target_rot`."""
    q_t = np.zeros(4)
    q_c = np.zeros(4)
    mujoco.mju_mat2Quat(q_t, np.ascontiguousarray(target_rot).reshape(9))
    mujoco.mju_mat2Quat(q_c, np.ascontiguousarray(current_rot).reshape(9))
    err = np.zeros(3)
    # mju_subQuat gives the rotation, in current's local frame, that maps current to target.
    mujoco.mju_subQuat(err, q_t, q_c)
    return current_rot @ err


@dataclass
class IKResult:
    qpos: np.ndarray
    position_error: float  # m
    rotation_error: float  # rad
    converged: bool


class ArmKinematics:
    """FK / IK for one arm's joints and an end-effector site.

    Args:
        model: compiled BAVO model.
        joint_names: the arm's joints in action order.
        site_name: end-effector site (gripper centre or camera centre).
        home: joint configuration used as the null-space / regularisation target.
    """

    def __init__(self, model: mujoco.MjModel, joint_names: list[str], site_name: str, home,
                 posture_weights=None):
        self.model = model
        self.data = mujoco.MjData(model)
        ids = [model.joint(n).id for n in joint_names]
        self.qpos_adr = np.array([model.jnt_qposadr[i] for i in ids])
        self.dof_adr = np.array([model.jnt_dofadr[i] for i in ids])
        self.lower = model.jnt_range[ids, 0].copy()
        self.upper = model.jnt_range[ids, 1].copy()
        self.site_id = model.site(site_name).id
        self.home = np.asarray(home, dtype=np.float64)
        # Per-joint regularisation towards `home` inside the least-squares step. A small weight on
        # forearm_roll keeps the roll-pitch-roll wrist from flipping through its singularity
        # (wrist_angle = 0, where forearm_roll and wrist_rotate are collinear).
        self.posture_weights = (
            np.zeros(len(ids)) if posture_weights is None else np.asarray(posture_weights, float)
        )
        self._jacp = np.zeros((3, model.nv))
        self._jacr = np.zeros((3, model.nv))

    @property
    def n(self) -> int:
        return len(self.qpos_adr)

    def _set(self, q: np.ndarray) -> None:
        self.data.qpos[self.qpos_adr] = q
        mujoco.mj_kinematics(self.model, self.data)

    def fk(self, q) -> tuple[np.ndarray, np.ndarray]:
        """Site position (3,) and rotation matrix (3, 3) in the base frame for joints `q`."""
        self._set(np.asarray(q, dtype=np.float64))
        return self.data.site_xpos[self.site_id].copy(), self.data.site_xmat[self.site_id].reshape(
            3, 3
        ).copy()

    def _solve(self, q, target_pos, target_rot, rot_weight, damping, nullspace_gain, iters, pos_tol, rot_tol,
               max_step, posture_weights):
        pos_err = rot_err = np.inf
        for _ in range(iters):
            self._set(q)
            mujoco.mj_comPos(self.model, self.data)
            x = self.data.site_xpos[self.site_id]
            e_p = target_pos - x
            pos_err = float(np.linalg.norm(e_p))
            mujoco.mj_jacSite(self.model, self.data, self._jacp, self._jacr, self.site_id)
            if target_rot is None:
                err = e_p
                J = self._jacp[:, self.dof_adr]
                rot_err = 0.0
            else:
                e_r = rotation_error(np.asarray(target_rot), self.data.site_xmat[self.site_id].reshape(3, 3))
                rot_err = float(np.linalg.norm(e_r))
                err = np.concatenate([e_p, rot_weight * e_r])
                J = np.vstack([self._jacp[:, self.dof_adr], rot_weight * self._jacr[:, self.dof_adr]])
            if pos_err < pos_tol and rot_err < rot_tol:
                break
            # min |J dq - err|^2 + damping |dq|^2 + sum_k w_k (q_k + dq_k - home_k)^2
            H = J.T @ J + np.diag(damping + posture_weights)
            dq = np.linalg.solve(H, J.T @ err + posture_weights * (self.home - q))
            if nullspace_gain > 0.0:
                N = np.eye(self.n) - np.linalg.pinv(J) @ J
                dq += N @ (nullspace_gain * (self.home - q))
            step = np.max(np.abs(dq))
            if step > max_step:
                dq *= max_step / step
            q = np.clip(q + dq, self.lower, self.upper)
        else:
            # the loop ran out: measure the final iterate
            self._set(q)
            x = self.data.site_xpos[self.site_id]
            pos_err = float(np.linalg.norm(target_pos - x))
            if target_rot is not None:
                rot_err = float(
                    np.linalg.norm(
                        rotation_error(
                            np.asarray(target_rot), self.data.site_xmat[self.site_id].reshape(3, 3)
                        )
                    )
                )
        return q, pos_err, rot_err

    def fk_matrix(self, q) -> np.ndarray:
        pos, rot = self.fk(q)
        T = np.eye(4)
        T[:3, :3] = rot
        T[:3, 3] = pos
        return T

    def ik(
        self,
        target_pos,
        target_rot=None,
        q_init=None,
        *,
        rot_weight: float = 0.3,
        damping: float = 0.02,
        nullspace_gain: float = 0.0,
        max_iters: int = 60,
        pos_tol: float = 5e-4,
        rot_tol: float = 5e-3,
        max_step: float = 0.25,
        refine_iters: int = 20,
    ) -> IKResult:
        """Damped least squares on [position; rot_weight * orientation] error.

        `target_rot` None solves position only. Joint limits are enforced by clipping each
        iterate. `nullspace_gain` pulls redundant DoF towards `home` (useful for the 7-DoF arm).
        """
        q = np.array(self.home if q_init is None else q_init, dtype=np.float64)
        target_pos = np.asarray(target_pos, dtype=np.float64)
        # Stage 1 includes the posture term (it steers the wrist through its singularity); the
        # posture term biases the optimum slightly, so stage 2 refines without it from there.
        q, pos_err, rot_err = self._solve(q, target_pos, target_rot, rot_weight, damping, nullspace_gain,
                                          max_iters, pos_tol, rot_tol, max_step, self.posture_weights)
        if self.posture_weights.any() and not (pos_err < pos_tol and rot_err < rot_tol):
            q, pos_err, rot_err = self._solve(q, target_pos, target_rot, rot_weight, damping, nullspace_gain,
                                              refine_iters, pos_tol, rot_tol, max_step, np.zeros(self.n))
        return IKResult(q, pos_err, rot_err, bool(pos_err < 5 * pos_tol and rot_err < 5 * rot_tol))


MANIPULATOR_POSTURE_WEIGHTS = (0.0, 0.0, 0.0, 0.02, 0.0, 0.0)


def make_arm_kinematics(model: mujoco.MjModel) -> dict[str, ArmKinematics]:
    """Kinematics for the three arms: keys "left", "right" (gripper centres) and "camera"."""
    return {
        "left": ArmKinematics(
            model,
            [f"left_{j}" for j in C.MANIPULATOR_JOINTS],
            "left_gripper_center",
            C.MANIPULATOR_HOME,
            posture_weights=MANIPULATOR_POSTURE_WEIGHTS,
        ),
        "right": ArmKinematics(
            model,
            [f"right_{j}" for j in C.MANIPULATOR_JOINTS],
            "right_gripper_center",
            C.MANIPULATOR_HOME,
            posture_weights=MANIPULATOR_POSTURE_WEIGHTS,
        ),
        "camera": ArmKinematics(
            model, [f"cam_{j}" for j in C.CAMERA_ARM_JOINTS], "cam_camera_center", C.CAMERA_ARM_HOME
        ),
    }

"""MuJoCo <-> Pinocchio state conventions for the floating-base AlienGo.

Conventions (MuJoCo free joint vs Pinocchio free flyer)
-------------------------------------------------------
* qpos = [p_w (3), quat (w, x, y, z), q_legs (12)];  Pinocchio q = [p_w, quat (x, y, z, w), q_legs].
* qvel = [v_w (3): base-origin velocity in the WORLD frame, omega_b (3): BASE frame, qd (12)];
  Pinocchio v = [v_b = R^T v_w, omega_b, qd] (both base parts in the base frame).
  So ``qvel = T v`` with ``T = blockdiag(R, I_3, I_12)``.
* Leg coordinates are identical in both, hence leg blocks of M (``M_mj = T^-T M_pin T^-1``),
  leg entries of generalized forces and leg columns of Jacobians coincide.
* "Zero acceleration" differs. MuJoCo's ``qfrc_bias`` and ``mj_jacDot @ qvel`` are taken at
  qacc = d(qvel)/dt = 0, i.e. world linear acceleration 0 and body angular acceleration 0.
  Since v_b = R^T v_w:  d(v_b)/dt = -omega_b x v_b + R^T d(v_w)/dt,  so MuJoCo's qacc = 0 is the
  Pinocchio acceleration  ``a0 = [-omega_b x v_b, 0_3, 0_12]``  (see :func:`zero_qacc_acceleration`).
  Pinocchio's ``nle`` (taken at v_dot = 0) differs from qfrc_bias on the leg rows by
  ``M_pin[leg, 0:3] (omega_b x v_b)``; we use ``rnea(q, v, a0)`` instead, which is MuJoCo's bias
  exactly. Likewise ``Jdot qdot`` here is the foot acceleration at a0 (MuJoCo's convention), so
  ``foot_acc = J_full qacc_mj + Jdot_qdot`` with the MuJoCo qacc.
"""

from __future__ import annotations

import numpy as np

from dls_quadruped.robots.aliengo import constants as C

NQ_MJ = 7 + C.NUM_JOINTS
"""MuJoCo qpos size (19)."""
NV_MJ = 6 + C.NUM_JOINTS
"""MuJoCo qvel size (18)."""


def quat_wxyz_to_matrix(quat_wxyz: np.ndarray) -> np.ndarray:
    """Rotation matrices of (not necessarily unit) quaternions.

    Args:
        quat_wxyz: (B, 4) quaternions (w, x, y, z), MuJoCo order; normalised here.

    Returns:
        (B, 3, 3) rotation matrices (base -> world for a base orientation).
    """
    return np.ascontiguousarray(_rotation_batch_last(np.asarray(quat_wxyz, dtype=np.float64).T).transpose(2, 0, 1))


def _rotation_batch_last(quat_t: np.ndarray) -> np.ndarray:
    """(4, B) quaternions (w, x, y, z), any norm -> (3, 3, B) rotation matrices (batch last)."""
    w, x, y, z = quat_t / np.sqrt((quat_t * quat_t).sum(axis=0))
    return np.array(
        [
            [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)],
            [2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)],
            [2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)],
        ]
    )


def mujoco_to_pinocchio(qpos: np.ndarray, qvel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Convert MuJoCo free-joint coordinates to Pinocchio free-flyer coordinates.

    Args:
        qpos: (B, 19) [p_w (m), quat (w, x, y, z), 12 joint angles (rad)].
        qvel: (B, 18) [v_w (m/s) world frame, omega_b (rad/s) base frame, 12 joint rates].

    Returns:
        q: (B, 19) [p_w, unit quat (x, y, z, w), joints].
        v: (B, 18) [v_b = R^T v_w, omega_b, joint rates] (Pinocchio's LOCAL base velocity).
    """
    qpos, qvel = check_state(qpos, qvel)
    q, v = np.empty_like(qpos), np.empty_like(qvel)
    mujoco_to_pinocchio_into(qpos, qvel, q, v)
    return q, v


def pinocchio_to_mujoco(q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`mujoco_to_pinocchio`.

    Args:
        q: (B, 19) [p_w, quat (x, y, z, w), joints].
        v: (B, 18) [v_b base frame, omega_b, joint rates].

    Returns:
        qpos: (B, 19) [p_w, unit quat (w, x, y, z), joints]; qvel: (B, 18) [v_w, omega_b, rates].
    """
    q, v = np.asarray(q, dtype=np.float64), np.asarray(v, dtype=np.float64)
    qpos, qvel = q.copy(), v.copy()
    quat = q[:, [6, 3, 4, 5]]
    qpos[:, 3:7] = quat / np.linalg.norm(quat, axis=-1, keepdims=True)
    R = quat_wxyz_to_matrix(qpos[:, 3:7])
    qvel[:, 0:3] = (R @ v[:, 0:3, None])[..., 0]  # v_w = R v_b
    return qpos, qvel


def zero_qacc_acceleration(v: np.ndarray) -> np.ndarray:
    """Pinocchio acceleration v_dot that corresponds to MuJoCo's qacc = 0.

    qacc = 0 means d(v_w)/dt = 0 and d(omega_b)/dt = 0; with v_b = R^T v_w,
    d(v_b)/dt = -omega_b x v_b, so  a0 = [-omega_b x v_b, 0_3, 0_12].

    Args:
        v: (B, 18) Pinocchio velocity [v_b, omega_b, joint rates].

    Returns:
        (B, 18) acceleration a0.
    """
    a0 = np.zeros_like(v)
    a0[:, 0:3] = -np.cross(v[:, 3:6], v[:, 0:3])
    return a0


def check_state(qpos: np.ndarray, qvel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    qpos = np.asarray(qpos, dtype=np.float64)
    qvel = np.asarray(qvel, dtype=np.float64)
    if qpos.ndim != 2 or qpos.shape[1] != NQ_MJ or qvel.ndim != 2 or qvel.shape[1] != NV_MJ:
        raise ValueError(
            f"expected MuJoCo qpos (B, {NQ_MJ}) and qvel (B, {NV_MJ}) arrays, got {qpos.shape} and {qvel.shape}"
        )
    if qpos.shape[0] != qvel.shape[0]:
        raise ValueError(f"qpos and qvel batch sizes differ: {qpos.shape[0]} vs {qvel.shape[0]}")
    return qpos, qvel


def mujoco_to_pinocchio_into(qpos: np.ndarray, qvel: np.ndarray, q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Fill preallocated q (B, 19), v (B, 18); returns the base rotations, batch last (3, 3, B)."""
    quat_t = qpos[:, 3:7].T  # (4, B): w, x, y, z
    quat_t = quat_t / np.sqrt((quat_t * quat_t).sum(axis=0))
    Rt = _rotation_batch_last(quat_t)
    q[:, 0:3] = qpos[:, 0:3]
    q[:, 3:6] = quat_t[1:4].T  # x, y, z
    q[:, 6] = quat_t[0]  # w
    q[:, 7:] = qpos[:, 7:]
    vw = qvel[:, 0:3].T
    v[:, 0:3] = (Rt[0] * vw[0] + Rt[1] * vw[1] + Rt[2] * vw[2]).T  # v_b = R^T v_w
    v[:, 3:] = qvel[:, 3:]
    return Rt

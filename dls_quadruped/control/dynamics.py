"""Pinocchio leg dynamics for the low-level controller (thesis 2.2.5-2.2.6).

For B robots given in MuJoCo's coordinates, :class:`LegDynamics` returns per leg the
quantities the swing law ``tau = M J^-1 (a - Jdot qdot) + h`` and the stance law
``tau = -J^T F`` need: the leg blocks of the joint-space mass matrix, the bias torques
h = C(q, qdot) qdot + G(q), the world-aligned 3x3 foot Jacobians, ``Jdot qdot`` and the foot
positions/velocities.

Conventions: ``control/conventions.py`` (MuJoCo free joint vs Pinocchio free flyer, and why
the bias and ``Jdot qdot`` are taken at MuJoCo's zero acceleration ``a0``).

Algorithm and speed
-------------------
Pinocchio has no batched entry points for M, J or dJ, so there is ONE Python loop over robots
(in :meth:`LegDynamics._compute`) with two calls per robot: ``computeJointJacobiansTimeVariation``
(J and dJ of all joints, world frame) and ``crba`` (M), copied out through array views of
``data`` taken once at construction. Placements are never read from ``data`` (``data.oMi[i]``
costs ~0.9 us per access, 4 feet ~3.6 us per robot); the foot centres come from a batched numpy
forward kinematics of each leg's 3-joint chain, using the joint placements, axes and foot frames
of the same Pinocchio model (no numbers duplicated). The bias h comes from ``rneaInParallel``
over the whole batch at a0 (GIL released; one thread by default, since the backend's shard
processes already use every core). The foot-point Jacobian shift, the leg-block extraction and
the ``Jdot qdot`` assembly are vectorised numpy after the loop, laid out batch-last so every op
runs over contiguous memory, with preallocated work buffers (fresh ~0.4 MB temporaries were
page-faulted on every call and cost ~1 us per robot).

CPU time per robot, B = 1024, on the 2-core development VM while other jobs were running
(``python -m dls_quadruped.bench.dynamics``): total ~8.3-8.6 us, of which the Pinocchio loop
~4.6 us (3.5 us in the two calls, ~1.1 us copying M, J, dJ), rneaInParallel ~1.8 us, numpy ~2 us.
Alternatives measured in the same run: computeAllTerms + reading M, nle, J, dJ ~8.4-8.7 us (before
any foot work), the per-foot getFrameJacobian / getFrameClassicalAcceleration path ~10.7 us,
a nonLinearEffects loop for h ~2.5 us (vs 1.8 us for rneaInParallel with one thread; two threads
did not help on this loaded 2-core machine).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin

from dls_quadruped.control.conventions import (
    NQ_MJ,
    NV_MJ,
    check_state,
    mujoco_to_pinocchio_into,
)
from dls_quadruped.robots.aliengo import constants as C

_AXIS_OF_JOINT = {"JointModelRX": (1.0, 0.0, 0.0), "JointModelRY": (0.0, 1.0, 0.0), "JointModelRZ": (0.0, 0.0, 1.0)}


# ---------------------------------------------------------------------------- results
@dataclass
class LegDynamicsResult:
    """Per-leg dynamics of B robots (float64 numpy; legs FL, FR, RL, RR; joints hip, thigh, calf).

    The arrays are buffers owned by :class:`LegDynamics` and overwritten by its next ``compute``:
    copy what must outlive that call.

    Attributes:
        M_leg: (B, 4, 3, 3) [kg m^2] leg diagonal blocks of the 18x18 joint-space mass matrix.
        h_leg: (B, 4, 3) [N m] leg entries of h = C(q, qdot) qdot + G(q) (MuJoCo's qfrc_bias).
        J_leg: (B, 4, 3, 3) [m] foot-centre translational Jacobian w.r.t. the leg's joint rates,
            world-aligned: foot_vel_w = J_leg qd_leg + (base motion terms).
        Jdot_qdot: (B, 4, 3) [m/s^2] foot-centre acceleration at MuJoCo qacc = 0 (base terms included).
        foot_pos_w: (B, 4, 3) [m] foot sphere centres, world frame.
        foot_vel_w: (B, 4, 3) [m/s] foot-centre velocities (full Jacobian times qvel), world frame.
    """

    M_leg: np.ndarray
    h_leg: np.ndarray
    J_leg: np.ndarray
    Jdot_qdot: np.ndarray
    foot_pos_w: np.ndarray
    foot_vel_w: np.ndarray

    @classmethod
    def empty(cls, batch: int) -> LegDynamicsResult:
        n = C.NUM_LEGS
        return cls(
            M_leg=np.zeros((batch, n, 3, 3)),
            h_leg=np.zeros((batch, n, 3)),
            J_leg=np.zeros((batch, n, 3, 3)),
            Jdot_qdot=np.zeros((batch, n, 3)),
            foot_pos_w=np.zeros((batch, n, 3)),
            foot_vel_w=np.zeros((batch, n, 3)),
        )


# ---------------------------------------------------------------------------- model layout
@dataclass(frozen=True)
class _LegChains:
    """Constant per-leg kinematic data read from the Pinocchio model (leg l, chain joint k).

    Attributes:
        R_place: (4, 3, 3, 3) joint placement rotations in the parent joint frame.
        t_place: (4, 3, 3) [m] joint placement translations in the parent joint frame.
        axis: (4, 3, 3) unit joint axes in the joint frame.
        foot_in_calf: (4, 3) [m] foot frame origin in the calf joint frame.
    """

    R_place: np.ndarray
    t_place: np.ndarray
    axis: np.ndarray
    foot_in_calf: np.ndarray


def _leg_chains(model: pin.Model) -> _LegChains:
    """Read and validate the leg layout (free flyer, then FL, FR, RL, RR x hip, thigh, calf)."""
    names = tuple(model.names)
    if model.nq != NQ_MJ or model.nv != NV_MJ or model.joints[1].shortname() != "JointModelFreeFlyer":
        raise ValueError(f"expected a free-flyer model with nq={NQ_MJ}, nv={NV_MJ}; got nq={model.nq}, nv={model.nv}")
    if names[2:] != C.JOINT_NAMES:
        raise ValueError(f"Pinocchio joint order {names[2:]} differs from constants.JOINT_NAMES {C.JOINT_NAMES}")
    R_place, t_place, axis, foot = (np.zeros((4, 3, 3, 3)), np.zeros((4, 3, 3)), np.zeros((4, 3, 3)), np.zeros((4, 3)))
    for leg in range(C.NUM_LEGS):
        for k in range(3):
            jid = 2 + 3 * leg + k
            parent = 1 if k == 0 else jid - 1
            if model.parents[jid] != parent:
                raise ValueError(f"joint {names[jid]} has parent {names[model.parents[jid]]}, expected {names[parent]}")
            joint = model.joints[jid]
            kind = joint.shortname()
            if kind in _AXIS_OF_JOINT:
                axis[leg, k] = _AXIS_OF_JOINT[kind]
            elif kind == "JointModelRevoluteUnaligned":
                axis[leg, k] = np.asarray(joint.extract().axis)
            else:
                raise ValueError(f"joint {names[jid]} is {kind}; only revolute leg joints are supported")
            if model.idx_vs[jid] != 6 + 3 * leg + k:
                raise ValueError(
                    f"joint {names[jid]} has velocity index {model.idx_vs[jid]}, expected {6 + 3 * leg + k}"
                )
            R_place[leg, k] = model.jointPlacements[jid].rotation
            t_place[leg, k] = model.jointPlacements[jid].translation
        fname = C.FOOT_NAMES[leg]
        if not model.existFrame(fname):
            raise ValueError(f"foot frame {fname!r} missing from the Pinocchio model")
        frame = model.frames[model.getFrameId(fname)]
        if frame.parentJoint != 2 + 3 * leg + 2:
            raise ValueError(f"foot frame {fname} is attached to {names[frame.parentJoint]}, expected the calf joint")
        foot[leg] = frame.placement.translation
    return _LegChains(R_place=R_place, t_place=t_place, axis=axis, foot_in_calf=foot)


# ---------------------------------------------------------------------------- dynamics
class LegDynamics:
    """Batched per-leg dynamics from Pinocchio; one instance per process/shard.

    Owns a Pinocchio model/data pair (and a ModelPool for the batched RNEA), built from
    one MJCF so MuJoCo and Pinocchio see the same robot.

    Args:
        model_path: MJCF of the robot (default: the AlienGo in constants.MJCF_PATH).
        num_threads: threads for ``pinocchio.rneaInParallel`` (1 inside worker processes).
    """

    def __init__(self, model_path: str | Path = C.MJCF_PATH, num_threads: int = 1):
        if num_threads < 1:
            raise ValueError(f"num_threads must be >= 1, got {num_threads}")
        self.model: pin.Model = pin.buildModelFromMJCF(str(model_path))
        self.data: pin.Data = self.model.createData()
        self.num_threads = num_threads
        self._pool = pin.ModelPool(self.model, num_threads)
        self._chains = _leg_chains(self.model)
        # Views into data's Eigen storage, taken once (the storage never reallocates).
        self._M_view, self._J_view, self._dJ_view = self.data.M, self.data.J, self.data.dJ
        cols = 6 + np.arange(C.NUM_JOINTS).reshape(C.NUM_LEGS, 3)
        self._leg_cols = cols  # (4, 3) velocity indices of each leg's joints
        rows, cols_ = np.broadcast_arrays(cols[:, :, None], cols[:, None, :])  # (4, 3, 3) block indices
        self._blk_flat = (np.minimum(rows, cols_) * NV_MJ + np.maximum(rows, cols_)).ravel()  # into M.ravel()
        # (18, 4) velocity support of each foot: the 6 base coordinates and the leg's own joints
        self._support = np.zeros((NV_MJ, C.NUM_LEGS))
        self._support[:6] = 1.0
        self._support[cols, np.arange(C.NUM_LEGS)[:, None]] = 1.0
        # chain position k -> i if every leg's joint k turns about the base axis e_i, else -1
        self._principal_axis = [-1, -1, -1]
        for k in range(3):
            for i in range(3):
                if np.array_equal(self._chains.axis[:, k], np.tile(np.eye(3)[i], (C.NUM_LEGS, 1))):
                    self._principal_axis[k] = i
        self._place_is_identity = [bool(np.allclose(self._chains.R_place[:, k], np.eye(3), atol=0.0)) for k in range(3)]
        self._batch = -1

    def _allocate(self, batch: int) -> None:
        self._batch = batch
        self._q = np.zeros((batch, NQ_MJ))
        self._v = np.zeros((batch, NV_MJ))
        self._M = np.zeros((batch, NV_MJ, NV_MJ))
        self._JdJ = np.zeros((batch, 12, NV_MJ))  # rows 0:6 data.J, 6:12 data.dJ (world frame)
        self._h = np.zeros((batch, NV_MJ))
        self._a0 = np.zeros((batch, NV_MJ))
        # Work buffers: temporaries above ~128 kB would be mmap-ed and page-faulted on every call.
        self._v_support = np.zeros((batch, NV_MJ, C.NUM_LEGS))
        self._prod = np.zeros((batch, 12, C.NUM_LEGS))
        self._T = np.zeros((12, C.NUM_LEGS, batch))
        self._Jc = np.zeros((6, C.NUM_JOINTS, batch))
        self._Jp = np.zeros((3, C.NUM_LEGS, 3, batch))
        self.out = LegDynamicsResult.empty(batch)

    def compute(self, qpos: np.ndarray, qvel: np.ndarray) -> LegDynamicsResult:
        """Leg dynamics of B robots.

        Args:
            qpos: (B, 19) MuJoCo qpos [p_w (m), quat (w, x, y, z), 12 joints (rad)].
            qvel: (B, 18) MuJoCo qvel [v_w (m/s) world, omega_b (rad/s) base frame, 12 joint rates].

        Returns:
            The reused result buffers (see :class:`LegDynamicsResult`).
        """
        qpos, qvel = check_state(qpos, qvel)
        B = qpos.shape[0]
        if B != self._batch:
            self._allocate(B)
        # A robot with a non-finite state gets non-finite terms (in its own rows only); the caller
        # flags and resets it, so numpy's per-step warnings about it are silenced here.
        with np.errstate(invalid="ignore", over="ignore"):
            return self._compute(qpos, qvel)

    def _compute(self, qpos: np.ndarray, qvel: np.ndarray) -> LegDynamicsResult:
        B = qpos.shape[0]
        q, v, out = self._q, self._v, self.out
        Rt = mujoco_to_pinocchio_into(qpos, qvel, q, v)  # (3, 3, B) base -> world

        # The one Python loop over robots: Pinocchio has no batched M, J or dJ.
        model, data = self.model, self.data
        jac_dot, crba = pin.computeJointJacobiansTimeVariation, pin.crba
        M_view, J_view, dJ_view = self._M_view, self._J_view, self._dJ_view
        for qi, vi, Mi, Ji, dJi in zip(q, v, self._M, self._JdJ[:, :6], self._JdJ[:, 6:]):
            jac_dot(model, data, qi, vi)  # data.J, data.dJ (world frame), oMi
            crba(model, data, qi)  # data.M
            Mi[...] = M_view
            Ji[...] = J_view
            dJi[...] = dJ_view

        # h = rnea(q, v, a0) = MuJoCo's qfrc_bias (a0 <=> qacc_mj = 0); (nq, B) column-major views.
        a0 = self._a0
        a0[:, 0:3] = -np.cross(v[:, 3:6], v[:, 0:3])  # zero_qacc_acceleration(v), in place
        pin.rneaInParallel(self.num_threads, self._pool, q.T, v.T, a0.T, self._h.T)
        out.h_leg[...] = self._h[:, 6:].reshape(B, C.NUM_LEGS, 3)

        # M leg blocks, gathered from the upper triangle only (crba may leave the lower one empty).
        np.take(self._M.reshape(B, -1), self._blk_flat, axis=1, out=out.M_leg.reshape(B, -1))

        self._kinematics(q, v, a0, Rt, out)
        return out

    def _kinematics(self, q: np.ndarray, v: np.ndarray, a0: np.ndarray, Rt: np.ndarray, out: LegDynamicsResult) -> None:
        """Foot positions, velocities, Jdot qdot and leg Jacobians from the copied J, dJ (vectorised).

        Rt: (3, 3, B) base rotations (batch last); the other arguments as in :meth:`compute`.
        """
        B = q.shape[0]
        # Below, arrays are laid out batch-last, (component, leg, B): every component slice is a
        # contiguous (4, B) block, which makes each numpy op ~4x cheaper than on (B, 4) slices.
        P = self._foot_positions(q, Rt)  # (3, 4, B) [m]
        out.foot_pos_w[...] = P.transpose(2, 1, 0)

        # Calf twists (v_o, omega) and their derivatives at v_dot = a0, world frame, from the
        # spatial Jacobians restricted to each foot's support (base + own leg): one batched matmul.
        np.multiply(v[:, :, None], self._support, out=self._v_support)
        np.matmul(self._JdJ, self._v_support, out=self._prod)  # (B, 12, 4): rows [J v, dJ v]
        T = self._T  # (12, 4, B)
        np.copyto(T, self._prod.transpose(1, 2, 0))
        # + J a0: a0 is base-linear only, and the free flyer's base-linear columns of J are [R; 0]
        a = a0[:, 0:3].T
        for i in range(3):
            T[6 + i] += Rt[i, 0] * a[0] + Rt[i, 1] * a[1] + Rt[i, 2] * a[2]
        p0, p1, p2 = P
        w0, w1, w2 = T[3], T[4], T[5]  # omega
        al0, al1, al2 = T[9], T[10], T[11]  # alpha = d(omega)/dt
        # point velocity p_dot = v_o + omega x p
        pd0 = T[0] + w1 * p2 - w2 * p1
        pd1 = T[1] + w2 * p0 - w0 * p2
        pd2 = T[2] + w0 * p1 - w1 * p0
        out.foot_vel_w[...] = np.stack((pd0, pd1, pd2)).transpose(2, 1, 0)
        # point acceleration p_ddot = a_o + alpha x p + omega x p_dot
        pdd0 = T[6] + al1 * p2 - al2 * p1 + w1 * pd2 - w2 * pd1
        pdd1 = T[7] + al2 * p0 - al0 * p2 + w2 * pd0 - w0 * pd2
        pdd2 = T[8] + al0 * p1 - al1 * p0 + w0 * pd1 - w1 * pd0
        out.Jdot_qdot[...] = np.stack((pdd0, pdd1, pdd2)).transpose(2, 1, 0)

        # point Jacobian column = J_lin + J_ang x p, for each leg's own joint columns
        np.copyto(self._Jc, self._JdJ[:, :6, 6:].transpose(1, 2, 0))
        Jc = self._Jc.reshape(6, C.NUM_LEGS, 3, B)
        q0, q1, q2 = p0[:, None], p1[:, None], p2[:, None]  # (4, 1, B) against (4, 3 joints, B)
        Jp = self._Jp  # (3 xyz, 4 legs, 3 joints, B)
        Jp[0] = Jc[0] + Jc[4] * q2 - Jc[5] * q1
        Jp[1] = Jc[1] + Jc[5] * q0 - Jc[3] * q2
        Jp[2] = Jc[2] + Jc[3] * q1 - Jc[4] * q0
        out.J_leg[...] = Jp.transpose(3, 1, 0, 2)

    def _foot_positions(self, q: np.ndarray, Rt: np.ndarray) -> np.ndarray:
        """Batched forward kinematics of the foot centres, (3, 4, B) [m] world frame (xyz, leg, robot).

        Evaluated from the foot inwards on vectors only, with the model's joint placements and
        axes: x <- t_place_k + R_place_k Rot(axis_k, q_k) x for calf, thigh, hip, then
        p = p_b + R_b x (reading data.oMi per robot would cost ~4 us). Rt: (3, 3, B) base
        rotations; each component is a contiguous (4, B) array.
        """
        ch = self._chains
        B = q.shape[0]
        ang = q[:, 7:].T.reshape(C.NUM_LEGS, 3, B)  # (leg, joint, B), a copy
        x = [np.broadcast_to(ch.foot_in_calf[:, i, None], (C.NUM_LEGS, B)) for i in range(3)]
        for k in (2, 1, 0):
            s, c = np.sin(ang[:, k]), np.cos(ang[:, k])
            i = self._principal_axis[k]
            if i >= 0:  # rotation about base axis e_i: plane rotation of the other two components
                j, l = (i + 1) % 3, (i + 2) % 3
                x[j], x[l] = c * x[j] - s * x[l], s * x[j] + c * x[l]
            else:  # Rodrigues: x + s (a x x) + (1 - c) a x (a x x)
                a = ch.axis[:, k, :, None].transpose(1, 0, 2)  # (3, 4, 1)
                ax = _cross3(a, x)
                aax = _cross3(a, ax)
                x = [x[n] + s * ax[n] + (1.0 - c) * aax[n] for n in range(3)]
            if not self._place_is_identity[k]:
                Rp = ch.R_place[:, k, :, :, None]  # (4, 3, 3, 1)
                x = [Rp[:, n, 0] * x[0] + Rp[:, n, 1] * x[1] + Rp[:, n, 2] * x[2] for n in range(3)]
            x = [x[n] + ch.t_place[:, k, n, None] for n in range(3)]
        R = Rt[:, :, None, :]  # (3, 3, 1, B)
        return np.stack([q[:, n] + R[n, 0] * x[0] + R[n, 1] * x[1] + R[n, 2] * x[2] for n in range(3)])


def _cross3(a: list[np.ndarray] | np.ndarray, b: list[np.ndarray]) -> list[np.ndarray]:
    """a x b with both given as 3 component arrays (broadcasting)."""
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]

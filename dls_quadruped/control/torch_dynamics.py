"""Device-agnostic batched leg terms in torch: the GPU path's ``LegTerms``.

:class:`TorchLegDynamics` builds the :class:`~dls_quadruped.control.lowlevel.LegTerms` that
``LowLevelController.compute`` takes from four batched tensors on any device, in float64 or
float32, with no Python loop over robots:

* ``qpos`` (B, 19), ``qvel`` (B, 18): MuJoCo's free-joint coordinates (``control/conventions.py``);
* ``qM``: MuJoCo's joint-space inertia, either sparse as C MuJoCo's ``data.M`` (``data.qM`` before
  MuJoCo 4) / MuJoCo Warp's sparse ``qM``, (B, nM) or (B, 1, nM), or dense (B, nv, nv) as
  ``mj_fullM`` / MuJoCo Warp's dense ``qM`` (its default for nv < 60);
* ``qfrc_bias`` (B, nv): MuJoCo's bias forces.

The mass-matrix leg blocks and the bias rows are read from MuJoCo's own ``qM`` and ``qfrc_bias``
(:func:`leg_mass_blocks`, :func:`leg_bias`); the foot kinematics (foot centres, their velocities,
the world-aligned 3x3 leg Jacobians and ``Jdot qdot``) are computed here
(:func:`foot_kinematics`), from kinematic parameters read from the ``mujoco.MjModel``
(:func:`leg_chain_params`: body offsets and orientations, joint axes, anchors and reference
angles, foot-site offsets), so no robot number is typed in this file.

Conventions (the same as ``control/dynamics.py`` ``LegDynamics``; tests/control/test_torch_dynamics.py)
-------------------------------------------------------------------------------------------------------
* Leg blocks of M and leg rows of the bias are the same in MuJoCo's free-joint coordinates and in
  Pinocchio's free-flyer coordinates (``qvel = T v``, ``T = blockdiag(R, I_3, I_12)`` leaves the
  leg coordinates alone), so ``qM``'s leg blocks are ``LegDynamics.M_leg`` exactly.
* MuJoCo's ``qfrc_bias`` is the inverse dynamics at ``qacc = 0``: world-frame base linear
  acceleration 0 and body-frame angular acceleration 0. That is exactly the point
  ``a0 = [-omega_b x v_b, 0, 0]`` at which ``LegDynamics`` evaluates ``rnea``, so its leg rows
  ARE ``LegDynamics.h_leg`` (not Pinocchio's ``nle``, which is taken at ``v_dot = 0`` and differs
  on the leg rows by ``M_pin[leg, 0:3] (omega_b x v_b)``). The base rows differ only by the
  coordinate change: ``qfrc_bias[0:3] = R rnea(q, v, a0)[0:3]``, ``qfrc_bias[3:6] = rnea(...)[3:6]``.
* ``Jdot_qdot`` is the foot-centre acceleration at ``qacc = 0``, MuJoCo's ``mj_jacDot @ qvel``
  (``foot_acc = J_full qacc + Jdot_qdot``). At ``qacc = 0`` the base origin does not accelerate
  (``d v_w/dt = 0``) and neither does its angular velocity in the world frame
  (``d(R omega_b)/dt = R (omega_b x omega_b) + R d omega_b/dt = 0``).

Algorithm (foot kinematics)
---------------------------
Batched over (B, 4 legs), vectors only. Joint k turns body k by ``q_k - qpos0_k`` about its axis through
its anchor; in the parent's frame a point x of body k lies at ``A_k + Rp_k Rot(axis_k, q_k - qpos0_k)
(x - jp_k)`` (``A_k = t_k + Rp_k jp_k``: body offset t, orientation Rp, joint anchor jp in body k).
Positions: the foot, then the anchors ``a_k`` and axes ``z_k`` of the deeper joints, are carried from
the foot inwards to the base frame with Rodrigues' formula on vectors (no rotation matrices are
composed), then to the world with one batched product by the base rotation. Velocities and
accelerations at ``qacc = 0``: an outward recursion along each chain from the base origin through the
anchors to the foot with the rigid-body point rules ``v = v_ref + omega x d``,
``acc = acc_ref + alpha x d + omega x (omega x d)`` (d from the previous reference point, which is
fixed in the same body), and the body rates ``omega_k = omega_{k-1} + qd_k z_k``,
``alpha_k = alpha_{k-1} + qd_k (omega_{k-1} x z_k)`` (the axis turns with body k-1; ``qdd = 0``),
starting from ``v_w``, ``omega_w = R omega_b`` and zero accelerations. The leg Jacobian columns are
``z_k x (p_foot - a_k)``; the base columns (``J_base``, for MuJoCo's ``qvel[0:6]``) are
``[I_3, -[p_foot - p_base]x R]``. Everything is analytic (no finite differences) and elementwise over
robots, so a robot with a non-finite state spoils only its own rows.

CPU time of the leg terms against ``LegDynamics.compute``: docs/benchmarks.md "Leg dynamics from MuJoCo".
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
import torch

from dls_quadruped.control.lowlevel import LegTerms
from dls_quadruped.robots.aliengo import constants as C

NQ = 7 + C.NUM_JOINTS
NV = 6 + C.NUM_JOINTS


# ---------------------------------------------------------------------------- model parameters
@dataclass(frozen=True)
class LegChainParams:
    """Kinematic parameters of the 4 legs read from a ``mujoco.MjModel`` (leg l, chain joint k; float64).

    Attributes:
        body_pos: (4, 3, 3) [m] body k's origin in its parent body's frame (``body_pos``).
        body_rot: (4, 3, 3, 3) body k's orientation in its parent body's frame (``body_quat``).
        axis: (4, 3, 3) unit joint axes in body k's frame (``jnt_axis``).
        anchor: (4, 3, 3) [m] joint anchors in body k's frame (``jnt_pos``).
        qpos0: (4, 3) [rad] joint reference angles (``qpos0``: the body turns by ``q - qpos0``).
        foot: (4, 3) [m] foot-site (sphere centre) position in the calf body's frame (``site_pos``).
        qpos_adr: (4, 3) qpos addresses of the leg joints; dof_adr: (4, 3) their qvel/dof addresses.
        nv: the model's number of dofs.
        qM_adr: (4, 3, 3) addresses of the leg blocks' entries in C MuJoCo's sparse inertia (``data.M``,
            ``data.qM`` before MuJoCo 4; both triangles map to the one stored entry).
    """

    body_pos: np.ndarray
    body_rot: np.ndarray
    axis: np.ndarray
    anchor: np.ndarray
    qpos0: np.ndarray
    foot: np.ndarray
    qpos_adr: np.ndarray
    dof_adr: np.ndarray
    nv: int
    qM_adr: np.ndarray


def leg_chain_params(model: mujoco.MjModel) -> LegChainParams:
    """Read and validate the AlienGo layout from a MuJoCo model (robot-only MJCF or a scene).

    The base body ``constants.BASE_BODY_NAME`` must carry the free joint at qpos 0..6 / dofs 0..5;
    leg joints are hinges named ``constants.JOINT_NAMES``, one per body, chained base -> hip ->
    thigh -> calf, at qpos ``7 + i`` and dofs ``6 + i``; the foot sites ``constants.FOOT_NAMES`` sit on
    the calves.

    Raises:
        ValueError: the model does not have that layout.
    """
    base = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, C.BASE_BODY_NAME)
    if base < 0:
        raise ValueError(f"base body {C.BASE_BODY_NAME!r} missing from the model")
    free = model.body_jntadr[base]
    if (model.body_jntnum[base] != 1 or model.jnt_type[free] != mujoco.mjtJoint.mjJNT_FREE
            or model.jnt_qposadr[free] != 0 or model.jnt_dofadr[free] != 0):
        raise ValueError(f"body {C.BASE_BODY_NAME!r} must carry the model's free joint at qpos 0 / dof 0")
    n = C.NUM_LEGS
    body_pos, body_rot = np.zeros((n, 3, 3)), np.zeros((n, 3, 3, 3))
    axis, anchor, qpos0 = np.zeros((n, 3, 3)), np.zeros((n, 3, 3)), np.zeros((n, 3))
    foot = np.zeros((n, 3))
    qpos_adr, dof_adr = np.zeros((n, 3), dtype=np.int64), np.zeros((n, 3), dtype=np.int64)
    for leg in range(n):
        parent = base
        for k in range(3):
            name = C.JOINT_NAMES[3 * leg + k]
            jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
            if jid < 0:
                raise ValueError(f"joint {name!r} missing from the model")
            if model.jnt_type[jid] != mujoco.mjtJoint.mjJNT_HINGE:
                raise ValueError(f"joint {name!r} is not a hinge")
            body = model.jnt_bodyid[jid]
            if model.body_parentid[body] != parent or model.body_jntnum[body] != 1:
                raise ValueError(f"joint {name!r} must be the only joint of a child of the previous link of its leg")
            qadr, dadr = int(model.jnt_qposadr[jid]), int(model.jnt_dofadr[jid])
            if qadr != 7 + 3 * leg + k or dadr != 6 + 3 * leg + k:
                raise ValueError(f"joint {name!r} has qpos/dof address {qadr}/{dadr}, expected "
                                 f"{7 + 3 * leg + k}/{6 + 3 * leg + k} (constants.JOINT_NAMES order)")
            body_pos[leg, k] = model.body_pos[body]
            rot = np.zeros(9)
            mujoco.mju_quat2Mat(rot, model.body_quat[body])
            body_rot[leg, k] = rot.reshape(3, 3)
            axis[leg, k] = model.jnt_axis[jid]
            anchor[leg, k] = model.jnt_pos[jid]
            qpos0[leg, k] = model.qpos0[qadr]
            qpos_adr[leg, k], dof_adr[leg, k] = qadr, dadr
            parent = body
        sid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, C.FOOT_NAMES[leg])
        if sid < 0 or model.site_bodyid[sid] != parent:
            raise ValueError(f"foot site {C.FOOT_NAMES[leg]!r} missing or not on the calf body")
        foot[leg] = model.site_pos[sid]
    return LegChainParams(body_pos=body_pos, body_rot=body_rot, axis=axis, anchor=anchor, qpos0=qpos0, foot=foot,
                          qpos_adr=qpos_adr, dof_adr=dof_adr, nv=int(model.nv), qM_adr=_qM_addresses(model, dof_adr))


def _qM_addresses(model: mujoco.MjModel, dof_adr: np.ndarray) -> np.ndarray:
    """(4, 3, 3) addresses in C MuJoCo's sparse inertia (``data.M``; ``data.qM`` before MuJoCo 4) of the leg blocks.

    Found by asking MuJoCo itself: with the sparse inertia ``e_a``, ``mj_fullM`` lights the dense
    entries stored at address a. No assumption on the sparse layout (it changed in MuJoCo 4).
    """
    data = mujoco.MjData(model)
    sparse = data.M if hasattr(data, "M") else data.qM
    dense = np.zeros((model.nv, model.nv))
    rows, cols = [], []
    for a in range(model.nM):
        sparse[:] = 0.0
        sparse[a] = 1.0
        try:
            mujoco.mj_fullM(model, data, dense)  # MuJoCo >= 4: reads data.M
        except TypeError:
            mujoco.mj_fullM(model, dense, sparse)  # older signature (dst, M)
        i, j = np.nonzero(np.tril(dense))
        if len(i) != 1:
            raise ValueError(f"sparse inertia address {a} maps to {len(i)} lower-triangle entries, expected 1")
        rows.append(int(i[0]))
        cols.append(int(j[0]))
    return qM_addresses_from_pairs(np.array(rows), np.array(cols), dof_adr)


def qM_addresses_from_pairs(rows: np.ndarray, cols: np.ndarray, dof_adr: np.ndarray) -> np.ndarray:
    """(4, 3, 3) sparse-inertia addresses of the leg blocks, given each stored entry's (row, col).

    For a sparse layout other than the C model's, e.g. MuJoCo Warp's sparse ``qM`` (its model's
    ``qM_fullm_i``, ``qM_fullm_j`` give the row and column of each element; their order follows
    MuJoCo Warp's version, not necessarily C MuJoCo 4's CSR order).

    Args:
        rows, cols: (nM,) dof row and column (row >= col) of each stored element.
        dof_adr: (4, 3) dof addresses of the leg joints (:attr:`LegChainParams.dof_adr`).
    """
    rows, cols = np.asarray(rows), np.asarray(cols)
    lo, hi = np.minimum(rows, cols), np.maximum(rows, cols)
    where = {(int(r), int(c)): a for a, (r, c) in enumerate(zip(hi, lo))}
    r = np.maximum(dof_adr[:, :, None], dof_adr[:, None, :])
    c = np.minimum(dof_adr[:, :, None], dof_adr[:, None, :])
    try:
        return np.vectorize(lambda i, j: where[(int(i), int(j))])(r, c).astype(np.int64)
    except KeyError as err:
        raise ValueError(f"leg block entry {err.args[0]} of the mass matrix is not stored in the sparse inertia "
                         "(legs must be serial chains)") from None


# ---------------------------------------------------------------------------- mass matrix and bias
def leg_mass_blocks(qM: torch.Tensor, params: LegChainParams, qM_adr: np.ndarray | None = None) -> torch.Tensor:
    """Leg blocks (B, 4, 3, 3) [kg m^2] of MuJoCo's joint-space inertia, in ``qM``'s dtype and device.

    Args:
        qM: sparse (B, nM) or (B, 1, nM) (C MuJoCo's ``data.M``; MuJoCo Warp's sparse ``qM``), or dense
            (B, nv, nv) (``mj_fullM``; MuJoCo Warp's dense ``qM``, its default for nv < 60); of a dense
            matrix only the lower triangle (row >= column: the child dof's row, the triangle MuJoCo
            stores) is read.
        params: from :func:`leg_chain_params` of the model that produced ``qM``.
        qM_adr: (4, 3, 3) sparse addresses of the leg blocks when the sparse layout is not C MuJoCo's
            (:func:`qM_addresses_from_pairs`); default ``params.qM_adr``.
    """
    qM = torch.as_tensor(qM)
    adr = params.qM_adr if qM_adr is None else np.asarray(qM_adr)
    return _leg_mass_blocks(qM, params.nv, _LegIndices(params.dof_adr, adr, qM.device))


class _LegIndices:
    """The leg-block index tensors of one model on one device (built once: a per-call upload of a numpy array
    is a host-to-device copy on a GPU).

    Attributes:
        dense_rows, dense_cols: (4, 3, 3) row >= column of each leg-block entry in a dense (nv, nv) inertia.
        sparse: (4, 3, 3) addresses of the entries in a sparse inertia; ``sparse_max`` the largest (a host int).
        dof: (4, 3) dof addresses of the leg joints (rows of ``qfrc_bias``).
    """

    def __init__(self, dof_adr: np.ndarray, qM_adr: np.ndarray, device: torch.device):
        self.dense_rows = torch.as_tensor(np.maximum(dof_adr[:, :, None], dof_adr[:, None, :]), device=device)
        self.dense_cols = torch.as_tensor(np.minimum(dof_adr[:, :, None], dof_adr[:, None, :]), device=device)
        self.sparse = torch.as_tensor(qM_adr, device=device)
        self.sparse_max = int(np.max(qM_adr))
        self.dof = torch.as_tensor(dof_adr, device=device)


def _leg_mass_blocks(qM: torch.Tensor, nv: int, idx: _LegIndices) -> torch.Tensor:
    """:func:`leg_mass_blocks` with the index tensors given (shape checks on the host only)."""
    if qM.ndim == 3 and tuple(qM.shape[1:]) == (nv, nv):
        return qM[:, idx.dense_rows, idx.dense_cols]
    if qM.ndim == 3 and qM.shape[1] == 1:
        qM = qM[:, 0]
    if qM.ndim != 2:
        raise ValueError(f"qM must be (B, nM), (B, 1, nM) or (B, {nv}, {nv}); got {tuple(qM.shape)}")
    if idx.sparse_max >= qM.shape[1]:
        raise ValueError(f"qM has {qM.shape[1]} entries per robot, fewer than the model's sparse inertia needs")
    return qM[:, idx.sparse]


def leg_bias(qfrc_bias: torch.Tensor, params: LegChainParams) -> torch.Tensor:
    """Leg rows (B, 4, 3) [N m] of MuJoCo's ``qfrc_bias`` (B, nv) = ``LegDynamics.h_leg`` (module doc)."""
    qfrc_bias = torch.as_tensor(qfrc_bias)
    return _leg_bias(qfrc_bias, params.nv, torch.as_tensor(params.dof_adr, device=qfrc_bias.device))


def _leg_bias(qfrc_bias: torch.Tensor, nv: int, dof: torch.Tensor) -> torch.Tensor:
    """:func:`leg_bias` with the (4, 3) dof-address tensor ``dof`` on ``qfrc_bias``'s device given."""
    if qfrc_bias.ndim != 2 or qfrc_bias.shape[1] != nv:
        raise ValueError(f"qfrc_bias must be (B, {nv}); got {tuple(qfrc_bias.shape)}")
    return qfrc_bias[:, dof]


# ---------------------------------------------------------------------------- kinematics
@dataclass
class FootKinematics:
    """Foot-centre kinematics of B robots (torch, the state's device and dtype; legs FL, FR, RL, RR).

    Attributes:
        foot_pos_w: (B, 4, 3) [m] foot centres, world frame.
        foot_vel_w: (B, 4, 3) [m/s] foot-centre velocities (full Jacobian times qvel), world frame.
        J_leg: (B, 4, 3, 3) [m] world-aligned Jacobian w.r.t. the leg's own joint rates (hip, thigh, calf).
        J_base: (B, 4, 3, 6) world-aligned Jacobian w.r.t. MuJoCo's base velocities ``qvel[0:6]``
            (v_w, then omega_b in the base frame).
        Jdot_qdot: (B, 4, 3) [m/s^2] foot-centre acceleration at MuJoCo's ``qacc = 0``.
    """

    foot_pos_w: torch.Tensor
    foot_vel_w: torch.Tensor
    J_leg: torch.Tensor
    J_base: torch.Tensor
    Jdot_qdot: torch.Tensor


def quat_wxyz_to_matrix(quat: torch.Tensor) -> torch.Tensor:
    """(..., 4) quaternions (w, x, y, z), any norm -> (..., 3, 3) rotation matrices."""
    w, x, y, z = (quat / quat.norm(dim=-1, keepdim=True)).unbind(-1)
    return torch.stack([
        1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y),
        2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x),
        2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y),
    ], dim=-1).unflatten(-1, (3, 3))


def _cross(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """a x b over the last axis (broadcasting)."""
    return torch.linalg.cross(a, b, dim=-1)


class _ParamTensors:
    """The chain parameters of one :class:`LegChainParams` as tensors of one device and dtype.

    Per joint k, in the frame of its parent (the base for k = 0): the anchor ``A_k = t_k + Rp_k jp_k`` and
    axis ``Rp_k axis_k``; a point x of body k is at ``A_k + Rp_k Rot(axis_k, q_k - qpos0_k) (x - jp_k)``.
    """

    def __init__(self, p: LegChainParams, device: torch.device, dtype: torch.dtype):
        def t(a: np.ndarray) -> torch.Tensor:
            return torch.as_tensor(a, dtype=dtype, device=device)

        anchor_parent = p.body_pos + np.einsum("lkij,lkj->lki", p.body_rot, p.anchor)  # (4, 3, 3)
        axis_parent = np.einsum("lkij,lkj->lki", p.body_rot, p.axis)
        self.axis = t(p.axis[:, None])  # (4, 1, 3 joints, 3): broadcasts over (B, 4, n, 3)
        self.body_rot = t(p.body_rot)  # (4, 3, 3, 3)
        self.rotated = [bool(np.any(p.body_rot[:, k] != np.eye(3))) for k in range(3)]
        self.jp = t(p.anchor)  # (4, 3, 3) joint anchors in their own body's frame
        self.anchor_parent, self.axis_parent = t(anchor_parent), t(axis_parent)
        self.foot_local = t(p.foot - p.anchor[:, 2])  # (4, 3) foot relative to the calf anchor, calf frame
        self.qpos0 = t(p.qpos0)
        self.has_qpos0 = bool(np.any(p.qpos0 != 0.0))
        self.leg_qpos = torch.as_tensor(p.qpos_adr.reshape(-1), device=device)
        self.leg_dof = torch.as_tensor(p.dof_adr.reshape(-1), device=device)


def _joint_to_parent(pt: _ParamTensors, k: int, s: torch.Tensor, c: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """``Rp_k Rot(axis_k, q_k) y`` for vectors y (B, 4, n, 3) of body k's frame (Rodrigues on vectors).

    s, c: (B, 4) sine and cosine of ``q_k - qpos0_k``.
    """
    a = pt.axis[:, :, k]  # (4, 1, 3)
    ay = _cross(a.expand_as(y), y)
    aay = _cross(a.expand_as(y), ay)
    y = y + s[:, :, None, None] * ay + (1.0 - c)[:, :, None, None] * aay
    if pt.rotated[k]:
        R = pt.body_rot[:, k, None]  # (4, 1, 3, 3)
        y = R[..., 0] * y[..., 0:1] + R[..., 1] * y[..., 1:2] + R[..., 2] * y[..., 2:3]
    return y


def foot_kinematics(qpos: torch.Tensor, qvel: torch.Tensor, pt: _ParamTensors) -> FootKinematics:
    """Foot kinematics from MuJoCo states (module doc "Algorithm"); see :meth:`TorchLegDynamics.kinematics`."""
    B, n = qpos.shape[0], C.NUM_LEGS
    R_b = quat_wxyz_to_matrix(qpos[:, 3:7])  # (B, 3, 3) base -> world
    p_b = qpos[:, 0:3]
    q = qpos[:, pt.leg_qpos].view(B, n, 3)
    qd = qvel[:, pt.leg_dof].view(B, n, 3)
    if pt.has_qpos0:
        q = q - pt.qpos0
    s, c = torch.sin(q), torch.cos(q)

    # Positions: the foot, the anchors and axes of the deeper joints, carried from the foot inwards to the base
    # frame, vectors only. Stack rows: [foot, anchor_2, anchor_1 | axis_2, axis_1] as they appear.
    foot = pt.foot_local.expand(B, n, 3).unsqueeze(2)  # (B, 4, 1, 3), relative to the calf anchor
    pts = _joint_to_parent(pt, 2, s[..., 2], c[..., 2], foot) + pt.anchor_parent[:, 2, None]  # body-1 frame
    pts = torch.cat([pts, pt.anchor_parent[:, 2, None].expand(B, n, 1, 3)], dim=2)  # [foot, anchor_2]
    dirs = pt.axis_parent[:, 2, None].expand(B, n, 1, 3)  # [axis_2]
    y = torch.cat([pts - pt.jp[:, 1, None], dirs], dim=2)
    y = _joint_to_parent(pt, 1, s[..., 1], c[..., 1], y)  # body-0 frame
    pts = torch.cat([y[:, :, 0:2] + pt.anchor_parent[:, 1, None], pt.anchor_parent[:, 1, None].expand(B, n, 1, 3)],
                    dim=2)  # [foot, anchor_2, anchor_1]
    dirs = torch.cat([y[:, :, 2:3], pt.axis_parent[:, 1, None].expand(B, n, 1, 3)], dim=2)  # [axis_2, axis_1]
    y = torch.cat([pts - pt.jp[:, 0, None], dirs], dim=2)
    y = _joint_to_parent(pt, 0, s[..., 0], c[..., 0], y)  # base frame
    y = torch.cat([y[:, :, 0:3] + pt.anchor_parent[:, 0, None], pt.anchor_parent[:, 0, None].expand(B, n, 1, 3),
                   y[:, :, 3:5], pt.axis_parent[:, 0, None].expand(B, n, 1, 3)], dim=2)
    # rows: foot, anchor_2, anchor_1, anchor_0 (relative to the base origin), axis_2, axis_1, axis_0 -> world
    w = (y.reshape(B, n * 7, 3) @ R_b.transpose(1, 2)).view(B, n, 7, 3)
    p_f = w[:, :, 0] + p_b.unsqueeze(1)
    r_f = w[:, :, 0]  # foot relative to the base origin, world-aligned
    anchors = w[:, :, 1:4].flip(2)  # (B, 4, 3 joints, 3) relative to the base origin
    axes = w[:, :, 4:7].flip(2)

    # Velocities and accelerations at qacc = 0 along the chain (reference point: base origin, then each anchor).
    ref = torch.zeros_like(r_f)
    v_ref = qvel[:, None, 0:3].expand(B, n, 3)
    acc_ref = torch.zeros_like(r_f)
    omega = (R_b @ qvel[:, 3:6, None]).view(B, 1, 3).expand(B, n, 3)
    alpha = torch.zeros_like(r_f)
    for k in range(4):
        point = anchors[:, :, k] if k < 3 else r_f
        d = point - ref
        w_d = _cross(omega, d)
        v_ref = v_ref + w_d
        acc_ref = acc_ref + _cross(alpha, d) + _cross(omega, w_d)
        if k < 3:
            z = axes[:, :, k]
            alpha = alpha + qd[:, :, k, None] * _cross(omega, z)
            omega = omega + qd[:, :, k, None] * z
            ref = point
    J_leg = _cross(axes, r_f.unsqueeze(2) - anchors).transpose(-1, -2)  # columns z_k x (p_f - a_k)
    # d v_f / d omega_b: omega_w x r = (R_b omega_b) x r, column j = R_b[:, j] x r
    J_ang = _cross(R_b.transpose(1, 2).unsqueeze(1), r_f.unsqueeze(2)).transpose(-1, -2)
    eye = torch.eye(3, dtype=qpos.dtype, device=qpos.device).expand(B, n, 3, 3)
    return FootKinematics(foot_pos_w=p_f, foot_vel_w=v_ref, J_leg=J_leg, J_base=torch.cat([eye, J_ang], dim=-1),
                          Jdot_qdot=acc_ref)


# ---------------------------------------------------------------------------- the LegTerms builder
class TorchLegDynamics:
    """Batched leg terms on any device: foot kinematics in torch, M and h from MuJoCo's own qM, qfrc_bias.

    Args:
        model: the ``mujoco.MjModel`` the states and (qM, qfrc_bias) belong to; default the robot-only
            MJCF ``constants.MJCF_PATH`` (a scene with terrain has the same robot layout and the same
            leg addresses).
        qM_pairs: (rows, cols) of each element of a sparse ``qM`` whose layout is not C MuJoCo's (MuJoCo
            Warp's ``m.qM_fullm_i``, ``m.qM_fullm_j``); None: C MuJoCo's layout (a dense qM needs none).
    """

    def __init__(self, model: mujoco.MjModel | None = None, qM_pairs: tuple[np.ndarray, np.ndarray] | None = None):
        if model is None:
            model = mujoco.MjModel.from_xml_path(str(C.MJCF_PATH))
        self.params = leg_chain_params(model)
        self.qM_adr = self.params.qM_adr if qM_pairs is None else qM_addresses_from_pairs(*qM_pairs,
                                                                                           self.params.dof_adr)
        self._tensors: dict[tuple[torch.device, torch.dtype], _ParamTensors] = {}
        self._indices: dict[torch.device, _LegIndices] = {}

    def _param_tensors(self, like: torch.Tensor) -> _ParamTensors:
        key = (like.device, like.dtype)
        if key not in self._tensors:
            self._tensors[key] = _ParamTensors(self.params, like.device, like.dtype)
        return self._tensors[key]

    @staticmethod
    def _check_state(qpos: torch.Tensor, qvel: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        qpos, qvel = torch.as_tensor(qpos), torch.as_tensor(qvel)
        if qpos.ndim != 2 or qpos.shape[1] != NQ or qvel.ndim != 2 or qvel.shape[1] != NV:
            raise ValueError(f"expected MuJoCo qpos (B, {NQ}) and qvel (B, {NV}), got {tuple(qpos.shape)} "
                             f"and {tuple(qvel.shape)}")
        if qpos.shape[0] != qvel.shape[0]:
            raise ValueError(f"qpos and qvel batch sizes differ: {qpos.shape[0]} vs {qvel.shape[0]}")
        if not qpos.is_floating_point() or qpos.dtype != qvel.dtype or qpos.device != qvel.device:
            raise ValueError(f"qpos and qvel must be floating tensors of one dtype and device, got "
                             f"{qpos.dtype}/{qpos.device} and {qvel.dtype}/{qvel.device}")
        return qpos, qvel

    def kinematics(self, qpos: torch.Tensor, qvel: torch.Tensor) -> FootKinematics:
        """Foot kinematics of B robots, in the state's device and dtype.

        Args:
            qpos: (B, 19) MuJoCo qpos [p_w (m), quat (w, x, y, z) (any norm), 12 joints (rad)].
            qvel: (B, 18) MuJoCo qvel [v_w (m/s) world, omega_b (rad/s) base frame, 12 joint rates].
        """
        qpos, qvel = self._check_state(qpos, qvel)
        return foot_kinematics(qpos, qvel, self._param_tensors(qpos))

    def terms(self, qpos: torch.Tensor, qvel: torch.Tensor, qM: torch.Tensor, qfrc_bias: torch.Tensor) -> LegTerms:
        """The controller's LegTerms from a MuJoCo (or MuJoCo Warp) state and its qM, qfrc_bias.

        ``qM`` and ``qfrc_bias`` must belong to this very (qpos, qvel): after ``mj_step`` (or MuJoCo
        Warp's ``step``) they are those of the state before the step, so run the position and velocity
        stages (``mj_fwdPosition`` + ``mj_fwdVelocity``, ``mj_forward``, or MuJoCo Warp's
        ``fwd_position`` + ``fwd_velocity``) on the new state first.

        Args:
            qpos, qvel: as in :meth:`kinematics`; they set the dtype and device of the result.
            qM: (B, nM), (B, 1, nM) sparse or (B, nv, nv) dense (:func:`leg_mass_blocks`).
            qfrc_bias: (B, nv).
        """
        qpos, qvel = self._check_state(qpos, qvel)
        kin = foot_kinematics(qpos, qvel, self._param_tensors(qpos))
        if qpos.device not in self._indices:
            self._indices[qpos.device] = _LegIndices(self.params.dof_adr, self.qM_adr, qpos.device)
        idx = self._indices[qpos.device]
        M_leg = _leg_mass_blocks(torch.as_tensor(qM).to(qpos), self.params.nv, idx)
        h_leg = _leg_bias(torch.as_tensor(qfrc_bias).to(qpos), self.params.nv, idx.dof)
        if M_leg.shape[0] != qpos.shape[0] or h_leg.shape[0] != qpos.shape[0]:
            raise ValueError(f"qM / qfrc_bias batch sizes {M_leg.shape[0]} / {h_leg.shape[0]} differ from the "
                             f"state's {qpos.shape[0]}")
        return LegTerms(M_leg=M_leg, h_leg=h_leg, J_leg=kin.J_leg, Jdot_qdot=kin.Jdot_qdot,
                        foot_pos_w=kin.foot_pos_w, foot_vel_w=kin.foot_vel_w)

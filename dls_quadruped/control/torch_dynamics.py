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
the world-aligned 3x3 leg Jacobians and ``Jdot qdot``) are computed in torch
(``control/foot_kinematics.py``), from kinematic parameters read from the ``mujoco.MjModel``
(``control/leg_chain.py``: body offsets and orientations, joint axes, anchors and reference
angles, foot-site offsets), so no robot number is typed in these files.

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

CPU time of the leg terms against ``LegDynamics.compute``: docs/reports/benchmarks.md "Leg dynamics from MuJoCo".
"""

from __future__ import annotations

import mujoco
import numpy as np
import torch

from dls_quadruped.control.foot_kinematics import (
    ChainTensors,
    FootKinematics,
    foot_kinematics,
)
from dls_quadruped.control.leg_chain import (
    LegChainParams,
    leg_chain_params,
    qM_addresses_from_pairs,
)
from dls_quadruped.control.lowlevel import LegTerms
from dls_quadruped.robots.aliengo import constants as C

NQ = 7 + C.NUM_JOINTS
NV = 6 + C.NUM_JOINTS


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
        self._tensors: dict[tuple[torch.device, torch.dtype], ChainTensors] = {}
        self._indices: dict[torch.device, _LegIndices] = {}

    def _param_tensors(self, like: torch.Tensor) -> ChainTensors:
        key = (like.device, like.dtype)
        if key not in self._tensors:
            self._tensors[key] = ChainTensors(self.params, like.device, like.dtype)
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

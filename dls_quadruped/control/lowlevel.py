"""Low-level controller (thesis Fig. 1, 2.2.2-2.2.6, Appendix B), run every physics step.

Inputs are world-frame latent references held between high-level updates:
step frequency ``f`` and duty ``d`` per leg, touch-down target ``p_td_w`` and stance
ground-reaction force ``F_w``. Per physics step and per leg:

* gait generator: contact ``c = theta < d``; ``theta`` then advances by ``f dt``;
* swing legs track the two-segment Bezier reference from the lift-off position to
  ``p_td_w``, which follows a moving target (below), with feedback linearisation (the sign
  of the thesis's eq. 2.2.8 is a typo)::

      tau = M J^-1 (a_ref + K_D (v_ref - v) + K_P (p_ref - p) - Jdot qdot) + h

  using the 3x3 leg blocks of M, h = C qdot + G, the world-aligned foot Jacobian J and
  the foot drift acceleration Jdot qdot, all from Pinocchio (``control/dynamics.py``);
* stance legs apply the ground-reaction force: ``tau = -J^T F`` (eq. 2.2.9 with the
  leg-on-ground sign);
* torques are clipped to the motor limits.

Moving touch-down target: the target is re-planned by the MPC (100 Hz) or the
policy (50 Hz) relative to the moving base, so it moves with the body in steps. An alpha-beta tracker
per leg (a critically damped second-order observer of bandwidth ``target_bandwidth``, zero lag on a
target moving at constant velocity) turns the horizontal target into a smooth position and velocity;
the Bezier reference runs to the tracked position and carries the target's velocity
(``swing.swing_reference(target_vel_w=...)``). Without it the foot trails a target moving at
0.5 m/s by 3.4 cm RMS at touch-down (docs/mpc.md "Swing foot and moving targets"). The vertical target
(terrain height under it) is used as given. ``target_bandwidth = 0`` aims the reference at the raw
target as if it stood still.

Everything is batched over B robots in float64 torch (the simulator state is float64), on the CPU or on
the device given (``device``: the Warp backends, ``sim/warp_backend.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from dls_quadruped.control.gait import (
    advance_phase,
    contact_from_phase,
    swing_progress,
    trot_phases,
)
from dls_quadruped.control.swing import swing_reference
from dls_quadruped.robots.aliengo import constants as C


@dataclass(frozen=True)
class LowLevelConfig:
    """Gains and limits of the low-level controller.

    Attributes:
        kp_swing: task-space position gain [1/s^2] (x, y, z), applied as an acceleration.
        kd_swing: task-space velocity gain [1/s] (x, y, z).
        step_height: swing apex above the higher of lift-off and touch-down [m].
        min_swing_duration: lower bound on T_s = (1 - d) / f [s], guards f -> inf, d -> 1.
        jacobian_damping: Tikhonov damping of the swing-leg Jacobian inverse (near-singular legs).
        target_bandwidth: [rad/s] bandwidth omega of the touch-down target tracker (module doc);
            0 = no tracker, the swing reference aims at the raw target as if it were at rest.
    """

    kp_swing: tuple[float, float, float] = (1200.0, 1200.0, 1200.0)
    kd_swing: tuple[float, float, float] = (60.0, 60.0, 60.0)
    step_height: float = 0.06
    min_swing_duration: float = 0.05
    jacobian_damping: float = 1e-3
    target_bandwidth: float = 40.0


@dataclass
class LegTerms:
    """Per-leg dynamics terms for B robots (float64 torch), from ``control/dynamics.py``.

    Attributes:
        M_leg: (B, 4, 3, 3) [kg m^2] leg blocks of the joint-space mass matrix.
        h_leg: (B, 4, 3) [N m] leg entries of C(q, qdot) qdot + G(q).
        J_leg: (B, 4, 3, 3) [m] foot-centre Jacobian w.r.t. the leg's joints, world-aligned.
        Jdot_qdot: (B, 4, 3) [m/s^2] foot acceleration at zero generalized acceleration.
        foot_pos_w: (B, 4, 3) [m] foot centres, world frame.
        foot_vel_w: (B, 4, 3) [m/s] foot-centre velocities, world frame.
    """

    M_leg: torch.Tensor
    h_leg: torch.Tensor
    J_leg: torch.Tensor
    Jdot_qdot: torch.Tensor
    foot_pos_w: torch.Tensor
    foot_vel_w: torch.Tensor


SOLVES = ("lu", "cramer")
"""How :class:`LowLevelController` solves the swing leg's damped 3x3 system (its ``solve`` argument)."""


def solve3_spd(A: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """x with ``A x = b`` for (..., 3, 3) symmetric positive definite A, (..., 3) b, by the adjugate (Cramer).

    Elementwise over the batch: no pivoting, no LAPACK call, so it fuses into one kernel when compiled. For the
    damped ``J^T J + lambda^2 I`` of a leg (condition at most ~1e8 at lambda = 1e-3) it agrees with LU to
    round-off (tests/control/test_lowlevel.py); a singular A gives non-finite x, as LU does.
    """
    a, b_, c = A[..., 0, 0], A[..., 0, 1], A[..., 0, 2]
    d, e, f = A[..., 1, 1], A[..., 1, 2], A[..., 2, 2]
    # cofactors of the symmetric matrix [[a b c] [b d e] [c e f]]
    c00, c01, c02 = d * f - e * e, c * e - b_ * f, b_ * e - c * d
    c11, c12, c22 = a * f - c * c, b_ * c - a * e, a * d - b_ * b_
    det = a * c00 + b_ * c01 + c * c02
    x, y, z = b.unbind(-1)
    return torch.stack([c00 * x + c01 * y + c02 * z, c01 * x + c11 * y + c12 * z,
                        c02 * x + c12 * y + c22 * z], dim=-1) / det.unsqueeze(-1)


class LowLevelController:
    """Stateful batched low-level controller: gait phases and lift-off positions live here.

    Args:
        num_robots: B.
        cfg: gains and limits.
        dt: physics (= control) step [s].
        device: where the buffers live and ``compute`` runs; its inputs (terms, references, ids) must be
            there too. Default the CPU (the ``cpu`` backend); the Warp backends pass theirs.
        solve: how the swing leg's damped 3x3 system is solved (:data:`SOLVES`): ``lu``
            (``torch.linalg.solve_ex``, the CPU backend's, kept for its bit-identical results) or ``cramer``
            (:func:`solve3_spd`: elementwise, so a compiled step fuses it, and no LAPACK call that reads pivots
            back to the host; the Warp backends'). They agree to round-off (tests/control/test_lowlevel.py).

    Every per-robot buffer (:attr:`STATE_FIELDS`) is updated in place, so its storage never moves: a captured
    or compiled physics step (``sim/warp_control.py``) keeps pointing at it.
    """

    def __init__(self, num_robots: int, cfg: LowLevelConfig = LowLevelConfig(), dt: float = 0.005,
                 device: torch.device | str = "cpu", solve: str = "lu"):
        if solve not in SOLVES:
            raise ValueError(f"LowLevelController solve must be one of {SOLVES}, got {solve!r}")
        self.cfg = cfg
        self.solve = solve
        self.dt = dt
        self.device = torch.device(device)
        dtype = torch.float64
        dev = self.device
        self.phase = trot_phases(num_robots, device=dev, dtype=dtype)
        # (1, 4) trot offsets for resets, a tensor attribute: compiled resets read it instead of building it from
        # Python floats (symbolic inputs whose guards torch 2.11 evaluates on the host at every call)
        self._trot = trot_phases(1, device=dev, dtype=dtype)
        self.p_lo_w = torch.zeros(num_robots, 4, 3, dtype=dtype, device=dev)
        self.contact = torch.ones(num_robots, 4, dtype=torch.bool, device=dev)
        self._kp = torch.tensor(cfg.kp_swing, dtype=dtype, device=dev)
        self._kd = torch.tensor(cfg.kd_swing, dtype=dtype, device=dev)
        self._tau_limit = torch.as_tensor(C.TORQUE_LIMITS, dtype=dtype).view(4, 3).to(dev)
        self._eye = torch.eye(3, dtype=dtype, device=dev) * cfg.jacobian_damping**2
        # alpha-beta tracker of the horizontal touch-down targets: observer x' = v + 2 w r, v' = w^2 r
        # (r = target - x, critically damped) discretised per step as alpha = 2 w dt, beta = (w dt)^2
        self.target_xy_w = torch.zeros(num_robots, 4, 2, dtype=dtype, device=dev)
        self.target_vel_xy_w = torch.zeros(num_robots, 4, 2, dtype=dtype, device=dev)
        self._fresh = torch.ones(num_robots, dtype=torch.bool, device=dev)  # tracker starts at the first target
        self._alpha = 2.0 * cfg.target_bandwidth * dt
        self._beta = (cfg.target_bandwidth * dt) ** 2
        if cfg.target_bandwidth < 0 or self._alpha >= 1.0:
            raise ValueError(f"LowLevelConfig.target_bandwidth must be in [0, 1 / (2 dt)) = [0, {0.5 / dt:g}) rad/s, "
                             f"got {cfg.target_bandwidth!r}")
        self.p_ref_w = torch.zeros(num_robots, 4, 3, dtype=dtype, device=dev)  # last swing reference (for logging)

    def reset(self, ids: torch.Tensor, foot_pos_w: torch.Tensor, phase: torch.Tensor | None = None) -> None:
        """Reset the gait phase (default: trot offsets) and lift-off positions of robots ``ids``.

        Args:
            ids: (n,) robot indices, or a (B,) bool mask of the robots to reset (then n = B: the next two
                arguments hold every robot's rows and only the masked ones are used).
            foot_pos_w: (n, 4, 3) [m] current foot positions (the lift-off point of a first swing).
            phase: (n, 4) phases in [0, 1), or None for the trot offsets.
        """
        if ids.dtype == torch.bool:  # a mask (B,) with foot_pos_w and phase of every robot: the masked rows kept
            new_phase = self._trot.expand(len(ids), 4) if phase is None else phase
            self.phase.copy_(torch.where(ids[:, None], new_phase.to(self.phase), self.phase))
            self.p_lo_w.copy_(torch.where(ids[:, None, None], foot_pos_w.to(self.p_lo_w), self.p_lo_w))
            self.contact.masked_fill_(ids[:, None], True)
            self._fresh.masked_fill_(ids, True)
            self.target_vel_xy_w.masked_fill_(ids[:, None, None], 0.0)
            return
        self.phase[ids] = self._trot.expand(len(ids), 4) if phase is None else phase.to(self.phase)
        self.p_lo_w[ids] = foot_pos_w.to(self.p_lo_w)
        self.contact.index_fill_(0, ids, True)  # scalar fills: x[ids] = v copies v from the host on CUDA
        self._fresh.index_fill_(0, ids, True)
        self.target_vel_xy_w.index_fill_(0, ids, 0.0)

    STATE_FIELDS = ("phase", "p_lo_w", "contact", "target_xy_w", "target_vel_xy_w", "_fresh", "p_ref_w")
    """The per-robot buffers that carry from one physics step to the next (a checkpoint's controller state)."""

    def state_dict(self) -> dict[str, torch.Tensor]:
        """Copies of :attr:`STATE_FIELDS` (each (B, ...)): restored, the next ``compute`` is bit-identical."""
        return {k: getattr(self, k).clone() for k in self.STATE_FIELDS}

    def load_state_dict(self, state: dict[str, torch.Tensor]) -> None:
        """Restore :meth:`state_dict` output.

        Raises:
            ValueError: a buffer is missing or has another shape (another number of robots).
        """
        for k in self.STATE_FIELDS:
            mine = getattr(self, k)
            if k not in state or tuple(state[k].shape) != tuple(mine.shape):
                got = tuple(state[k].shape) if k in state else "missing"
                raise ValueError(f"controller state {k}: expected shape {tuple(mine.shape)}, got {got}")
            mine.copy_(state[k])  # in place: the storage a compiled step points at stays

    def track_target(self, p_td_w: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        """One alpha-beta step on the horizontal targets: (tracked target (B, 4, 3), its velocity (B, 4, 3))."""
        if self.cfg.target_bandwidth == 0.0:
            return p_td_w, None
        meas = p_td_w[..., :2].to(self.target_xy_w)
        fresh = self._fresh.view(-1, 1, 1)
        xy = torch.where(fresh, meas, self.target_xy_w)
        vel = torch.where(fresh, torch.zeros_like(meas), self.target_vel_xy_w)
        pred = xy + self.dt * vel  # constant-velocity prediction
        resid = meas - pred
        xy = pred + self._alpha * resid
        vel = vel + (self._beta / self.dt) * resid
        self.target_xy_w.copy_(xy)
        self.target_vel_xy_w.copy_(vel)
        # a non-finite target must not stay in the tracker: that robot restarts from its next target
        self._fresh.copy_(~torch.isfinite(xy).flatten(1).all(dim=1))
        zero = torch.zeros_like(vel[..., :1])
        return (torch.cat([xy, p_td_w[..., 2:3].to(xy)], dim=-1), torch.cat([vel, zero], dim=-1))

    def compute(
        self,
        terms: LegTerms,
        freq: torch.Tensor,
        duty: torch.Tensor,
        p_td_w: torch.Tensor,
        F_w: torch.Tensor,
    ) -> torch.Tensor:
        """Joint torques for one physics step, then advance the gait phase by dt.

        Args:
            terms: dynamics of the current state.
            freq: (B, 4) [Hz]; duty: (B, 4) in [0, 1].
            p_td_w: (B, 4, 3) [m] touch-down targets (foot centre), world frame.
            F_w: (B, 4, 3) [N] ground-reaction force on each stance foot, world frame.

        Returns:
            tau: (B, 12) [N m] clipped joint torques, leg-major.
        """
        cfg = self.cfg
        contact = contact_from_phase(self.phase, duty)  # (B, 4)
        # a stance foot's current position is the lift-off point of its next swing
        p_lo_w = torch.where(contact.unsqueeze(-1), terms.foot_pos_w, self.p_lo_w)
        self.p_lo_w.copy_(p_lo_w)
        self.contact.copy_(contact)

        # --- swing: feedback linearisation in task space ---
        progress = swing_progress(self.phase, duty)
        swing_duration = ((1.0 - duty) / freq.clamp_min(1e-6)).clamp_min(cfg.min_swing_duration)
        target_w, target_vel_w = self.track_target(p_td_w)
        p_ref, v_ref, a_ref = swing_reference(p_lo_w, target_w, cfg.step_height, progress, swing_duration,
                                              target_vel_w)
        self.p_ref_w.copy_(p_ref)
        # a = a_ref + K_D (v_ref - v) + K_P (p_ref - p) - Jdot qdot  (foot acceleration to realise)
        acc = a_ref + self._kd * (v_ref - terms.foot_vel_w) + self._kp * (p_ref - terms.foot_pos_w) - terms.Jdot_qdot
        J = terms.J_leg
        Jt = J.transpose(-1, -2)
        # qddot = J^-1 acc, damped: (J^T J + lambda^2 I) qddot = J^T acc. solve_ex: linalg.solve's own
        # singularity check reads the info codes back to the host (a GPU synchronisation per physics step); the
        # damped matrix is positive definite, and a non-finite leg gives non-finite torques either way
        if self.solve == "lu":
            qdd = torch.linalg.solve_ex(Jt @ J + self._eye, (Jt @ acc.unsqueeze(-1))).result.squeeze(-1)
        else:
            qdd = solve3_spd(Jt @ J + self._eye, (Jt @ acc.unsqueeze(-1)).squeeze(-1))
        tau_swing = (terms.M_leg @ qdd.unsqueeze(-1)).squeeze(-1) + terms.h_leg

        # --- stance: tau = -J^T F ---
        tau_stance = -(Jt @ F_w.unsqueeze(-1)).squeeze(-1)

        tau = torch.where(contact.unsqueeze(-1), tau_stance, tau_swing)
        tau = torch.maximum(torch.minimum(tau, self._tau_limit), -self._tau_limit)
        self.phase.copy_(advance_phase(self.phase, freq, self.dt))
        return tau.reshape(-1, 12)

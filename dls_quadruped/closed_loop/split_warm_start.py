"""Warm starts that take the gait from one source and the forces from the other: the control that separates what
the RL warm start hands the MPC (docs/experiments/gait_control_plan.md).

``rl_warm_start`` gives the MPC the student's whole horizon: its gait (f, d), its footholds (p) and its force
offsets (F); ``naive_warm_start`` gives it a periodic trot, the heuristic footholds (eq. 2.2.4) and its own previous
plan's force offsets, shifted. With the MPC sampling the forces only (the default, 7.3.1), the gait and footholds
of the warm start are also the plan's. The two crossed arms:

* ``rl_gait_naive_forces`` (:class:`StudentGaitNaiveForcesMPC`): the student's f, d and p (its horizon shifted by the
  MPC periods since the query, as ``rl_warm_start`` shifts it) with the naive warm start's F block: the MPC's
  previous plan shifted, its swing-step offsets zeroed (``warm_start.naive``); zero offsets (gravity compensation)
  at an episode's first solve;
* ``naive_gait_rl_forces`` (:class:`NaiveGaitStudentForcesMPC`): the naive trot's f and d, the heuristic footholds
  held over the horizon (``mpc.baseline.held_footholds_block``) with the student's F block (shifted likewise).

Force offsets are the MPC's own coordinates (``warm_start``: F = c (dF + m g / stance legs)), so an F block moves
between gaits unchanged: under the other arm's contact sequence the offsets of its stance steps apply, those of
its swing steps are ignored. Everything else (the cost, its foothold and height references, the sampler, the
solve rate, the records, the fallback of a robot whose student output is not finite) is ``rl_warm_start``'s:
both classes differ from :class:`~dls_quadruped.closed_loop.mpc_controllers.RLWarmStartMPC` only in the warm start
they hand :meth:`SamplingMPC.solve`. One student each.
"""

from __future__ import annotations

import torch

from dls_quadruped.closed_loop.controller_config import ControllerConfig
from dls_quadruped.closed_loop.mpc_controllers import RLWarmStartMPC
from dls_quadruped.core.state import RobotState
from dls_quadruped.mpc.baseline import held_footholds_block
from dls_quadruped.mpc.encodings import block_slices
from dls_quadruped.mpc.inputs import heuristic_footholds_h, mpc_inputs
from dls_quadruped.mpc.sampler import MPCResult


class SplitWarmStartMPC(RLWarmStartMPC):
    """The sampling MPC warm-started by one student's horizon with some blocks replaced (module docstring); a
    subclass implements :meth:`blend`.

    Raises:
        ValueError: not exactly one student.
    """

    def __init__(self, cfg: ControllerConfig, env, *, references: bool = False, device: str | None = None):
        super().__init__(cfg, env, references=references, device=device)
        if len(self.students) != 1:
            raise ValueError(f"{self.cfg.name} takes one student, got {len(self.students)}")
        self.slices = block_slices(self.sampler_cfg.encoding)
        trot = [self.baseline_cfg.freq] * 4 + [self.baseline_cfg.duty] * 4
        self._trot = torch.tensor(trot, dtype=torch.float32, device=self.device)[None]  # (1, 8) f, d

    def blend(self, student: torch.Tensor, p_h: torch.Tensor) -> torch.Tensor:
        """The warm start (B, D) from the student's shifted horizon ``student`` (B, D) and the heuristic footholds
        ``p_h`` (B, 4, 2), frame H [m]."""
        raise NotImplementedError

    def solve(self, state: RobotState, cmd: torch.Tensor, ground: dict, substep: int) -> MPCResult:
        if self._student_ws is None:
            raise RuntimeError(f"{self.cfg.name}: prepare(obs) must run before act (envs.controller.step runs both)")
        p_h = heuristic_footholds_h(state, cmd, self.baseline_cfg)
        srbd, refs, frame = mpc_inputs(state, cmd, p_h, self.baseline_cfg.com_height, self.sampler_cfg, self.mpc.model,
                                       **ground)
        ws = self.blend(self._student_warm_start(substep, 0), p_h)
        return self.mpc.solve(srbd, refs, [ws], (1.0,), phase=state.phase, **frame)


class StudentGaitNaiveForcesMPC(SplitWarmStartMPC):
    """``rl_gait_naive_forces``: the student's gait and footholds, the naive warm start's forces."""

    def blend(self, student: torch.Tensor, p_h: torch.Tensor) -> torch.Tensor:
        F = self.slices["F"]
        naive = self.mpc.naive_warm_start(self.default)  # the previous plan shifted; the nominal trot's at first
        return torch.cat([student[:, :F.start], naive[:, F]], dim=1)


class NaiveGaitStudentForcesMPC(SplitWarmStartMPC):
    """``naive_gait_rl_forces``: the naive trot and heuristic footholds, the student's forces."""

    def blend(self, student: torch.Tensor, p_h: torch.Tensor) -> torch.Tensor:
        gait = self._trot.to(student.dtype).expand(student.shape[0], 8)
        p_block = held_footholds_block(p_h.to(student.dtype), self.sampler_cfg)
        return torch.cat([gait, p_block, student[:, self.slices["F"]]], dim=1)

"""The sampling MPC as a controller of the env (thesis 7.3.1): ``RLWarmStartMPC`` and ``NaiveWarmStartMPC``.

Both solve at the MPC's rate (``sampler.mpc_period``, 100 Hz: two commands per 50 Hz env step, each held for
``mpc_period / physics_dt`` physics steps, ``envs/controller.py``) from the env's robot state and command, on the
ground they plan on (``mpc.inputs.ground_inputs``), and differ in their warm starts only:

* ``RLWarmStartMPC`` (``rl_warm_start``): the distilled student(s), queried once per env step on the policy
  observation (:meth:`RLWarmStartMPC.prepare`); each student's encoded horizon, decoded to the MPC's units
  (``warm_start.from_student``), seeds its own sample group (``shares``, equal by default; sample 0 of a group is
  that student's horizon); a later solve of the same env step uses the horizon shifted by the MPC periods since
  the query (its swing-step force offsets zeroed, as the naive warm start shifts its own); optionally a share of
  the samples is drawn around the naive warm start as well. Every solve records which group won
  (``warm_start_index``: student k is group k, the naive group comes last);
* ``NaiveWarmStartMPC`` (``naive_warm_start``): the model-based baseline (``mpc.baseline.ModelBasedBaseline``):
  periodic trot, heuristic footholds (eq. 2.2.4), the MPC warm-started by its previous solution only. The same
  class runs the baseline in the home task (``closed_loop/baseline_run.py``), its plan sent as world references.

The MPC optimises the forces only by default (7.3.1); ``optimise`` adds f, d or p. Its first action ``(f, d, p_0,
F_0)`` (frame H) is normalised with the current stance count (Table 5, the exact inverse of what the action
manager applies: the MPC's latent-action configuration is the env's, ``ControllerConfig.for_env``) and goes
through the env's action path (``env.apply_action``), so the observation's last action, the action rewards and
the terrain height of the touch-down targets see what was applied; with ``references=True`` the solve's world
references (``MPCResult.foot_target_w``, ``force_w``) go straight to the backend instead. The MPC runs where its
kernel runs (``cpp``: the CPU, or Warp's kernel on the env's device when that is CUDA, ``sampler.resolved_kernel``;
the torch and Warp kernels: the env's device, unless ``device`` says otherwise); inputs are moved there.
"""

from __future__ import annotations

import time
from abc import abstractmethod

import torch
from tensordict import TensorDict

from dls_quadruped.closed_loop.controller_base import (
    Controller,
    SolveRecord,
    call,
    check_output,
    load_student,
)
from dls_quadruped.closed_loop.controller_config import ControllerConfig
from dls_quadruped.control import gait
from dls_quadruped.control.latent_action import LatentAction, normalise
from dls_quadruped.core.state import RobotState
from dls_quadruped.envs.controller import Command, References
from dls_quadruped.mpc import warm_start
from dls_quadruped.mpc.baseline import ModelBasedBaseline, optimised
from dls_quadruped.mpc.config import SamplerConfig
from dls_quadruped.mpc.inputs import ground_inputs, heuristic_footholds_h, mpc_inputs
from dls_quadruped.mpc.sampler import MPCResult, SamplingMPC, resolved_kernel


def mpc_physics_steps(cfg: ControllerConfig, env) -> int:
    """Physics steps per MPC period (``cfg.sampler.mpc_period / env.physics_dt``).

    Raises:
        ValueError: the period is not a whole number of physics steps dividing the env step.
    """
    period = cfg.sampler.mpc_period / env.physics_dt
    steps = round(period)
    if abs(period - steps) > 1e-9 or steps < 1 or env.decimation % steps:
        raise ValueError(f"the MPC period {cfg.sampler.mpc_period} s must be a whole number of physics steps "
                         f"({env.physics_dt} s) dividing the policy step ({env.decimation} physics steps)")
    return steps


class MPCController(Controller):
    """What both MPC controllers share: the rate, the device, one solve per command, its record and its command.
    A subclass sets ``mpc`` and ``sampler_cfg`` and implements :meth:`solve`.

    Args:
        references: send the solve's world references (``env.apply_references``) instead of its normalised raw
            action (``env.apply_action``).
        device: where the MPC computes; None: the CPU for the ``cpp`` kernel, else the env's device.

    Every solve's record (``SolveRecord``) stays where the MPC computes: nothing is read back to the host per solve
    (the episode recorder reads the records once, when its loop ends); the first action is finite by construction
    (``MPCResult.fallback``), so the env does not read it back to check it (``finite_commands``).

    Attributes:
        solves_per_step: solves per env step; mpc_decimation: physics steps each is held for.
        result: the last solve's ``MPCResult``.
    """

    mpc: SamplingMPC
    sampler_cfg: SamplerConfig
    finite_commands = True

    def __init__(self, cfg: ControllerConfig, env, *, references: bool = False, device: str | None = None):
        super().__init__(cfg, env, physics_steps=mpc_physics_steps(cfg, env))
        self.mpc_decimation = self.physics_steps
        self.solves_per_step = self.commands_per_step
        self.references = references
        self.baseline_cfg = self.cfg.baseline_config()
        if device is None:  # the C++ kernel computes on the CPU; the others (Warp's for cpp on CUDA) on the env's
            kernel = resolved_kernel(self.cfg.sampler.kernel, torch.device(env.device))
            device = "cpu" if kernel == "cpp" else env.device
        self.device = torch.device(device)
        self.height_fn = env.scene.terrain.height_at if self.cfg.ground == "terrain" else None
        self.result: MPCResult | None = None
        self._solves = 0
        self._student_ok: list[torch.Tensor] = [torch.ones(env.num_envs, dtype=torch.bool, device=self.device)]

    def kernel_seconds(self) -> float:
        return self.mpc.kernel_seconds

    def reset(self, env_ids: torch.Tensor) -> None:
        self.mpc.reset(env_ids.to(self.device))

    def reset_where(self, env_mask: torch.Tensor) -> None:
        """:meth:`reset` of the robots of a (B,) bool mask by masked updates (``SamplingMPC.reset``): no host read."""
        self.mpc.reset(env_mask.to(self.device))

    def prepare(self, obs: TensorDict) -> None:
        self.step_records = []

    def _state(self) -> RobotState:
        """The env's robot state where the MPC computes (the env's own tensors when on one device)."""
        state = self.env.state
        return state if state.base_pos_w.device == self.device else state.to(self.device)

    @abstractmethod
    def solve(self, state: RobotState, cmd: torch.Tensor, ground: dict, substep: int) -> MPCResult:
        """One solve from ``state`` (B robots, on the MPC's device), command ``cmd`` (B, 3) and the ground's
        keywords (``ground_inputs``), for command ``substep`` of the env step."""

    def act(self, obs: TensorDict, substep: int) -> Command:
        """One solve (its step costs recorded every ``horizon_cost_every``-th), recorded in ``step_records`` (on the
        MPC's device); returns its first action as a raw action, or its world references."""
        self.mpc.record_step_costs = self._solves % self.cfg.horizon_cost_every == 0
        self._solves += 1
        tic = time.perf_counter()
        state = self._state()
        cmd = self.env.command_manager.command.to(self.device)
        result = self.solve(state, cmd, ground_inputs(self.cfg.ground, state, self.height_fn), substep)
        self.solve_seconds += time.perf_counter() - tic
        self.result = result
        self.step_records.append(SolveRecord(
            best_cost=result.best_cost, input_cost=result.best_input_cost, initial_cost=result.initial_cost,
            step_costs=result.step_costs, step_input_costs=result.step_input_costs, state_terms=result.state_terms,
            warm_start_index=result.warm_start_index, fallback=result.fallback,
            student_fallback=~torch.stack(self._student_ok).all(dim=0)))
        if self.references:
            return References(result.f, result.d, result.foot_target_w, result.force_w)
        action = LatentAction(result.f, result.d, result.p_h, result.F_h)
        return normalise(action, self._state().contact_cmd.sum(dim=-1), self.sampler_cfg.action)


class NaiveWarmStartMPC(MPCController):
    """``naive_warm_start``: the model-based baseline (module docstring), warm-started by its own last plan."""

    def __init__(self, cfg: ControllerConfig, env, *, references: bool = False, device: str | None = None):
        super().__init__(cfg, env, references=references, device=device)
        self.baseline = ModelBasedBaseline(env.num_envs, self.baseline_cfg, device=self.device, seed=self.cfg.seed)
        self.mpc = self.baseline.mpc
        self.sampler_cfg = self.baseline.sampler_cfg

    def solve(self, state: RobotState, cmd: torch.Tensor, ground: dict, substep: int) -> MPCResult:
        result, _ = self.baseline.step(state, cmd, **ground)
        return result


class RLWarmStartMPC(MPCController):
    """``rl_warm_start``: the student(s) warm-start the MPC (module docstring)."""

    def __init__(self, cfg: ControllerConfig, env, *, references: bool = False, device: str | None = None):
        super().__init__(cfg, env, references=references, device=device)
        cfg = self.cfg
        self.sampler_cfg = optimised(cfg.sampler, cfg.optimise)
        self.mpc = SamplingMPC(self.sampler_cfg, device=self.device, seed=cfg.seed)
        self.students = []
        for path in cfg.students:
            module, meta = load_student(path, env, str(self.device))
            try:
                warm_start.check_student_encoding(meta, self.sampler_cfg)
            except ValueError as err:
                raise ValueError(f"student {path}: {err}") from None
            self.students.append(module)
        self.shares = cfg.group_shares()
        self.default = warm_start.nominal_trot(env.num_envs, self.sampler_cfg).to(self.device)
        self._student_ws: list[torch.Tensor] | None = None
        self._query_phase: torch.Tensor | None = None

    def prepare(self, obs: TensorDict) -> None:
        """Query every student on the policy observation; a robot whose output is not finite is flagged (its
        solves fall back to the naive warm start)."""
        super().prepare(obs)
        x = obs["policy"].to(self.device)
        self._student_ws, self._student_ok = [], []
        for path, student in zip(self.cfg.students, self.students):
            out = call(f"student {path}", student, x)
            check_output(f"student {path}", x, out, self.mpc.dim)
            ok = torch.isfinite(out).all(dim=1)
            self._student_ok.append(ok)
            self._student_ws.append(warm_start.from_student(torch.where(ok[:, None], out, torch.zeros_like(out)),
                                                            self.sampler_cfg))
        self._query_phase = self.env.state.phase.to(self.device).clone()

    def _student_warm_start(self, substep: int, k: int = 0) -> torch.Tensor:
        """Student k's horizon shifted by ``substep`` MPC periods (as the naive warm start is shifted);
        robots whose student output was not finite get the naive warm start (or the nominal trot), chosen by
        ``torch.where`` on every solve (no host read of the flags)."""
        ws = self._student_ws[k]
        if substep:
            enc = self.sampler_cfg.encoding
            f, d = ws[:, 0:4], ws[:, 4:8]
            _, contact = gait.contact_sequence(self._query_phase, f, d, self.sampler_cfg.dt, enc.horizon)
            for _ in range(substep):
                ws = warm_start.naive(ws, self.sampler_cfg, contact)
        naive = self.mpc.naive_warm_start(self.default)
        return torch.where(self._student_ok[k][:, None], ws, naive)

    def solve(self, state: RobotState, cmd: torch.Tensor, ground: dict, substep: int) -> MPCResult:
        if self._student_ws is None:
            raise RuntimeError("rl_warm_start: prepare(obs) must run before act (envs.controller.step runs both)")
        p_h = heuristic_footholds_h(state, cmd, self.baseline_cfg)
        srbd, refs, frame = mpc_inputs(state, cmd, p_h, self.baseline_cfg.com_height, self.sampler_cfg, self.mpc.model,
                                       **ground)
        ws = [self._student_warm_start(substep, k) for k in range(len(self.students))]
        if self.cfg.naive_share > 0.0:
            ws.append(self.mpc.naive_warm_start(ws[0]))
        return self.mpc.solve(srbd, refs, ws, self.shares, phase=state.phase, **frame)

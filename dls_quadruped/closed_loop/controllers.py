"""The four controllers of thesis 7.3.1, selectable by name, acting in a ``LocomotionEnv``.

* ``rl_warm_start``: the distilled student is queried at 50 Hz on the policy observation; its
  encoded horizon, decoded to the MPC's units (``warm_start.from_student``), warm-starts the
  sampling MPC, which solves at 100 Hz (twice per policy step: the second solve uses the student's
  horizon shifted by one MPC period, its swing-step force offsets zeroed, as the naive warm start
  shifts its own). Optionally a share of the samples is drawn around the naive warm start as well.
* ``naive_warm_start``: the model-based baseline (``mpc.baseline``): periodic trot, heuristic
  footholds (eq. 2.2.4), MPC warm-started by its previous solution only.
* ``rl_baseline``: the RL expert alone (its action at 50 Hz, held for the 4 physics steps).
* ``student``: the student alone (the decoded first action of its horizon).

The MPC controllers optimise the forces only by default (7.3.1); ``optimise`` adds f, d or p.
Their action reaches the simulator through the env's own pipeline: the MPC's first action
``(f, d, p_0, F_0)`` (frame H) is normalised with the current stance count (Table 5, the exact
inverse of what the action manager applies) and handed to ``action_manager.process``, so the
observation's last action, the action rewards and the terrain height of the touch-down targets see
what was applied.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import torch
from tensordict import TensorDict

from dls_quadruped.control import gait
from dls_quadruped.control.latent_action import ACTION_DIM, LatentAction, normalise
from dls_quadruped.mpc import warm_start
from dls_quadruped.mpc.baseline import (
    BaselineConfig,
    ModelBasedBaseline,
    check_optimise,
    heuristic_footholds_h,
    mpc_inputs,
    optimised,
)
from dls_quadruped.mpc.config import SamplerConfig
from dls_quadruped.mpc.sampler import MPCResult, SamplingMPC

CONTROLLERS = ("rl_warm_start", "naive_warm_start", "rl_baseline", "student")
"""Controller names (thesis 7.3.1 plus the student alone)."""
NEEDS_STUDENT = ("rl_warm_start", "student")
NEEDS_POLICY = ("rl_baseline",)


@dataclass(frozen=True)
class ControllerConfig:
    """What to run.

    Attributes:
        name: one of ``CONTROLLERS``.
        policy: the RL expert (exported TorchScript actor or rsl-rl checkpoint), for ``rl_baseline``.
        student: a distilled student export (``make distill``), for ``rl_warm_start`` and ``student``.
        sampler: MPC settings (M, N, dt, encoding, kernel, sigmas); the student must match its
            encoding, horizon and dt.
        optimise: variables the MPC samples (sigma of the others set to 0): default forces only.
        naive_share: ``rl_warm_start`` only: share of the M samples drawn around the naive warm start
            (previous solution shifted), the rest around the student's horizon; 0 = student only.
        seed: seed of the MPC's noise.
        horizon_cost_every: record the chosen sample's cost per horizon step (Fig. 28) at every k-th solve
            (an eager re-rollout, ~1.5 ms per solve).
    """

    name: str
    policy: Path | None = None
    student: Path | None = None
    sampler: SamplerConfig = field(default_factory=SamplerConfig)
    optimise: tuple[str, ...] = ("F",)
    naive_share: float = 0.0
    seed: int = 0
    horizon_cost_every: int = 10

    def __post_init__(self) -> None:
        if self.name not in CONTROLLERS:
            raise ValueError(f"unknown controller {self.name!r}; allowed: {list(CONTROLLERS)}")
        if self.name in NEEDS_STUDENT and self.student is None:
            raise ValueError(f"controller {self.name!r} needs a student (--student, a `make distill` export)")
        if self.name in NEEDS_POLICY and self.policy is None:
            raise ValueError(f"controller {self.name!r} needs the RL expert (--policy)")
        check_optimise(self.optimise)
        if not 0.0 <= self.naive_share < 1.0:
            raise ValueError(f"naive_share must be in [0, 1), got {self.naive_share!r}")
        if not isinstance(self.horizon_cost_every, int) or self.horizon_cost_every < 1:
            raise ValueError(f"horizon_cost_every must be an int >= 1, got {self.horizon_cost_every!r}")
        if self.naive_share > 0.0 and self.name != "rl_warm_start":
            raise ValueError(f"naive_share applies to rl_warm_start only, got it for {self.name!r}")

    @property
    def uses_mpc(self) -> bool:
        return self.name in ("rl_warm_start", "naive_warm_start")


@dataclass
class SolveRecord:
    """One batched MPC solve (B robots). step_costs, step_input_costs: (B, N); the rest (B,).
    best_cost is the full J of the chosen sample; input_cost its foothold-deviation part."""

    best_cost: torch.Tensor
    input_cost: torch.Tensor
    initial_cost: torch.Tensor
    step_costs: torch.Tensor
    step_input_costs: torch.Tensor
    warm_start_index: torch.Tensor
    fallback: torch.Tensor
    student_fallback: torch.Tensor


def _load_student(path: Path, env, device: str = "cpu"):
    """A student export and its metadata, refused unless it was distilled for the env's observation size."""
    from dls_quadruped.learning.student import load_student

    module, meta = load_student(path, device=device)
    if int(meta.get("obs_dim", -1)) != env.obs_dims["policy"]:
        raise ValueError(f"student {path} was distilled for {meta.get('obs_dim')} observations, "
                         f"the env gives {env.obs_dims['policy']}")
    return module, meta


def _check_output(module_name: str, obs: torch.Tensor, out: torch.Tensor, dim: int) -> None:
    if out.dim() != 2 or tuple(out.shape) != (obs.shape[0], dim):
        raise ValueError(f"{module_name} returned shape {tuple(out.shape)}, expected ({obs.shape[0]}, {dim})")


def _call(module_name: str, fn, obs: torch.Tensor) -> torch.Tensor:
    """Call a policy; a size mismatch becomes one ValueError naming the observation size."""
    try:
        return fn(obs)
    except RuntimeError as err:  # TorchScript shape errors
        raise ValueError(f"{module_name} does not accept the env's observation of {obs.shape[1]} values "
                         f"(trained for another observation?): {str(err).splitlines()[-1][:200]}") from None


class Controller:
    """Common interface: ``act(obs)`` at the policy rate; MPC controllers also run the physics."""

    def __init__(self, cfg: ControllerConfig, env):
        self.cfg = cfg
        self.env = env
        self.records: list[SolveRecord] = []
        self.solve_seconds = 0.0

    @property
    def name(self) -> str:
        return self.cfg.name

    def act(self, obs: TensorDict) -> torch.Tensor:
        """(B, 28) raw action for ``env.step`` (policy controllers)."""
        raise NotImplementedError

    def physics(self) -> torch.Tensor | None:
        """Run one policy step's physics (MPC controllers), see ``LocomotionEnv.step_controlled``."""
        raise NotImplementedError

    def prepare(self, obs: TensorDict) -> None:
        """Query what the policy-rate part needs before ``physics`` (MPC controllers)."""

    def reset(self, robots: torch.Tensor) -> None:
        """The env restarted these robots' episodes."""

    def kernel_seconds(self) -> float:
        return 0.0


class PolicyController(Controller):
    """``rl_baseline`` (the expert) or ``student`` (decoded first action of the student's horizon)."""

    def __init__(self, cfg: ControllerConfig, env):
        super().__init__(cfg, env)
        if cfg.name == "rl_baseline":
            from dls_quadruped.eval.policy import load_policy

            self._policy = load_policy(cfg.policy, env)
            self._what = f"policy {cfg.policy}"
        else:
            module, _ = _load_student(cfg.student, env, str(env.device))
            self._policy = lambda obs: module.first_action(obs["policy"])
            self._what = f"student {cfg.student}"

    def act(self, obs: TensorDict) -> torch.Tensor:
        out = _call(self._what, self._policy, obs)
        _check_output(self._what, obs["policy"], out, ACTION_DIM)
        return out


class MPCController(Controller):
    """``rl_warm_start`` or ``naive_warm_start`` (see the module docstring)."""

    def __init__(self, cfg: ControllerConfig, env):
        super().__init__(cfg, env)
        b = env.num_envs
        period = cfg.sampler.mpc_period / env.physics_dt
        self.mpc_decimation = round(period)
        if abs(period - self.mpc_decimation) > 1e-9 or self.mpc_decimation < 1 or env.decimation % self.mpc_decimation:
            raise ValueError(f"the MPC period {cfg.sampler.mpc_period} s must be a whole number of physics steps "
                             f"({env.physics_dt} s) dividing the policy step ({env.decimation} physics steps)")
        self.solves_per_step = env.decimation // self.mpc_decimation
        self.baseline_cfg = BaselineConfig(optimise=cfg.optimise, sampler=cfg.sampler)
        if cfg.name == "naive_warm_start":
            self.baseline = ModelBasedBaseline(b, self.baseline_cfg, device="cpu", seed=cfg.seed)
            self.mpc = self.baseline.mpc
            self.sampler_cfg = self.baseline.sampler_cfg
        else:
            self.sampler_cfg = optimised(cfg.sampler, cfg.optimise)
            self.mpc = SamplingMPC(self.sampler_cfg, device="cpu", seed=cfg.seed)
            self.student, meta = _load_student(cfg.student, env)
            warm_start.check_student_encoding(meta, self.sampler_cfg)
            self.default = warm_start.nominal_trot(b, self.sampler_cfg)
        self._solves = 0
        self._student_ws: torch.Tensor | None = None
        self._student_ok = torch.ones(b, dtype=torch.bool)

    def kernel_seconds(self) -> float:
        return self.mpc.kernel_seconds

    def reset(self, robots: torch.Tensor) -> None:
        self.mpc.reset(robots.cpu())

    def prepare(self, obs: TensorDict) -> None:
        if self.cfg.name != "rl_warm_start":
            return
        x = obs["policy"].cpu()
        out = _call(f"student {self.cfg.student}", self.student, x)
        _check_output(f"student {self.cfg.student}", x, out, self.mpc.dim)
        ok = torch.isfinite(out).all(dim=1)
        self._student_ok = ok
        self._student_ws = warm_start.from_student(torch.where(ok[:, None], out, torch.zeros_like(out)), self.sampler_cfg)
        self._query_phase = self.env.state.phase.cpu().clone()

    def _student_warm_start(self, substep: int) -> torch.Tensor:
        """The student's horizon shifted by ``substep`` MPC periods (as the naive warm start is shifted);
        robots whose student output was not finite get the naive warm start (or the nominal trot)."""
        ws = self._student_ws
        if substep:
            enc = self.sampler_cfg.encoding
            f, d = ws[:, 0:4], ws[:, 4:8]
            _, contact = gait.contact_sequence(self._query_phase, f, d, self.sampler_cfg.dt, enc.horizon)
            for _ in range(substep):
                ws = warm_start.naive(ws, self.sampler_cfg, contact)
        if not bool(self._student_ok.all()):
            naive = self.mpc.naive_warm_start(self.default)
            ws = torch.where(self._student_ok[:, None], ws, naive)
        return ws

    def _solve(self, substep: int) -> MPCResult:
        state = self.env.state
        cmd = self.env.command_manager.command.cpu()
        if self.cfg.name == "naive_warm_start":
            result, _ = self.baseline.step(state, cmd)
            return result
        if self._student_ws is None:
            raise RuntimeError("rl_warm_start: prepare(obs) must run before physics()")
        p_h = heuristic_footholds_h(state, cmd, self.baseline_cfg)
        srbd, refs, frame = mpc_inputs(state, cmd, p_h, self.baseline_cfg.com_height, self.sampler_cfg, self.mpc.model)
        ws = [self._student_warm_start(substep)]
        props: tuple[float, ...] = (1.0,)
        if self.cfg.naive_share > 0.0:
            ws.append(self.mpc.naive_warm_start(ws[0]))
            props = (1.0 - self.cfg.naive_share, self.cfg.naive_share)
        return self.mpc.solve(srbd, refs, ws, props, phase=state.phase, **frame)

    def physics(self) -> torch.Tensor | None:
        env = self.env
        am = env.action_manager
        prev = am.raw_action.clone()
        act_cfg = self.sampler_cfg.action
        for j in range(self.solves_per_step):
            self.mpc.record_step_costs = self._solves % self.cfg.horizon_cost_every == 0
            self._solves += 1
            tic = time.perf_counter()
            result = self._solve(j)
            self.solve_seconds += time.perf_counter() - tic
            state = env.state
            action = LatentAction(result.f, result.d, result.p_h, result.F_h)
            raw = normalise(action, state.contact_cmd.sum(dim=-1).cpu(), act_cfg)
            am.process(raw.to(env.device))
            env.scene.sim.step(self.mpc_decimation)
            env.refresh_state()
            self.records.append(SolveRecord(
                best_cost=result.best_cost.cpu(), input_cost=result.best_input_cost.cpu(),
                initial_cost=result.initial_cost.cpu(), step_costs=result.step_costs.cpu(),
                step_input_costs=result.step_input_costs.cpu(), warm_start_index=result.warm_start_index.cpu(),
                fallback=result.fallback.cpu(), student_fallback=~self._student_ok.cpu()))
        am.prev_raw_action[:] = prev  # the action rate of the policy step, as the policy controllers see it
        return None


def make_controller(cfg: ControllerConfig, env) -> Controller:
    """The controller ``cfg.name`` acting in ``env``."""
    return MPCController(cfg, env) if cfg.uses_mpc else PolicyController(cfg, env)

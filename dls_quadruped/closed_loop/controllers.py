"""The four controllers of thesis 7.3.1, selectable by name, acting in a ``LocomotionEnv``.

* ``rl_warm_start``: the distilled student is queried at 50 Hz on the policy observation; its
  encoded horizon, decoded to the MPC's units (``warm_start.from_student``), warm-starts the
  sampling MPC, which solves at 100 Hz (twice per policy step: the second solve uses the student's
  horizon shifted by one MPC period, its swing-step force offsets zeroed, as the naive warm start
  shifts its own). Optionally a share of the samples is drawn around the naive warm start as well.
  With several students (thesis 7.4, Algorithm 2) each seeds its own sample group (``shares``,
  equal by default; sample 0 of a group is that student's horizon) in the same batched solve, and
  every solve records which group won (``warm_start_index``: student k is group k, the naive group
  comes last).
* ``naive_warm_start``: the model-based baseline (``mpc.baseline``): periodic trot, heuristic
  footholds (eq. 2.2.4), MPC warm-started by its previous solution only.
* ``rl_baseline``: the RL expert alone (its action at 50 Hz, held for the 4 physics steps).
* ``student``: the student alone (the decoded first action of its horizon).

The MPC controllers optimise the forces only by default (7.3.1); ``optimise`` adds f, d or p.
Their action reaches the simulator through the env's own action path: the MPC's first action
``(f, d, p_0, F_0)`` (frame H) is normalised with the current stance count (Table 5, the exact
inverse of what the action manager applies: the MPC's latent-action configuration is the env's,
``ControllerConfig.for_env``) and handed to ``env.apply_action`` inside
``env.step_controlled`` (the action manager, then the backend's physics steps), so the
observation's last action, the action rewards and the terrain height of the touch-down targets see
what was applied. The MPC runs where its kernel runs (``cpp``: the CPU; the torch kernels: the env's
device); inputs are moved there and the action back to the env's device.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import torch
from tensordict import TensorDict

from dls_quadruped.closed_loop.controller_config import ControllerConfig
from dls_quadruped.closed_loop.registry import CONTROLLER_REGISTRY
from dls_quadruped.control import gait
from dls_quadruped.control.latent_action import ACTION_DIM, LatentAction, normalise
from dls_quadruped.mpc import warm_start
from dls_quadruped.mpc.baseline import ModelBasedBaseline, optimised
from dls_quadruped.mpc.inputs import ground_inputs, heuristic_footholds_h, mpc_inputs
from dls_quadruped.mpc.sampler import MPCResult, SamplingMPC


@dataclass
class SolveRecord:
    """One batched MPC solve (B robots). step_costs, step_input_costs: (B, N); state_terms: (B, 9); the rest (B,).
    best_cost is the full J of the chosen sample; input_cost its foothold-deviation part; state_terms its state
    part by term (``MPCResult.state_terms``, NaN on a solve without ``record_step_costs``)."""

    best_cost: torch.Tensor
    input_cost: torch.Tensor
    initial_cost: torch.Tensor
    step_costs: torch.Tensor
    step_input_costs: torch.Tensor
    state_terms: torch.Tensor
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
    except RuntimeError as err:  # an exported program's (or TorchScript's) shape errors
        raise ValueError(f"{module_name} does not accept the env's observation of {obs.shape[1]} values "
                         f"(trained for another observation?): {str(err).splitlines()[-1][:200]}") from None


class Controller:
    """Common interface: ``step(obs)``, one policy step of its env under the controller (``act(obs)`` at the
    policy rate; MPC controllers also run the physics); ``records`` / ``step_records``: the MPC solves. ``cfg``:
    the config it was given with the env's latent-action configuration (``ControllerConfig.for_env``)."""

    def __init__(self, cfg: ControllerConfig, env):
        self.cfg = cfg.for_env(env)
        self.env = env
        self.records: list[SolveRecord] = []
        self.step_records: list[SolveRecord] = []
        """The solves of the last :meth:`step` (``records`` keeps those of ``physics`` run outside it)."""
        self.solve_seconds = 0.0
        self.policy_seconds = 0.0
        """[s] in network queries (``act``, ``prepare``) during :meth:`step`."""

    @property
    def name(self) -> str:
        return self.cfg.name

    def step(self, obs: TensorDict) -> tuple[TensorDict, torch.Tensor, torch.Tensor, dict]:
        """One policy step of the env (``envs.recorder.StepFn``): ``env.step(act(obs))``."""
        tic = time.perf_counter()
        action = self.act(obs)
        self.policy_seconds += time.perf_counter() - tic
        return self.env.step(action)

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
            (path,) = cfg.students
            module, _ = _load_student(path, env, str(env.device))
            self._policy = lambda obs: module.first_action(obs["policy"])
            self._what = f"student {path}"

    def act(self, obs: TensorDict) -> torch.Tensor:
        out = _call(self._what, self._policy, obs)
        _check_output(self._what, obs["policy"], out, ACTION_DIM)
        return out


class MPCController(Controller):
    """``rl_warm_start`` or ``naive_warm_start`` (see the module docstring)."""

    def __init__(self, cfg: ControllerConfig, env):
        super().__init__(cfg, env)
        cfg = self.cfg  # with the env's action configuration
        b = env.num_envs
        period = cfg.sampler.mpc_period / env.physics_dt
        self.mpc_decimation = round(period)
        if abs(period - self.mpc_decimation) > 1e-9 or self.mpc_decimation < 1 or env.decimation % self.mpc_decimation:
            raise ValueError(f"the MPC period {cfg.sampler.mpc_period} s must be a whole number of physics steps "
                             f"({env.physics_dt} s) dividing the policy step ({env.decimation} physics steps)")
        self.solves_per_step = env.decimation // self.mpc_decimation
        self.baseline_cfg = cfg.baseline_config()
        # the C++ kernel computes on the CPU; the torch kernels where the env's tensors are
        self.device = torch.device("cpu") if cfg.sampler.kernel == "cpp" else torch.device(env.device)
        if cfg.name == "naive_warm_start":
            self.baseline = ModelBasedBaseline(b, self.baseline_cfg, device=self.device, seed=cfg.seed)
            self.mpc = self.baseline.mpc
            self.sampler_cfg = self.baseline.sampler_cfg
        else:
            self.sampler_cfg = optimised(cfg.sampler, cfg.optimise)
            self.mpc = SamplingMPC(self.sampler_cfg, device=self.device, seed=cfg.seed)
            self.students = []
            for path in cfg.students:
                module, meta = _load_student(path, env, str(self.device))
                try:
                    warm_start.check_student_encoding(meta, self.sampler_cfg)
                except ValueError as err:
                    raise ValueError(f"student {path}: {err}") from None
                self.students.append(module)
            self.shares = cfg.group_shares()
            self.default = warm_start.nominal_trot(b, self.sampler_cfg).to(self.device)
        self.height_fn = env.scene.terrain.height_at if cfg.ground == "terrain" else None
        self._solves = 0
        self._student_ws: list[torch.Tensor] | None = None
        self._student_ok: list[torch.Tensor] = [torch.ones(b, dtype=torch.bool, device=self.device)]

    def kernel_seconds(self) -> float:
        return self.mpc.kernel_seconds

    def step(self, obs: TensorDict) -> tuple[TensorDict, torch.Tensor, torch.Tensor, dict]:
        """One policy step: :meth:`prepare`, then ``env.step_controlled(physics)``; its solves in ``step_records``."""
        tic = time.perf_counter()
        self.prepare(obs)
        self.policy_seconds += time.perf_counter() - tic
        first = len(self.records)
        out = self.env.step_controlled(self.physics)
        self.step_records = self.records[first:]
        del self.records[first:]
        return out

    def reset(self, robots: torch.Tensor) -> None:
        self.mpc.reset(robots.to(self.device))

    def _state(self):
        """The env's robot state where the MPC computes (the env's own tensors when on one device)."""
        state = self.env.state
        return state if state.base_pos_w.device == self.device else state.to(self.device)

    def prepare(self, obs: TensorDict) -> None:
        if self.cfg.name != "rl_warm_start":
            return
        x = obs["policy"].to(self.device)
        self._student_ws, self._student_ok = [], []
        for path, student in zip(self.cfg.students, self.students):
            out = _call(f"student {path}", student, x)
            _check_output(f"student {path}", x, out, self.mpc.dim)
            ok = torch.isfinite(out).all(dim=1)
            self._student_ok.append(ok)
            self._student_ws.append(warm_start.from_student(torch.where(ok[:, None], out, torch.zeros_like(out)),
                                                            self.sampler_cfg))
        self._query_phase = self.env.state.phase.to(self.device).clone()

    def _student_warm_start(self, substep: int, k: int = 0) -> torch.Tensor:
        """Student k's horizon shifted by ``substep`` MPC periods (as the naive warm start is shifted);
        robots whose student output was not finite get the naive warm start (or the nominal trot)."""
        ws = self._student_ws[k]
        if substep:
            enc = self.sampler_cfg.encoding
            f, d = ws[:, 0:4], ws[:, 4:8]
            _, contact = gait.contact_sequence(self._query_phase, f, d, self.sampler_cfg.dt, enc.horizon)
            for _ in range(substep):
                ws = warm_start.naive(ws, self.sampler_cfg, contact)
        if not bool(self._student_ok[k].all()):
            naive = self.mpc.naive_warm_start(self.default)
            ws = torch.where(self._student_ok[k][:, None], ws, naive)
        return ws

    def _solve(self, substep: int) -> MPCResult:
        state = self._state()
        cmd = self.env.command_manager.command.to(self.device)
        ground = ground_inputs(self.cfg.ground, state, self.height_fn)
        if self.cfg.name == "naive_warm_start":
            result, _ = self.baseline.step(state, cmd, **ground)
            return result
        if self._student_ws is None:
            raise RuntimeError("rl_warm_start: prepare(obs) must run before physics()")
        p_h = heuristic_footholds_h(state, cmd, self.baseline_cfg)
        srbd, refs, frame = mpc_inputs(state, cmd, p_h, self.baseline_cfg.com_height, self.sampler_cfg, self.mpc.model,
                                       **ground)
        ws = [self._student_warm_start(substep, k) for k in range(len(self.students))]
        if self.cfg.naive_share > 0.0:
            ws.append(self.mpc.naive_warm_start(ws[0]))
        return self.mpc.solve(srbd, refs, ws, self.shares, phase=state.phase, **frame)

    def physics(self) -> torch.Tensor | None:
        """One policy step: ``solves_per_step`` solves, each applied through ``env.apply_action`` for
        ``mpc_decimation`` physics steps (inside ``env.step_controlled``)."""
        env = self.env
        act_cfg = self.sampler_cfg.action
        for j in range(self.solves_per_step):
            self.mpc.record_step_costs = self._solves % self.cfg.horizon_cost_every == 0
            self._solves += 1
            tic = time.perf_counter()
            result = self._solve(j)
            self.solve_seconds += time.perf_counter() - tic
            action = LatentAction(result.f, result.d, result.p_h, result.F_h)
            raw = normalise(action, self._state().contact_cmd.sum(dim=-1), act_cfg)
            env.apply_action(raw, self.mpc_decimation, replan=j > 0)
            self.records.append(SolveRecord(
                best_cost=result.best_cost.cpu(), input_cost=result.best_input_cost.cpu(),
                initial_cost=result.initial_cost.cpu(), step_costs=result.step_costs.cpu(),
                step_input_costs=result.step_input_costs.cpu(), state_terms=result.state_terms.cpu(),
                warm_start_index=result.warm_start_index.cpu(),
                fallback=result.fallback.cpu(), student_fallback=~torch.stack(self._student_ok).all(dim=0).cpu()))
        return None


CONTROLLER_REGISTRY.register("rl_warm_start", MPCController, "the distilled student(s) warm-start the sampling MPC")
CONTROLLER_REGISTRY.register("naive_warm_start", MPCController,
                             "the model-based baseline: trot, heuristic footholds, MPC warm-started by its last plan")
CONTROLLER_REGISTRY.register("rl_baseline", PolicyController, "the RL expert alone")
CONTROLLER_REGISTRY.register("student", PolicyController, "the student alone, the first action of its horizon")
CONTROLLERS = CONTROLLER_REGISTRY.names()
"""Controller names (thesis 7.3.1 plus the student alone), in registration order."""


def make_controller(cfg: ControllerConfig, env) -> Controller:
    """The controller ``cfg.name`` acting in ``env`` (``closed_loop/registry.py``)."""
    return CONTROLLER_REGISTRY.get(cfg.name)(cfg, env)

"""Sampling MPC controller (thesis 3.2, Algorithm 2): one batched solve over B robots x M samples.

    mpc = SamplingMPC(SamplerConfig(num_samples=10000, horizon=10))
    result = mpc.solve(state, refs, warm_starts=[mpc.naive_warm_start(default), policy_ws], proportions=(0.5, 0.5),
                       phase=phase)

Per solve: validate inputs -> split M into warm-start groups -> draw/clip/decode -> roll out and
cost every sample (``cpp``, ``fast`` or ``reference`` kernel, :mod:`kernel`) -> argmin (with several warm
starts optionally arbitrated for a coherent winning group, :mod:`arbitration`) -> re-draw and decode the winner's
first action. Robots with a non-finite input (state, phase, base
position or yaw, terrain height, any reference) get the previous solution back (``fallback`` flag and
``reason`` naming the robots and the input) instead of a meaningless argmin; a solution that is
not finite for any other reason is replaced the same way, so ``fallback = False`` always means a
finite action.
"""

from __future__ import annotations

import importlib.util
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING

import torch

from dls_quadruped.core.device import checked_device
from dls_quadruped.mpc import arbitration, solve_glue, solve_inputs, warm_start
from dls_quadruped.mpc.config import SamplerConfig
from dls_quadruped.mpc.cost import (
    STATE_TERMS,
    Refs,
    initial_cost,
    input_step_costs,
    rollout_step_costs_and_terms,
)
from dls_quadruped.mpc.encodings import encoded_dim
from dls_quadruped.mpc.kernel import KernelInputs
from dls_quadruped.mpc.kernel_registry import KERNEL_REGISTRY
from dls_quadruped.mpc.samples import decode_samples, group_layout, sample_encoded
from dls_quadruped.mpc.solution import MPCResult, action_finite, describe_bad
from dls_quadruped.mpc.srbd import SRBDModel, SRBDState, robot_srbd_model

if TYPE_CHECKING:
    from dls_quadruped.mpc.warp_solve import DeviceSolve, DeviceSolver


def resolved_kernel(name: str, device: torch.device) -> str:
    """The kernel that runs for ``SamplerConfig.kernel`` = ``name`` on ``device``: ``cpp`` (the default) is ``warp`` on
    CUDA when Warp is installed (the ``cpp`` kernel is CPU only), otherwise the name itself."""
    if name == "cpp" and device.type == "cuda" and importlib.util.find_spec("warp") is not None:
        return "warp"
    return name


class SamplingMPC:
    """Batched sampling MPC with warm starts (Algorithm 2).

    Args:
        cfg: sampler configuration (frozen).
        model: SRBD parameters (default: from the MJCF, :func:`robot_srbd_model`).
        device: where the rollouts run ("cpu" or "cuda").
        seed: seed of the generator that draws one noise seed per solve (deterministic solves).
    """

    def __init__(self, cfg: SamplerConfig | None = None, model: SRBDModel | None = None,
                 device: torch.device | str = "cpu", seed: int = 0):
        try:
            self.device = checked_device(device)
        except ValueError as err:
            raise ValueError(f"SamplingMPC: {err}") from None
        self.cfg = cfg if cfg is not None else SamplerConfig()
        self.model = model if model is not None else robot_srbd_model()
        self.dim = encoded_dim(self.cfg.encoding)
        self.generator = torch.Generator().manual_seed(seed)
        self.last_result: MPCResult | None = None
        self._forgotten: torch.Tensor | None = None  # (B,) robots whose previous solution was reset
        self.kernel_seconds = 0.0
        """Wall time [s] spent in the cost kernel (all solves so far): the closed loop's profile."""
        self.record_step_costs = False
        """Fill ``MPCResult.step_costs`` (a reference rollout of the winner, ~1.5 ms per solve); else NaN."""
        self._layouts: dict[tuple[float, ...], tuple[torch.Tensor, torch.Tensor]] = {}
        self._counts: dict[tuple[float, ...], tuple[int, ...]] = {}
        self._arbitration: arbitration.Memory | None = None
        """Previous winning group and running group costs per robot (``cfg.arbitrates`` with several warm starts)."""
        self._average: torch.Tensor | None = None  # this solve's running group costs, until its result is known
        self.fused = True
        """With the ``cpp`` kernel on the CPU, run the fused solve (:mod:`solve_glue`: input cleaning, kernel +
        argmin and the winner's decoding in C++ calls, preallocated buffers); the same result bit for bit as the
        torch path that ``fused = False`` runs (and any other kernel or device)."""
        self.fused_solve = solve_glue.FusedSolve()
        """The fused path's libraries and buffers (:class:`solve_glue.FusedSolve`)."""
        self.capture = True
        """With the ``warp`` kernel (:mod:`warp_solve`), replay each solve from a captured Warp graph (False: launch
        its four kernels one by one; the same numbers)."""
        self.device_solver: DeviceSolver | None = None
        """The device path's prepared solves (:class:`warp_solve.DeviceSolver`), made on the first device solve."""
        self._solve_counter: torch.Tensor | None = None
        self.last_device_solve: DeviceSolve | None = None
        """The :class:`warp_solve.DeviceSolve` of the last device solve (its flags: :meth:`fallback_report`)."""

    # ------------------------------------------------------------------ warm starts

    def naive_warm_start(self, default: torch.Tensor | None = None) -> torch.Tensor:
        """Previous best sample, its swing-step force offsets zeroed, shifted by one MPC period (mpc_period / dt
        horizon steps): :func:`warm_start.naive`.

        Args:
            default: (B, D) or (D,) used when there is no previous solution yet (e.g. a trot
                with feet under the hips and m g / 2 on the stance legs).

        Raises:
            ValueError: no previous solution and no default.
        """
        if self.last_result is None or self._forgotten is not None:
            if default is None:
                raise ValueError("naive_warm_start: there is no previous solution yet; pass default=(B, D) encoded "
                                 "action")
            default = default.to(self.device, torch.float32)
            if self.last_result is None:
                return default
        shifted = warm_start.naive(self.last_result.best_encoded, self.cfg, self.last_result.contact_horizon)
        if self._forgotten is None:
            return shifted
        return torch.where(self._forgotten[:, None], default.expand_as(shifted), shifted)

    def reset(self, robots: torch.Tensor | None = None) -> None:
        """Forget the previous solution of ``robots`` ((K,) indices or a (B,) bool mask, none set allowed; all if
        None): their next naive warm start is the default (e.g. after the env restarted their episode), and their
        arbitration between warm-start groups starts afresh (no previous winner, no running group cost). A mask is
        applied by masked updates (no host read)."""
        if robots is None or self.last_result is None:
            self.last_result, self._forgotten, self._arbitration = None, None, None
            return
        robots = robots.to(self.device)
        if robots.dtype != torch.bool:
            b = self.last_result.best_encoded.shape[0]
            robots = torch.zeros(b, dtype=torch.bool, device=self.device).index_fill_(0, robots, True)
        if self._arbitration is not None:
            self._arbitration.forget(robots)
        self._forgotten = robots.clone() if self._forgotten is None else self._forgotten | robots

    # ------------------------------------------------------------------ solve

    def sample_layout(self, proportions: tuple[float, ...]) -> tuple[torch.Tensor, torch.Tensor]:
        """(M,) long warm-start group and (M,) float 0/1 perturbation flag of every sample for ``proportions``
        (:func:`samples.group_layout`; sample 0 of each group is its warm start unperturbed), cached on the device."""
        if proportions not in self._layouts:
            group, perturb, counts = group_layout(self.cfg.num_samples, proportions)
            self._layouts[proportions] = (group.to(self.device), perturb.to(self.device))
            self._counts[proportions] = counts
        return self._layouts[proportions]

    def _arbitrate(self, costs: torch.Tensor, props: tuple[float, ...], best_cost: torch.Tensor,
                   best_index: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The winners (best_cost, best_index) under ``cfg.switching_cost`` and ``cfg.group_cost_smoothing``
        (:func:`arbitration.select` on the (B, M) costs); the plain argmin with one warm start or both off."""
        self._average = None
        if not self.cfg.arbitrates or len(props) < 2:
            return best_cost, best_index
        memory = self._arbitration
        if memory is not None and tuple(memory.average.shape) != (costs.shape[0], len(props)):
            memory = None  # another batch or number of warm starts: nothing to be coherent with
        best_cost, best_index, self._average = arbitration.select(
            costs, self._counts[props], self.cfg.switching_cost, self.cfg.group_cost_smoothing, memory)
        return best_cost, best_index

    def remember(self, result: MPCResult) -> None:
        """Keep ``result`` as the previous solution (the next naive warm start) and, when arbitrating, each robot's
        winning group and running group costs (a fallback robot keeps neither): every solve path ends here."""
        self.last_result, self._forgotten = result, None
        if self._average is None:
            self._arbitration = None
            return
        average, self._average = self._average, None
        average[result.fallback] = float("nan")
        self._arbitration = arbitration.Memory(result.warm_start_index.clone(), average)

    def solve_counter(self) -> torch.Tensor:
        """(1,) int64 on the device: solves so far on the device path (each derives its noise seed from it there)."""
        if self._solve_counter is None:
            with torch.inference_mode(False):  # advanced in place by every later solve, in inference mode or not
                self._solve_counter = torch.zeros(1, dtype=torch.int64, device=self.device)
        return self._solve_counter

    def fallback_report(self) -> str:
        """The last device solve's fallbacks in words (one host read; the torch path's ``reason``), "" if none."""
        return self.last_device_solve.fallback_report() if self.last_device_solve is not None else ""

    def uses_device_solve(self, num_warm_starts: int) -> bool:
        """Whether a solve runs on the device path (:mod:`warp_solve`): the ``warp`` kernel (or ``cpp`` on CUDA with
        Warp installed), ``fused`` on, no arbitration between several warm starts."""
        kernel = resolved_kernel(self.cfg.kernel, self.device)
        return kernel == "warp" and self.fused and not (self.cfg.arbitrates and num_warm_starts > 1)

    def validate_shapes(self, state: SRBDState, refs: Refs, warm_starts: Sequence[torch.Tensor],
                        proportions: Sequence[float] | None, phase: torch.Tensor,
                        frame: tuple = (None, None, None)) -> tuple[torch.Tensor, tuple[float, ...]]:
        """The argument checks that read no tensor data: types, shapes, proportions, M >= G. Returns the (B, G, D)
        warm starts on the device and the proportions."""
        return solve_inputs.validate(self.cfg, self.dim, self.device, state, refs, warm_starts, proportions, phase,
                                     read_data=False, frame=frame)

    def solve(
        self,
        state: SRBDState,
        refs: Refs,
        warm_starts: Sequence[torch.Tensor],
        proportions: Sequence[float] | None = None,
        phase: torch.Tensor | None = None,
        base_xy_w: torch.Tensor | None = None,
        base_yaw: torch.Tensor | None = None,
        terrain_z_w: torch.Tensor | None = None,
    ) -> MPCResult:
        """One MPC solve for B robots.

        Args:
            state: SRBD state of B robots.
            refs: cost references.
            warm_starts: G encoded actions, each (B, D) or (D,) (naive, policy, ...).
            proportions: G fractions of M summing to 1 (default: (1.0,) for a single warm start).
            phase: (B, 4) current gait phase in [0, 1).
            base_xy_w: (B, 2) [m] origin of the horizontal frame (default: the base position
                recovered from the CoM and the model's CoM offset).
            base_yaw: (B,) [rad] yaw of the horizontal frame (default: the state's yaw).
            terrain_z_w: (B, 4) [m] ground height under each leg's nominal foothold (default 0).

        Returns:
            :class:`MPCResult`.

        Raises:
            ValueError: wrong shapes, non-finite warm starts, bad proportions, M < G, a phase outside [0, 1).
        """
        if phase is None:
            raise ValueError("phase must be given: (B, 4) gait phase in [0, 1)")
        if isinstance(warm_starts, Sequence) and self.uses_device_solve(len(warm_starts)):
            from dls_quadruped.mpc import warp_solve  # imports Warp: only on this path

            if self.device_solver is None:
                self.device_solver = warp_solve.DeviceSolver()
            result, self.last_device_solve, seconds = self.device_solver.solve(
                self, state, refs, warm_starts, proportions, phase, base_xy_w, base_yaw, terrain_z_w)
            self.kernel_seconds += seconds
            self.remember(result)
            return result
        frame = (base_xy_w, base_yaw, terrain_z_w)
        ws, props = solve_inputs.validate(self.cfg, self.dim, self.device, state, refs, warm_starts, proportions,
                                          phase, frame=frame)
        on_cpu_cpp = self.cfg.kernel == "cpp" and self.device.type == "cpu"
        if self.fused and on_cpu_cpp and self.fused_solve.ready():
            return self._solve_fused(ws, props, state, refs, phase, frame)
        dev = self.device
        x0, clean, refs, bad_inputs = solve_inputs.clean(state, refs, phase, frame, self.model, dev)
        group, perturb = self.sample_layout(props)
        seed = torch.randint(0, 2**31 - 1, (), generator=self.generator).to(dev)
        inp = KernelInputs(seed, ws, group, perturb, x0, clean["phase"], clean["base_xy_w"], clean["base_yaw"],
                           clean["terrain_z_w"], refs)
        tic = time.perf_counter()
        costs = KERNEL_REGISTRY.get(resolved_kernel(self.cfg.kernel, dev))(inp, self.cfg, self.model)
        if costs.is_cuda:
            torch.cuda.synchronize(costs.device)
        self.kernel_seconds += time.perf_counter() - tic
        best_cost, best_index = self._arbitrate(costs, props, *costs.min(dim=1))
        result = self.decode_winners(inp, best_index, best_cost, initial_cost(x0, refs, self.cfg.weights))
        return self._finish(result, inp, bad_inputs)

    def _solve_fused(self, ws: torch.Tensor, props: tuple[float, ...], state: SRBDState, refs: Refs,
                     phase: torch.Tensor, frame: solve_inputs.Frame) -> MPCResult:
        """:meth:`solve` on the fused CPU path (:mod:`solve_glue`) after its argument checks: the same result bit for
        bit as the torch path."""
        fused = self.fused_solve
        group, perturb = self.sample_layout(props)
        seed = torch.randint(0, 2**31 - 1, (), generator=self.generator)
        run = fused.costs(self.cfg, self.model, ws, group, perturb, seed, state, refs, phase, *frame)
        self.kernel_seconds += run.seconds
        best_cost, best_index = self._arbitrate(run.costs, props, run.best_cost, run.best_index)
        init_cost, ws_index = fused.winner_noise(run, best_index)
        if self.record_step_costs:  # the winner's reference rollout needs the torch decoding
            init_cost = torch.where(torch.isnan(init_cost), torch.full_like(init_cost, float("inf")), init_cost)
            result, num_bad = self.decode_winners(run.inp, best_index, best_cost, init_cost), -1
        else:
            result, num_bad = fused.decode_winner(run, best_index, best_cost, init_cost, ws_index)
        return self._finish(result, run.inp, fused.bad_inputs(run) if num_bad else None)  # num_bad < 0: not counted

    def _finish(self, result: MPCResult, inp: KernelInputs, bad_inputs: dict[str, torch.Tensor] | None) -> MPCResult:
        """The last guard, then :meth:`remember`: robots flagged in ``bad_inputs`` ((B,) bool per input; None: none
        flagged) or whose action is not finite get :meth:`fall_back`'s action, so ``fallback = False`` always means a
        finite action."""
        if bad_inputs is not None:
            finite = ~torch.stack(list(bad_inputs.values())).any(dim=0)
            bad_inputs["solution"] = finite & ~action_finite(result)
            bad = torch.stack(list(bad_inputs.values())).any(dim=0)
            if bool(bad.any()):
                result = self.fall_back(result, bad, inp, describe_bad(bad_inputs))
        self.remember(result)
        return result

    def decode_winners(self, inp: KernelInputs, best_index: torch.Tensor, best_cost: torch.Tensor,
                       init_cost: torch.Tensor) -> MPCResult:
        """Re-draw the winning samples (B,) ``best_index`` of ``inp`` and decode their first action: the
        :class:`MPCResult` of a solve without fallback (step costs NaN unless ``record_step_costs``)."""
        best = sample_encoded(inp.seed, inp.warm_starts, inp.group, inp.perturb, best_index[:, None], self.cfg)
        dec = decode_samples(best, inp.phase, inp.base_xy_w, inp.base_yaw, inp.terrain_z_w, self.cfg)
        first = {k: v[:, 0] for k, v in dec.items()}  # drop the K = 1 sample dim
        b = best_index.shape[0]
        step_input = input_step_costs(dec["foot_target_w"], dec["force_w"], inp.refs, self.cfg.weights)[:, 0]  # (B, N)
        if self.record_step_costs:
            step_costs, state_terms = rollout_step_costs_and_terms(
                inp.x0, dec["contact"], dec["foot_target_w"], dec["force_w"], inp.refs, self.model, self.cfg.weights,
                self.cfg.dt)
            step_costs, state_terms = step_costs[:, 0], state_terms[:, 0]
        else:  # an eager reference rollout costs ~1.5 ms per solve: off unless asked for
            step_costs = torch.full((b, self.cfg.horizon), float("nan"), device=best_index.device)
            state_terms = torch.full((b, len(STATE_TERMS)), float("nan"), device=best_index.device)
        return MPCResult(
            f=first["f"], d=first["d"], contact=first["contact"][:, 0], foot_target_w=first["foot_target_w"][:, 0],
            force_w=first["force_w"][:, 0], p_h=first["p_h"][:, 0], F_h=first["F_h"][:, 0],
            best_cost=best_cost, best_input_cost=step_input.sum(-1), initial_cost=init_cost, best_index=best_index,
            warm_start_index=inp.group[best_index], best_encoded=best[:, 0], contact_horizon=first["contact"],
            step_costs=step_costs, step_input_costs=step_input, state_terms=state_terms,
            fallback=torch.zeros(b, dtype=torch.bool, device=best_index.device),
        )

    def fall_back(self, result: MPCResult, bad: torch.Tensor, inp: KernelInputs, why: str) -> MPCResult:
        """``result`` with the (B,) ``bad`` robots (a non-finite input or action) given the previous solution (or
        the first warm start, decoded from ``inp``), +inf costs, index -1 and ``reason`` = ``why`` + the source."""
        prev = self.last_result
        if prev is not None and prev.f.shape[0] == bad.shape[0] and prev.f.device == bad.device:
            source = "the previous solution"
        else:  # sample 0 is warm start 0 itself (its group's unperturbed sample)
            source = "the first warm start (no previous solution)"
            prev = self.decode_winners(inp, torch.zeros_like(result.best_index), result.best_cost, result.initial_cost)
        out = {}
        for name in ("f", "d", "contact", "foot_target_w", "force_w", "p_h", "F_h", "best_encoded", "contact_horizon"):
            new, old = getattr(result, name), getattr(prev, name)
            out[name] = torch.where(bad.view(-1, *([1] * (new.dim() - 1))), old, new)
        inf = torch.full_like(result.best_cost, float("inf"))
        minus = torch.full_like(result.best_index, -1)
        return MPCResult(
            **out, best_cost=torch.where(bad, inf, result.best_cost),
            best_input_cost=torch.where(bad, inf, result.best_input_cost),
            step_input_costs=torch.where(bad[:, None], float("inf"), result.step_input_costs),
            initial_cost=torch.where(bad, inf, result.initial_cost),
            best_index=torch.where(bad, minus, result.best_index),
            step_costs=torch.where(bad[:, None], float("inf"), result.step_costs),
            state_terms=torch.where(bad[:, None], float("inf"), result.state_terms),
            warm_start_index=torch.where(bad, minus, result.warm_start_index),
            fallback=bad.clone(),
            reason=f"{why}: returned {source} for them",
        )

"""Batched closed-loop episodes of one controller in a ``LocomotionEnv``, with the thesis's metrics (7.3.1).

Every env runs one episode (15 s by default) from the same start; data after an env's first
termination is masked out (its restart is simulated but not counted; the loop stops once every episode has
ended; ``envs/recorder.py`` keeps the books). Per policy step (50 Hz) and
robot: the per-step RL reward (the env's reward without the dt factor, on the thesis's ~2.3
scale when the env uses the base task's Table-4 reward), the initial cost (the MPC's state cost of
the current state, computed the same way for every controller, so the RL baseline gets one too),
the planar velocity-tracking error and the motor power of eq. 4.3.7; per MPC solve (100 Hz, MPC
controllers): the rollout cost of the chosen sample (full J and its input part, so that the
state-only cost that comparisons use is their difference, ``mpc/cost.py``), its cost at each horizon
step (Fig. 28) and which warm start it came from (Fig. 34).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import torch

from dls_quadruped.closed_loop.controller_base import Controller
from dls_quadruped.envs.mdp.kernels import motor_power
from dls_quadruped.envs.recorder import EpisodeRecord, record
from dls_quadruped.eval.rollout import base_velocity
from dls_quadruped.mpc.baseline import BaselineConfig
from dls_quadruped.mpc.config import SamplerConfig
from dls_quadruped.mpc.cost import STATE_TERMS, initial_cost, state_cost_terms
from dls_quadruped.mpc.inputs import (
    GROUNDS,
    ground_inputs,
    heuristic_footholds_h,
    mpc_inputs,
)
from dls_quadruped.mpc.srbd import robot_srbd_model


@dataclass
class ClosedLoopTraces:
    """One episode per env (E envs, T policy steps, S MPC solves per policy step, N horizon steps).

    Attributes:
        controller: its name.
        command: (E, 3) (v_x, v_y [m/s], omega_z [rad/s]) of each episode.
        reward: (T, E) per-step reward (no dt factor), NaN after the episode ended.
        initial_cost: (T, E) state cost of the state at the start of the step, NaN after the end.
        initial_cost_terms: (T, E, 9) its terms (``mpc.cost.STATE_TERMS`` order: z, vx, vy, vz, roll,
            pitch, roll rate, pitch rate, yaw rate), summing to ``initial_cost``.
        vel_error: (T, E) |v_xy - cmd_xy| [m/s] after the step (base frame), NaN after the end.
        power: (T, E) [W] motor power (numerator of eq. 4.3.7); speed: (T, E) [m/s] horizontal base speed.
        base_vel: (T, E, 3) measured (v_x, v_y, omega_z), base frame.
        rollout_cost, mpc_initial_cost: (T, S, E) per solve (NaN without an MPC or after the end);
            rollout_cost is the full J of the chosen sample.
        rollout_input_cost: (T, S, E) its input (foothold-deviation) part; ``rollout_state_cost`` = J - it.
        step_costs: (T, S, E, N) cost of the chosen sample per horizon step; step_input_costs: its input part.
        rollout_state_terms: (T, S, E, 9) the chosen sample's state cost summed over the horizon, by term
            (``STATE_TERMS`` order), on the solves that record step costs (every ``horizon_cost_every``-th),
            NaN elsewhere; None where not recorded.
        winner: (T, S, E) warm-start group of the chosen sample (-1: fallback or no MPC).
        fell: (E,) ended by a non-time-out termination; length: (E,) policy steps it lasted.
        qpos: (T, R, 19) generalized positions of the first R robots (for the video).
        mpc_fallbacks, student_fallbacks: robot-solves that used a fallback.
        step_dt: [s] policy step; timing: wall-clock profile [s] (see :func:`run_closed_loop`).
        replicas: S sampler seeds per episode (env s E + e plays episode e; set by whoever built the env).
        terrain: on a terrain scenario, each robot's terrain type and row (``closed_loop.episodes.terrain_of``).
        ground_z: (T, E) [m] terrain height under the base after the step (``env.scene.terrain.height_at``),
            NaN after the end (the stairs scenario's climbed fraction, ``eval.stairs.climbed_fraction``).
    """

    controller: str
    command: np.ndarray
    reward: np.ndarray
    initial_cost: np.ndarray
    initial_cost_terms: np.ndarray
    vel_error: np.ndarray
    power: np.ndarray
    speed: np.ndarray
    base_vel: np.ndarray
    rollout_cost: np.ndarray
    rollout_input_cost: np.ndarray
    mpc_initial_cost: np.ndarray
    step_costs: np.ndarray
    step_input_costs: np.ndarray
    winner: np.ndarray
    fell: np.ndarray
    length: np.ndarray
    qpos: np.ndarray
    mpc_fallbacks: int
    student_fallbacks: int
    step_dt: float
    timing: dict = field(default_factory=dict)
    replicas: int = 1
    terrain: dict | None = None
    ground_z: np.ndarray | None = None
    rollout_state_terms: np.ndarray | None = None

    @property
    def rollout_state_cost(self) -> np.ndarray:
        """(T, S, E) state-only rollout cost of the chosen sample, sum_k (x_k+1 - x_ref)^T Q (x_k+1 - x_ref)."""
        return self.rollout_cost - self.rollout_input_cost

    @property
    def step_state_costs(self) -> np.ndarray:
        """(T, S, E, N) state-only cost of the chosen sample per horizon step."""
        return self.step_costs - self.step_input_costs

    @property
    def time(self) -> np.ndarray:
        """(T,) [s] time at the end of each policy step (what ``viz.video.render_gif`` reads)."""
        return (np.arange(self.reward.shape[0]) + 1) * self.step_dt


class InitialCostProbe:
    """The MPC's state cost of the current state (thesis 7.3.1 "initial cost"), for any controller:
    the same references as the MPC controllers (CoM height reference, commanded velocity and yaw rate,
    flat attitude; the foothold reference does not enter the state cost). The closed loop gives it the controller's
    own ``baseline_config()``, so a controller run with ``com_height`` is scored against that height."""

    def __init__(self, sampler: SamplerConfig, baseline: BaselineConfig | None = None, ground: str = "flat",
                 height_fn=None):
        if ground not in GROUNDS:
            raise ValueError(f"ground must be one of {list(GROUNDS)}, got {ground!r}")
        if ground == "terrain" and height_fn is None:
            raise ValueError("ground 'terrain' needs the terrain map (env.scene.terrain.height_at)")
        self.sampler = sampler
        self.baseline = baseline or BaselineConfig(sampler=sampler)
        self.model = robot_srbd_model()
        self.ground = ground  # one of GROUNDS: the ground the MPC controllers plan on
        self.height_fn = height_fn  # ground "terrain": (x_w, y_w) -> z_w

    def _inputs(self, state, cmd: torch.Tensor):
        p_h = heuristic_footholds_h(state, cmd, self.baseline)
        return mpc_inputs(state, cmd, p_h, self.baseline.com_height, self.sampler, self.model,
                          **ground_inputs(self.ground, state, self.height_fn))

    def __call__(self, state, cmd: torch.Tensor) -> torch.Tensor:
        """(B,) initial cost."""
        srbd, refs, _ = self._inputs(state, cmd)
        return initial_cost(srbd.as_vector(), refs, self.sampler.weights)

    def terms(self, state, cmd: torch.Tensor) -> torch.Tensor:
        """(B, 9) the initial cost by term (``mpc.cost.STATE_TERMS``); sums to :meth:`__call__`'s value."""
        srbd, refs, _ = self._inputs(state, cmd)
        return state_cost_terms(srbd.as_vector(), refs.state_vector(), self.sampler.weights)


def _solves(controller: Controller, name: str):
    """A probe of the last step's solves: (E, S[, N]) values of ``SolveRecord.<name>``, solve s in column s."""
    return lambda env: torch.stack([getattr(r, name) for r in controller.step_records], dim=1)


def _height_under_base(env) -> torch.Tensor:
    """(E,) [m] terrain height under each base."""
    return env.scene.terrain.height_at(env.state.base_pos_w[:, 0], env.state.base_pos_w[:, 1])


def _vel_error(env) -> torch.Tensor:
    """(E,) [m/s] |v_xy - cmd_xy|, base frame."""
    return torch.linalg.vector_norm(base_velocity(env)[:, :2] - env.command_manager.command[:, :2], dim=-1)


def _qpos(robots: int):
    """A probe of the first ``robots`` robots' (R, 19) generalized positions (the video)."""
    return lambda env: torch.cat([env.state.base_pos_w[:robots], env.state.base_quat_w[:robots],
                                  env.state.joint_pos[:robots]], dim=1)


PROBES = {
    "base_vel": base_velocity,
    "ground_z": _height_under_base,
    "vel_error": _vel_error,
    "power": lambda env: motor_power(env.state.joint_torque, env.state.joint_vel),
    "speed": lambda env: torch.linalg.vector_norm(env.state.base_lin_vel_w[:, :2], dim=-1),
}
"""What the loop reads after every step, (E, ...) per robot on the env's device (kept where the state is the
episode's; the recorder reads them back once)."""

SYNC_EVERY = 25
"""Env steps (0.5 s) between the closed loop's reads of whether every episode has ended, on a device backend (every
step on the ``cpu`` backend: ``envs.recorder.record``'s ``sync_every``)."""


SOLVE_FIELDS = ("best_cost", "input_cost", "initial_cost", "step_costs", "step_input_costs", "state_terms",
                "warm_start_index",
                "fallback", "student_fallback")
"""The ``SolveRecord`` fields recorded per step and solve."""


def _per_solve(rec: EpisodeRecord, name: str, solves: int, n: int, trailing: tuple[int, ...] = (),
               fill: float = np.nan, dtype=np.float32) -> np.ndarray:
    """(T, S, E, ...) values of solve field ``name`` kept where the step was active (``fill`` elsewhere, and
    everywhere without an MPC)."""
    steps = rec.active.shape[0]
    if f"solve.{name}" not in rec.after:
        return np.full((steps, max(solves, 1), n, *trailing), fill, dtype)
    values = rec.masked(rec.after[f"solve.{name}"], rec.active, fill)  # (T, E, S, ...)
    return np.ascontiguousarray(np.swapaxes(values, 1, 2)).astype(dtype, copy=False)


def run_closed_loop(env, controller: Controller, num_steps: int | None = None, record_robots: int = 1,
                    stop_when_all_ended: bool = True) -> ClosedLoopTraces:
    """Run every env of ``env`` under ``controller`` for ``num_steps`` policy steps (default: one episode).

    Every metric is masked (NaN) after a robot's episode ended, so once every robot's episode has ended
    the remaining steps could change nothing but the video's frames: with ``stop_when_all_ended`` the
    loop stops there (a survival cell whose robots all fell early no longer simulates the rest of the
    15 s); the traces keep their ``num_steps`` rows (NaN as before) and the video's last frame is held. On a
    device backend (not ``cpu``) the loop looks every ``SYNC_EVERY`` steps (so it may stop up to 24 steps later,
    masked ones): nothing else is read back before the recorder's one read-back at the end.

    ``timing``: ``wall`` (the loop), ``kernel`` (MPC cost kernel), ``solve`` (whole MPC solves incl.
    the kernel, warm starts, decode), ``policy`` (network queries), ``probe`` (initial-cost metric), and
    ``robot_seconds_per_second`` = E x T x step_dt / wall, T the ``steps_simulated``.
    """
    n = env.num_envs
    sampler = controller.cfg.sampler
    ground = controller.cfg.ground  # every controller's cost on the ground its MPC plans on
    probe = InitialCostProbe(sampler, controller.cfg.baseline_config(), ground=ground,  # its height reference too
                             height_fn=env.scene.terrain.height_at if ground == "terrain" else None)
    solves = controller.commands_per_step if controller.cfg.uses_mpc else 0
    t_probe = [0.0]

    def initial_cost_terms(env) -> torch.Tensor:
        tic = time.perf_counter()
        terms = probe.terms(env.state, env.command_manager.command)
        t_probe[0] += time.perf_counter() - tic
        return terms

    after = {**PROBES, "qpos": _qpos(min(record_robots, n))}
    if controller.cfg.uses_mpc:
        after.update({f"solve.{name}": _solves(controller, name) for name in SOLVE_FIELDS})
    policy0 = controller.prepare_seconds
    sync_every = 1 if env.scene.cfg.backend == "cpu" else SYNC_EVERY
    rec = record(env, controller, after, num_steps, before={"initial_cost_terms": initial_cost_terms},
                 stop_when_all_ended=stop_when_all_ended, desc=f"{controller.name}, {n} robots", sync_every=sync_every)
    terms = rec.before["initial_cost_terms"]
    qpos = rec.after["qpos"].astype(np.float32, copy=False)
    qpos[rec.steps:] = qpos[rec.steps - 1]  # the video holds its last frame
    ok = lambda name: rec.masked(rec.after[name], rec.valid).astype(np.float32, copy=False)
    horizon = (sampler.horizon,)
    fallbacks = {}
    for name in ("fallback", "student_fallback"):
        flags = rec.after.get(f"solve.{name}")
        fallbacks[name] = 0 if flags is None else int((flags & rec.active[..., None]).sum())
    wall, policy, solve = rec.wall_s, controller.prepare_seconds - policy0, controller.solve_seconds
    kernel = controller.kernel_seconds()
    timing = {"wall": wall, "kernel": kernel, "solve": solve, "policy": policy,
              "probe": t_probe[0], "env_and_sim": wall - solve - policy - t_probe[0],
              "kernel_share": kernel / wall if wall > 0 else float("nan"),
              "robot_seconds_per_second": n * rec.steps * env.step_dt / wall if wall > 0 else float("nan"),
              "steps_simulated": rec.steps,
              "num_threads": torch.get_num_threads()}
    return ClosedLoopTraces(
        controller=controller.name, command=rec.command, reward=rec.masked(rec.reward, rec.active),
        initial_cost=rec.masked(terms.sum(-1), rec.active), initial_cost_terms=rec.masked(terms, rec.active),
        vel_error=ok("vel_error"), power=ok("power"), speed=ok("speed"), base_vel=ok("base_vel"),
        rollout_cost=_per_solve(rec, "best_cost", solves, n),
        rollout_input_cost=_per_solve(rec, "input_cost", solves, n),
        mpc_initial_cost=_per_solve(rec, "initial_cost", solves, n),
        step_costs=_per_solve(rec, "step_costs", solves, n, horizon),
        step_input_costs=_per_solve(rec, "step_input_costs", solves, n, horizon),
        rollout_state_terms=_per_solve(rec, "state_terms", solves, n, (len(STATE_TERMS),)),
        winner=_per_solve(rec, "warm_start_index", solves, n, fill=-1, dtype=np.int16),
        fell=rec.fell, length=rec.length, qpos=qpos, mpc_fallbacks=fallbacks["fallback"],
        student_fallbacks=fallbacks["student_fallback"], step_dt=float(env.step_dt), timing=timing,
        ground_z=ok("ground_z"))

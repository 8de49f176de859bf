"""Batched closed-loop episodes of one controller in a ``LocomotionEnv``, with the thesis's metrics (7.3.1).

Every env runs one episode (15 s by default) from the same start; data after an env's first
termination is masked out (its restart is simulated but not counted; the loop stops once every episode has
ended). Per policy step (50 Hz) and
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

from dls_quadruped.closed_loop.controllers import GROUNDS, Controller, ground_inputs
from dls_quadruped.core.progress import progress
from dls_quadruped.envs.mdp.kernels import motor_power
from dls_quadruped.eval.rollout import base_velocity
from dls_quadruped.mpc.baseline import (
    BaselineConfig,
    heuristic_footholds_h,
    mpc_inputs,
)
from dls_quadruped.mpc.config import SamplerConfig
from dls_quadruped.mpc.cost import STATE_TERMS, initial_cost, state_cost_terms
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
        winner: (T, S, E) warm-start group of the chosen sample (-1: fallback or no MPC).
        fell: (E,) ended by a non-time-out termination; length: (E,) policy steps it lasted.
        qpos: (T, R, 19) generalized positions of the first R robots (for the video).
        mpc_fallbacks, student_fallbacks: robot-solves that used a fallback.
        step_dt: [s] policy step; timing: wall-clock profile [s] (see :func:`run_closed_loop`).
        replicas: S sampler seeds per episode (env s E + e plays episode e; set by whoever built the env).
        terrain: on a terrain scenario, each robot's terrain type and row (``closed_loop.__main__.terrain_of``).
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
    flat attitude; the foothold reference does not enter the state cost)."""

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


def run_closed_loop(env, controller: Controller, num_steps: int | None = None, record_robots: int = 1,
                    stop_when_all_ended: bool = True) -> ClosedLoopTraces:
    """Run every env of ``env`` under ``controller`` for ``num_steps`` policy steps (default: one episode).

    Every metric is masked (NaN) after a robot's episode ended, so once every robot's episode has ended
    the remaining steps could change nothing but the video's frames: with ``stop_when_all_ended`` the
    loop stops there (a survival cell whose robots all fell early no longer simulates the rest of the
    15 s); the traces keep their ``num_steps`` rows (NaN as before) and the video's last frame is held.

    ``timing``: ``wall`` (the loop), ``kernel`` (MPC cost kernel), ``solve`` (whole MPC solves incl.
    the kernel, warm starts, decode), ``policy`` (network queries), ``probe`` (initial-cost metric), and
    ``robot_seconds_per_second`` = E x T x step_dt / wall, T the ``steps_simulated``.
    """
    n = env.num_envs
    steps = int(num_steps or env.max_episode_length)
    cpu = lambda t: t.detach().cpu()
    sampler = controller.cfg.sampler
    ground = controller.cfg.ground  # every controller's cost on the ground its MPC plans on
    probe = InitialCostProbe(sampler, ground=ground, height_fn=env.scene.terrain.height_at if ground == "terrain" else None)
    solves = getattr(controller, "solves_per_step", 0)
    horizon = sampler.horizon
    nan = np.nan
    reward = np.full((steps, n), nan, np.float32)
    init = np.full((steps, n), nan, np.float32)
    init_terms = np.full((steps, n, len(STATE_TERMS)), nan, np.float32)
    vel_err = np.full((steps, n), nan, np.float32)
    power = np.full((steps, n), nan, np.float32)
    speed = np.full((steps, n), nan, np.float32)
    base_vel = np.full((steps, n, 3), nan, np.float32)
    ground_z = np.full((steps, n), nan, np.float32)
    roll_cost = np.full((steps, max(solves, 1), n), nan, np.float32)
    roll_input = np.full_like(roll_cost, nan)
    mpc_init = np.full_like(roll_cost, nan)
    step_costs = np.full((steps, max(solves, 1), n, horizon), nan, np.float32)
    step_input = np.full_like(step_costs, nan)
    winner = np.full((steps, max(solves, 1), n), -1, np.int16)
    r = min(record_robots, n)
    qpos = np.zeros((steps, r, 19), np.float32)
    alive = torch.ones(n, dtype=torch.bool)
    fell = torch.zeros(n, dtype=torch.bool)
    length = torch.full((n,), steps, dtype=torch.long)
    command = cpu(env.command_manager.command).numpy().copy()
    t_policy = t_probe = 0.0
    mpc_fallbacks = student_fallbacks = 0
    obs = env.get_observations()
    simulated = 0
    wall0 = time.perf_counter()
    with torch.inference_mode(), progress(total=steps, desc=f"{controller.name}, {n} robots", unit="step",
                                          leave=False) as bar:
        for k in range(steps):
            bar.update(1)
            tic = time.perf_counter()
            terms = cpu(probe.terms(env.state, cpu(env.command_manager.command))).numpy()
            init_terms[k] = np.where(alive.numpy()[:, None], terms, nan)
            init[k] = np.where(alive.numpy(), terms.sum(-1), nan)
            t_probe += time.perf_counter() - tic
            tic = time.perf_counter()
            if controller.cfg.uses_mpc:
                controller.prepare(obs)
                t_policy += time.perf_counter() - tic
                first = len(controller.records)
                obs, rew, dones, extras = env.step_controlled(controller.physics)
                for j, rec in enumerate(controller.records[first:]):
                    live = alive.numpy()
                    roll_cost[k, j] = np.where(live, rec.best_cost.numpy(), nan)
                    roll_input[k, j] = np.where(live, rec.input_cost.numpy(), nan)
                    mpc_init[k, j] = np.where(live, rec.initial_cost.numpy(), nan)
                    step_costs[k, j] = np.where(live[:, None], rec.step_costs.numpy(), nan)
                    step_input[k, j] = np.where(live[:, None], rec.step_input_costs.numpy(), nan)
                    winner[k, j] = np.where(live, rec.warm_start_index.numpy(), -1)
                    mpc_fallbacks += int((rec.fallback & alive).sum())
                    student_fallbacks += int((rec.student_fallback & alive).sum())
                del controller.records[first:]
            else:
                action = controller.act(obs)
                t_policy += time.perf_counter() - tic
                obs, rew, dones, extras = env.step(action)
            done = cpu(dones).bool()
            time_out = cpu(extras["time_outs"]).bool()
            reward[k] = np.where(alive.numpy(), (cpu(rew) / env.step_dt).numpy(), nan)
            ok = (alive & ~done).numpy()
            s = env.state
            vel = cpu(base_velocity(env))
            cmd = cpu(env.command_manager.command)
            base_vel[k] = np.where(ok[:, None], vel.numpy(), nan)
            ground_z[k] = np.where(ok, cpu(env.scene.terrain.height_at(s.base_pos_w[:, 0], s.base_pos_w[:, 1])).numpy(), nan)
            vel_err[k] = np.where(ok, torch.linalg.vector_norm(vel[:, :2] - cmd[:, :2], dim=-1).numpy(), nan)
            power[k] = np.where(ok, cpu(motor_power(s.joint_torque, s.joint_vel)).numpy(), nan)
            speed[k] = np.where(ok, cpu(torch.linalg.vector_norm(s.base_lin_vel_w[:, :2], dim=-1)).numpy(), nan)
            qpos[k] = cpu(torch.cat([s.base_pos_w[:r], s.base_quat_w[:r], s.joint_pos[:r]], dim=1)).numpy()
            ended = alive & done
            fell |= ended & ~time_out
            length[ended] = k + 1
            alive &= ~done
            simulated = k + 1
            if stop_when_all_ended and not bool(alive.any()):
                qpos[k + 1:] = qpos[k]  # the video holds its last frame
                break
            if bool(done.any()):
                controller.reset(torch.nonzero(done).flatten())
    wall = time.perf_counter() - wall0
    kernel = controller.kernel_seconds()
    timing = {"wall": wall, "kernel": kernel, "solve": controller.solve_seconds, "policy": t_policy,
              "probe": t_probe, "env_and_sim": wall - controller.solve_seconds - t_policy - t_probe,
              "kernel_share": kernel / wall if wall > 0 else float("nan"),
              "robot_seconds_per_second": n * simulated * env.step_dt / wall if wall > 0 else float("nan"),
              "steps_simulated": simulated,
              "num_threads": torch.get_num_threads()}
    return ClosedLoopTraces(
        controller=controller.name, command=command, reward=reward, initial_cost=init, initial_cost_terms=init_terms,
        vel_error=vel_err,
        power=power, speed=speed, base_vel=base_vel, rollout_cost=roll_cost, rollout_input_cost=roll_input,
        mpc_initial_cost=mpc_init, step_costs=step_costs, step_input_costs=step_input, winner=winner, fell=fell.numpy(), length=length.numpy(), qpos=qpos,
        mpc_fallbacks=mpc_fallbacks, student_fallbacks=student_fallbacks, step_dt=float(env.step_dt), timing=timing,
        ground_z=ground_z)

"""The model-based baseline walking in an env (``python -m dls_quadruped.mpc.run``, its acceptance tests).

The closed loop's ``naive_warm_start`` controller (``closed_loop/mpc_controllers.NaiveWarmStartMPC``: the
model-based baseline of ``mpc/baseline.py``) runs inside a ``LocomotionEnv`` of the home task
(``envs/home_task.py``: robots in the home pose, no termination, the command fixed): one env step is one MPC
period, whose solve's first action, in world references (``MPCResult.foot_target_w``, ``force_w``), goes to the
backend through ``env.apply_references`` for ``mpc_period / physics_dt`` physics steps; ``envs/recorder.py``
records every step.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from dls_quadruped.closed_loop.controller_config import ControllerConfig
from dls_quadruped.closed_loop.mpc_controllers import NaiveWarmStartMPC
from dls_quadruped.envs.env import LocomotionEnv
from dls_quadruped.envs.home_task import home_task, physics_dt
from dls_quadruped.envs.recorder import BASE_PROBES, record
from dls_quadruped.mpc.baseline import BaselineConfig
from dls_quadruped.sim.terrain import TerrainConfig


@dataclass
class BaselineRun:
    """Recorded signals of a closed-loop baseline run, one row per MPC step (robot 0..B-1).

    Attributes:
        time: (T,) [s]; base_vel_w: (T, B, 3) [m/s]; base_height: (T, B) [m];
        roll, pitch: (T, B) [rad]; contact: (T, B, 4) commanded stance;
        best_cost, initial_cost: (T, B); fallen: (B,) bool; qpos: (T, B, 19).
    """

    time: np.ndarray
    base_vel_w: np.ndarray
    base_height: np.ndarray
    roll: np.ndarray
    pitch: np.ndarray
    contact: np.ndarray
    best_cost: np.ndarray
    initial_cost: np.ndarray
    fallen: np.ndarray
    qpos: np.ndarray


def _probes(ctrl: NaiveWarmStartMPC) -> dict:
    """What ``run_baseline`` records after every step, by ``BaselineRun`` field (and the fall flags)."""
    return {
        **BASE_PROBES,
        "contact": lambda env: env.state.contact_cmd,
        "best_cost": lambda env: ctrl.result.best_cost,
        "initial_cost": lambda env: ctrl.result.initial_cost,
        "qpos": lambda env: torch.cat([env.state.base_pos_w, env.state.base_quat_w, env.state.joint_pos], 1),
        "down": lambda env: env.state.base_contact | env.state.diverged,
    }


def run_baseline(
    cmd_vel_h: tuple[float, float, float] = (0.5, 0.0, 0.0),
    seconds: float = 15.0,
    num_robots: int = 1,
    cfg: BaselineConfig = BaselineConfig(),  # noqa: B008 -- frozen dataclass: an immutable default
    seed: int = 0,
    device: str = "cpu",
    terrain: TerrainConfig | None = None,
    origin_w: tuple[float, float] = (0.0, 0.0),
    backend: str = "cpu",
) -> BaselineRun:
    """Walk B robots with the model-based baseline for ``seconds`` (a whole number of MPC periods).

    ``terrain``: the ground (None: MuJoCo's plane), the robots spawned at ``origin_w`` (x, y) [m] on a flat patch
    at z = 0 (the MPC plans on flat ground at z = 0). ``device``: where the MPC computes; ``backend``: the
    simulator (``sim/registry.py``); the env's tensors are on the CPU.
    """
    period = cfg.sampler.mpc_period
    decimation = round(period / physics_dt())
    steps = round(seconds / period)
    task = home_task(num_robots, steps * period, decimation, cmd_vel_h, terrain, seed, origin_xy=origin_w,
                     backend=backend)
    env = LocomotionEnv(task, num_envs=num_robots, seed=seed, verbose=False)
    try:
        ctrl = NaiveWarmStartMPC(ControllerConfig.naive(cfg, seed), env, references=True, device=device)
        rec = record(env, ctrl, _probes(ctrl), steps, desc=f"model-based baseline, {num_robots} robots")
    finally:
        env.close()
    fields = {k: v for k, v in rec.after.items() if k != "down"}
    return BaselineRun(time=np.array([(k + 1) * period for k in range(steps)]), fallen=rec.after["down"].any(axis=0),
                       **fields)

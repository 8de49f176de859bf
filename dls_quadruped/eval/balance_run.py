"""Closed-loop episodes of the balance-controller baseline: stand, then trot in place.

Used by ``make demo`` and by the foundation's integration test. The balance controller
(``control/balance.py``) produces latent actions at ``high_level_hz``; the backend runs
physics and the low-level controller at 200 Hz.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import mujoco
import numpy as np
import torch

from dls_quadruped.control.balance import BalanceConfig, BalanceController
from dls_quadruped.control.latent_action import (
    LatentActionConfig,
    clip,
    flat_ground,
    to_world,
)
from dls_quadruped.core.rotations import quat_to_rotmat, rpy_from_rotmat
from dls_quadruped.robots.aliengo import constants as C
from dls_quadruped.sim.interface import SimConfig, home_state
from dls_quadruped.sim.registry import make_backend


@dataclass
class BalanceRun:
    """Recorded signals, one row per high-level step.

    Attributes:
        time: (T,) [s].
        trotting: (T,) bool, False during the standing phase.
        base_height: (T, B) [m]; roll, pitch: (T, B) [rad].
        base_vel_w: (T, B, 3) [m/s].
        foot_pos_w: (T, B, 4, 3) [m]; contact_cmd: (T, B, 4) commanded stance.
        foot_force_z: (T, B, 4) [N] measured vertical ground reaction.
        diverged, base_contact: (T, B) bool.
        qpos: (T, B, 19) MuJoCo generalized positions (for rendering).
    """

    time: np.ndarray
    trotting: np.ndarray
    base_height: np.ndarray
    roll: np.ndarray
    pitch: np.ndarray
    base_vel_w: np.ndarray
    foot_pos_w: np.ndarray
    contact_cmd: np.ndarray
    foot_force_z: np.ndarray
    diverged: np.ndarray
    base_contact: np.ndarray
    qpos: np.ndarray
    summary: dict = field(default_factory=dict)


def run_balance(
    num_envs: int = 64,
    stand_seconds: float = 10.0,
    trot_seconds: float = 10.0,
    cmd_vel_h: tuple[float, float, float] = (0.0, 0.0, 0.0),
    seed: int = 0,
    joint_noise: float = 0.05,
    yaw: float | torch.Tensor = 0.0,
    high_level_hz: float = 100.0,
    sim_cfg: SimConfig = SimConfig(num_workers=0),
    balance_cfg: BalanceConfig = BalanceConfig(),
    model: mujoco.MjModel | None = None,
    height_fn=flat_ground,
    origin_w: tuple[float, float] = (0.0, 0.0),
    backend: str = "cpu",
) -> BalanceRun:
    """Stand for ``stand_seconds`` then trot for ``trot_seconds`` with the balance controller.

    On a terrain scene (``model`` from ``sim.terrain.build_scene``) pass ``height_fn =
    terrain.height_at`` so touch-down targets get the true terrain height, and spawn the robots
    at ``origin_w`` (x, y) [m] on a flat patch at z = 0. ``backend``: the simulator (``sim/registry.py``); the
    controller and the records read its state on the CPU.
    """
    model = model if model is not None else mujoco.MjModel.from_xml_path(str(C.SCENE_PATH))
    decimation = int(round(1.0 / (high_level_hz * model.opt.timestep)))
    ctrl = BalanceController(balance_cfg)
    iface_cfg = LatentActionConfig()
    cmd = torch.tensor(cmd_vel_h, dtype=torch.float64).expand(num_envs, 3)
    rec: dict[str, list] = {k: [] for k in BalanceRun.__dataclass_fields__ if k != "summary"}
    n_stand = int(round(stand_seconds * high_level_hz))
    n_total = n_stand + int(round(trot_seconds * high_level_hz))
    with make_backend(backend, model, num_envs, sim_cfg) as sim:
        home = home_state(num_envs, seed, joint_noise, yaw)
        home["base_pos_w"] = home["base_pos_w"] + torch.tensor([*origin_w, 0.0], dtype=torch.float64)
        state = sim.reset(torch.arange(num_envs), **home).to("cpu")
        for k in range(n_total):
            trotting = k >= n_stand
            # standing has f = 0, so the phases keep their trot offsets until the trot starts
            action, _ = clip(ctrl(state, cmd, stand=not trotting), iface_cfg)
            p_td_w, F_w = to_world(action, state.base_pos_w.double(), _yaw(state), height_fn, iface_cfg)
            sim.set_references(action.f, action.d, p_td_w, F_w)
            state = sim.step(decimation).to("cpu")
            rpy = rpy_from_rotmat(quat_to_rotmat(state.base_quat_w.double()))
            rec["time"].append((k + 1) * decimation * model.opt.timestep)
            rec["trotting"].append(trotting)
            rec["base_height"].append(state.base_pos_w[:, 2].numpy().copy())
            rec["roll"].append(rpy[:, 0].numpy())
            rec["pitch"].append(rpy[:, 1].numpy())
            rec["base_vel_w"].append(state.base_lin_vel_w.numpy().copy())
            rec["foot_pos_w"].append(state.foot_pos_w.numpy().copy())
            rec["contact_cmd"].append(state.contact_cmd.numpy().copy())
            rec["foot_force_z"].append(state.foot_force_w[..., 2].numpy().copy())
            rec["diverged"].append(state.diverged.numpy().copy())
            rec["base_contact"].append(state.base_contact.numpy().copy())
            rec["qpos"].append(torch.cat([state.base_pos_w, state.base_quat_w, state.joint_pos], dim=1).numpy())
    run = BalanceRun(**{k: np.asarray(v) for k, v in rec.items()})
    run.summary = summarise(run, balance_cfg.height, balance_cfg.freq)
    return run


def _yaw(state) -> torch.Tensor:
    return rpy_from_rotmat(quat_to_rotmat(state.base_quat_w.double()))[:, 2]


def summarise(run: BalanceRun, height: float, cycle_hz: float = 1.5) -> dict:
    """Pass/fail numbers of the foundation criteria."""
    out = {}
    for name, mask in (("stand", ~run.trotting), ("trot", run.trotting)):
        if not mask.any():
            continue
        h = run.base_height[mask]
        out[f"{name}_height_err_max"] = float(np.abs(h - height).max())
        out[f"{name}_roll_abs_max"] = float(np.abs(run.roll[mask]).max())
        out[f"{name}_pitch_abs_max"] = float(np.abs(run.pitch[mask]).max())
    if run.trotting.any():
        # highest foot-centre lift above the ground within each gait cycle; the worst foot/cycle/robot
        lift = run.foot_pos_w[run.trotting][..., 2] - C.FOOT_RADIUS  # (T, B, 4)
        dt = float(run.time[1] - run.time[0])
        per_cycle = max(1, int(round(1.0 / (cycle_hz * dt))))
        n = max(per_cycle, (lift.shape[0] // per_cycle) * per_cycle)
        windows = lift[:n].reshape(-1, per_cycle, *lift.shape[1:])
        out["trot_min_foot_lift"] = float(windows.max(axis=1).min())
    out["num_fallen"] = int((run.base_contact.any(axis=0) | run.diverged.any(axis=0)).sum())
    return out

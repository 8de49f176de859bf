"""Closed-loop episodes of the balance-controller baseline: stand, then trot in place.

Used by ``make demo`` and by the foundation's integration test. The balance controller
(``control/balance.py``) runs inside a ``LocomotionEnv`` of the home task (``envs/home_task.py``: robots
in the home pose, no termination) as a controller of the env (``envs/controller.py``): at ``high_level_hz`` its
latent action, clipped (Table 1) and turned into world references, goes to the backend, which runs
physics and the low-level controller at 200 Hz; ``envs/recorder.py`` records every step.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from dls_quadruped.control.balance import BalanceConfig, BalanceController
from dls_quadruped.control.latent_action import (
    LatentActionConfig,
    TerrainHeightFn,
    clip,
    flat_ground,
    to_world,
)
from dls_quadruped.core.rotations import quat_to_rotmat, rpy_from_rotmat
from dls_quadruped.envs.controller import EnvController, References
from dls_quadruped.envs.env import LocomotionEnv
from dls_quadruped.envs.home_task import home_task, physics_dt
from dls_quadruped.envs.recorder import BASE_PROBES, record
from dls_quadruped.robots.aliengo import constants as C
from dls_quadruped.sim.terrain import TerrainConfig


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


class BalanceEnvController(EnvController):
    """The balance controller as a controller of the env (``envs/controller.py``), one command per env step: it
    stands (``stand_steps`` steps: f = 0, d = 1, the phases keep their trot offsets) or trots, clips its latent
    action (Table 1) and turns it into world references with touch-downs at ``height_fn``, held for the step's
    ``env.decimation`` physics steps (``env.apply_references``).

    Args:
        cmd_vel_h: (B, 3) float64 command (v_x, v_y [m/s] in frame H, yaw rate [rad/s]).
    """

    name = "balance"

    def __init__(self, env, cfg: BalanceConfig, cmd_vel_h: torch.Tensor, stand_steps: int,
                 height_fn: TerrainHeightFn = flat_ground):
        super().__init__(env, physics_steps=env.decimation)
        self.cmd, self.stand_steps, self.height_fn = cmd_vel_h, stand_steps, height_fn
        self.controller = BalanceController(cfg)
        self.action_cfg = LatentActionConfig()
        self.steps = 0

    @property
    def trotting(self) -> bool:
        """The next step trots."""
        return self.steps >= self.stand_steps

    def act(self, obs, substep: int) -> References:
        state = self.env.state
        action, _ = clip(self.controller(state, self.cmd, stand=not self.trotting), self.action_cfg)
        p_td_w, F_w = to_world(action, state.base_pos_w.double(), _yaw(state), self.height_fn, self.action_cfg)
        self.steps += 1
        return References(action.f, action.d, p_td_w, F_w)


PROBES = {
    **BASE_PROBES,
    "foot_pos_w": lambda env: env.state.foot_pos_w,
    "contact_cmd": lambda env: env.state.contact_cmd,
    "foot_force_z": lambda env: env.state.foot_force_w[..., 2],
    "diverged": lambda env: env.state.diverged,
    "base_contact": lambda env: env.state.base_contact,
    "qpos": lambda env: torch.cat([env.state.base_pos_w, env.state.base_quat_w, env.state.joint_pos], dim=1),
}
"""What ``run_balance`` records after every step, by ``BalanceRun`` field."""


def run_balance(
    num_envs: int = 64,
    stand_seconds: float = 10.0,
    trot_seconds: float = 10.0,
    cmd_vel_h: tuple[float, float, float] = (0.0, 0.0, 0.0),
    seed: int = 0,
    joint_noise: float = 0.05,
    yaw: float | torch.Tensor = 0.0,
    high_level_hz: float = 100.0,
    num_workers: int = 0,
    balance_cfg: BalanceConfig = BalanceConfig(),  # noqa: B008 -- frozen dataclass: an immutable default
    terrain: TerrainConfig | None = None,
    height_fn: TerrainHeightFn | None = None,
    origin_w: tuple[float, float] = (0.0, 0.0),
    backend: str = "cpu",
) -> BalanceRun:
    """Stand for ``stand_seconds`` then trot for ``trot_seconds`` with the balance controller.

    ``terrain``: the ground (None: MuJoCo's plane), the robots spawned at ``origin_w`` (x, y) [m] on a flat patch
    at z = 0; the touch-down targets get ``height_fn`` (default: z = 0 on the plane, else the terrain's exact
    height). ``yaw``: [rad] heading, one for all robots or (num_envs,); ``joint_noise``: [rad] uniform on the
    nominal joints (seeded with ``seed``). ``num_workers``: simulator worker processes (0: in-process);
    ``backend``: the simulator (``sim/registry.py``); the controller and the records read its state on the CPU.
    """
    decimation = round(1.0 / (high_level_hz * physics_dt()))
    n_stand = round(stand_seconds * high_level_hz)
    n_total = n_stand + round(trot_seconds * high_level_hz)
    task = home_task(num_envs, n_total * decimation * physics_dt(), decimation, cmd_vel_h, terrain, seed,
                     joint_noise, yaw, origin_w, num_workers, backend)
    env = LocomotionEnv(task, num_envs=num_envs, seed=seed, verbose=False)
    try:
        if height_fn is None:
            height_fn = flat_ground if env.scene.terrain.is_plane else _terrain_height(env.scene.terrain)
        cmd = torch.tensor(cmd_vel_h, dtype=torch.float64).expand(num_envs, 3)
        ctrl = BalanceEnvController(env, balance_cfg, cmd, n_stand, height_fn)
        rec = record(env, ctrl, PROBES, n_total, desc=f"balance, {num_envs} robots")
    finally:
        env.close()
    time = np.array([(k + 1) * decimation * physics_dt() for k in range(n_total)])
    run = BalanceRun(time=time, trotting=np.arange(n_total) >= n_stand, **rec.after)
    run.summary = summarise(run, balance_cfg.height, balance_cfg.freq)
    return run


def _terrain_height(terrain) -> TerrainHeightFn:
    """The terrain's exact height lookup (float32) for touch-down targets in the caller's dtype."""
    return lambda x, y: terrain.height_at(x.float(), y.float()).to(x.dtype)


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
        per_cycle = max(1, round(1.0 / (cycle_hz * dt)))
        n = max(per_cycle, (lift.shape[0] // per_cycle) * per_cycle)
        windows = lift[:n].reshape(-1, per_cycle, *lift.shape[1:])
        out["trot_min_foot_lift"] = float(windows.max(axis=1).min())
    out["num_fallen"] = int((run.base_contact.any(axis=0) | run.diverged.any(axis=0)).sum())
    return out

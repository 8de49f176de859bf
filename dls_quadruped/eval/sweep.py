"""Shared machinery of the sweep scenarios (survival, stairs, speed, omni, cot, gait; thesis 7.1).

A sweep is a list of C *conditions* (a speed, a step height, a direction x magnitude cell), each
run for ``per`` episodes; env ``i`` runs condition ``i // per`` (condition-major), every episode in
parallel. Statistics per condition come from ``metrics.grouped_rate`` / ``grouped_mean``.

Probes (``env -> (B, ...)``, read after every policy step by ``rollout.record_episodes``):

* ``velocity``: (v_x, v_y [m/s], omega_z [rad/s]), base frame (what the tracking rewards see);
* ``speed_h``: |v_xy| [m/s] of the base, world frame;
* ``power``: sum over joints of max(tau qdot + alpha tau^2, 0) [W], the numerator of eq. 4.3.7
  (``kernels.cost_of_transport`` at speed 1 m/s and weight 1 N); tau is the torque of the last of
  the ``decimation`` physics steps, so the power is sampled at the policy rate;
* ``contact``: (4,) foot in contact (vertical ground force > 1 N), legs FL, FR, RL, RR;
* ``freq``, ``duty``: (4,) step frequency f [Hz] and duty cycle d of the applied latent action;
* ``base_pos``: (3,) [m] base position, world; ``ground_z``: [m] terrain height under the base.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from dls_quadruped.eval.rollout import Probe, Recording, base_velocity, record_episodes
from dls_quadruped.eval.scenario import EvalOptions

POWER_ALPHA = 0.3
"""[W / (N m)^2] Joule-heating weight alpha of eq. 4.3.7 (the reward term's default)."""


def _speed_h(env) -> torch.Tensor:
    return torch.linalg.vector_norm(env.state.base_lin_vel_w[:, :2], dim=-1)


def _power(env) -> torch.Tensor:
    from dls_quadruped.envs.mdp.kernels import cost_of_transport

    s = env.state
    one = torch.ones(s.joint_torque.shape[0], device=s.joint_torque.device)
    return cost_of_transport(s.joint_torque, s.joint_vel, one, weight=1.0, alpha=POWER_ALPHA, min_speed=1.0)


def _contact(env) -> torch.Tensor:
    from dls_quadruped.envs.mdp.observations import foot_contact

    return foot_contact(env)


def _ground_z(env) -> torch.Tensor:
    p = env.state.base_pos_w
    return env.scene.terrain.height_at(p[:, 0], p[:, 1])


PROBES: dict[str, Probe] = {
    "velocity": base_velocity,
    "speed_h": _speed_h,
    "power": _power,
    "contact": _contact,
    "freq": lambda env: env.action_manager.applied_physical[:, 0:4],
    "duty": lambda env: env.action_manager.applied_physical[:, 4:8],
    "base_pos": lambda env: env.state.base_pos_w,
    "ground_z": _ground_z,
}
"""Every probe by name; a scenario records the ones it needs."""


def repeat_conditions(conditions: np.ndarray, per: int) -> tuple[np.ndarray, np.ndarray]:
    """(C, 3) commands -> ((C per, 3) commands, (C per,) condition index), condition-major."""
    if per < 1:
        raise ValueError(f"episodes per condition must be >= 1, got {per}")
    conditions = np.asarray(conditions, dtype=float)
    return np.repeat(conditions, per, axis=0), np.repeat(np.arange(len(conditions)), per)


def settled(rec: Recording, settle_s: float) -> np.ndarray:
    """(T, E) valid steps after the first ``settle_s`` seconds."""
    steps = rec.valid.shape[0]
    return rec.valid & (np.arange(steps)[:, None] >= round(settle_s / rec.step_dt))


def run(task, policy_path: Path, opts: EvalOptions, num_envs: int, probes: list[str],
        rows: np.ndarray | None = None) -> tuple[Recording, dict]:
    """Build the env of ``task`` (a ``TaskConfig``), load the policy, record one episode per env.

    Args:
        rows: (num_envs,) terrain row (difficulty level) of every env, placed before the episode;
            None keeps the scene's own placement.

    Returns:
        (the recording, env facts: step_dt, robot_weight [N], terrain rows/cols and each env's
        terrain origin (E, 3) [m]).
    """
    from dls_quadruped.envs.env import LocomotionEnv
    from dls_quadruped.eval.policy import load_policy

    env = LocomotionEnv(task, num_envs=num_envs, device=opts.device, seed=opts.seed, verbose=False)
    try:
        if rows is not None:
            place_on_rows(env, np.asarray(rows))
        policy = load_policy(policy_path, env)
        torch.manual_seed(opts.seed)
        rec = record_episodes(env, policy, {name: PROBES[name] for name in probes})
        facts = {"robot_weight_n": float(env.robot_weight), "terrain_rows": env.scene.terrain.num_rows,
                 "terrain_cols": env.scene.terrain.num_cols,
                 "env_origins": env.scene.env_origins.cpu().numpy().copy(),
                 "terrain_types": env.scene.terrain_types.cpu().numpy().copy(),
                 "terrain_levels": env.scene.terrain_levels.cpu().numpy().copy()}
    finally:
        env.close()
    return rec, facts


def place_on_rows(env, rows: np.ndarray) -> None:
    """Move every env to terrain row ``rows[i]`` of its column and restart its episode there."""
    target = torch.as_tensor(rows, dtype=torch.long, device=env.device)
    if target.shape != (env.num_envs,) or target.min() < 0 or target.max() >= env.scene.terrain.num_rows:
        raise ValueError(f"rows must be ({env.num_envs},) in [0, {env.scene.terrain.num_rows}), got "
                         f"{tuple(target.shape)}")
    ids = torch.arange(env.num_envs, device=env.device)
    env.scene.update_levels(ids, target - env.scene.terrain_levels)
    env.reset()


def header(name: str, description: str, policy_path: Path, opts: EvalOptions, rec: Recording,
           per: int, conditions: int) -> dict:
    """The fields every sweep result starts with."""
    return {"scenario": name, "description": description, "policy": str(policy_path), "seed": opts.seed,
            "episode_length_s": rec.valid.shape[0] * rec.step_dt, "episode_steps": int(rec.valid.shape[0]),
            "episodes": int(rec.valid.shape[1]), "episodes_per_condition": per, "conditions": conditions}


def survival_of(rec: Recording, group: np.ndarray | None = None, num_groups: int = 1) -> list[dict]:
    """Survival (episode reached its time-out) per group, Wilson intervals."""
    from dls_quadruped.eval import metrics as M

    group = np.zeros(len(rec.fell), dtype=int) if group is None else group
    return M.grouped_rate(~rec.fell.astype(bool), group, num_groups)


def pct(b: dict) -> str:
    """'97.5 % [93.1, 99.2] (n = 128)' of a ``metrics.binomial``."""
    return f"{100 * b['rate']:.1f} % [{100 * b['ci95'][0]:.1f}, {100 * b['ci95'][1]:.1f}] (n = {b['n']})"


def savefig(fig, path: Path) -> None:
    import matplotlib.pyplot as plt

    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def pyplot():
    """matplotlib.pyplot on the Agg backend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def yerr(value, lo, hi) -> list[np.ndarray]:
    """Error-bar lengths [value - lo, hi - value] for matplotlib: missing ends (NaN, None) as 0."""
    value, lo, hi = (np.asarray(x, dtype=float) for x in (value, lo, hi))
    return [np.nan_to_num(np.clip(value - lo, 0, None)), np.nan_to_num(np.clip(hi - value, 0, None))]

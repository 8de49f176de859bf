"""Distillation metrics (thesis 7.2.1): test-set MSE (eq. 7.2.1) and simulation performance SP (eq. 7.2.2).

MSE: mean over the held-out datapoints and over the D outputs of (label - student)^2 in the label
space (spline curvature / 10, what the student is trained on), i.e. ``torch.nn.MSELoss``.

SP: the env is stepped with the decoded *first* action of the student for 15 s episodes (every
env one episode, started together from the same seeded resets for every policy), the base-task
reward is summed until the episode ends (a fall ends it early), and

    SP = (sum_i R_stud,i - sum_i R_0,i) / (sum_i R_exp,i - sum_i R_0,i)            (7.2.2)

with R_0 an untrained student and R_exp the expert on the same episodes. The 95 % interval is a
paired bootstrap over episodes (the same episode index is the same start and command for all
three policies). Survival (no termination but the time-out within the episode) has a Wilson interval.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch

from dls_quadruped.eval.metrics import wilson_interval
from dls_quadruped.learning.dataset import DiskDataset


@torch.no_grad()
def held_out_mse(net: Callable[[torch.Tensor], torch.Tensor], data: DiskDataset, batch: int = 8192) -> float:
    """Mean squared error (all rows, all outputs) of ``net`` (label-space outputs) on ``data``."""
    positions = data.positions()
    total, n = 0.0, 0
    for c in range(0, len(positions), batch):
        obs, labels = data.rows(positions[c:c + batch])
        total += float((net(obs) - labels).square().sum())
        n += labels.numel()
    return total / max(n, 1)


@torch.no_grad()
def episode_returns(env, policy: Callable[[torch.Tensor], torch.Tensor], seeds: list[int],
                    obs_group: str = "policy") -> dict[str, np.ndarray]:
    """One batch of episodes per seed (torch seeded, then every env reset), first episode only.

    Like ``eval.rollout.run_episodes`` but under ``no_grad`` instead of ``inference_mode``: the
    env goes on collecting afterwards, and an in-process simulator would keep inference tensors
    created at a reset, which later in-place updates refuse.

    Returns:
        {"return": (E,) summed reward of the env (Σ_t Σ_k w_k r_k dt) until the first termination
        or the time-out, "survived": (E,) bool, not terminated before the time-out}.
    """
    returns, survived = [], []
    for seed in seeds:
        torch.manual_seed(seed)
        obs = env.reset()[0][obs_group]
        total = torch.zeros(env.num_envs, dtype=torch.float64)
        alive = torch.ones(env.num_envs, dtype=torch.bool)
        fell = torch.zeros(env.num_envs, dtype=torch.bool)
        for _ in range(int(env.max_episode_length)):
            obs_td, reward, dones, extras = env.step(policy(obs))
            obs = obs_td[obs_group]
            total += torch.where(alive, reward.double().cpu(), 0.0)  # the ending step's reward counts
            done = dones.bool().cpu()
            fell |= alive & done & ~extras["time_outs"].bool().cpu()
            alive &= ~done
            if not alive.any():
                break
        returns.append(total.numpy())
        survived.append((~fell).numpy())
    return {"return": np.concatenate(returns), "survived": np.concatenate(survived)}


def simulation_performance(r_stud: np.ndarray, r_exp: np.ndarray, r_0: np.ndarray, n_boot: int = 2000,
                           seed: int = 0) -> dict:
    """SP (eq. 7.2.2) with a 95 % paired-bootstrap interval.

    Args:
        r_stud, r_exp, r_0: (E,) episode returns of the student, the expert and the untrained
            student on the same E episodes.
    """
    r_stud, r_exp, r_0 = (np.asarray(r, dtype=np.float64) for r in (r_stud, r_exp, r_0))
    if not r_stud.shape == r_exp.shape == r_0.shape or r_stud.ndim != 1:
        raise ValueError(f"returns must be three (E,) arrays, got {r_stud.shape}, {r_exp.shape}, {r_0.shape}")
    denom = r_exp.sum() - r_0.sum()
    sp = float((r_stud.sum() - r_0.sum()) / denom) if denom != 0 else float("nan")
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, len(r_stud), size=(n_boot, len(r_stud)))
    d = r_exp[idx].sum(1) - r_0[idx].sum(1)
    with np.errstate(divide="ignore", invalid="ignore"):
        boot = (r_stud[idx].sum(1) - r_0[idx].sum(1)) / d
    boot = boot[np.isfinite(boot)]
    lo, hi = (np.percentile(boot, [2.5, 97.5]) if len(boot) else (float("nan"), float("nan")))
    return {"sp": sp, "ci95": [float(lo), float(hi)], "episodes": len(r_stud),
            "mean_return": {"student": float(r_stud.mean()), "expert": float(r_exp.mean()),
                            "untrained": float(r_0.mean())}}


def survival(survived: np.ndarray) -> dict:
    """Share of episodes that lasted the full 15 s, with its 95 % Wilson interval."""
    k, n = int(np.sum(survived)), len(survived)
    lo, hi = wilson_interval(k, n)
    return {"rate": k / max(n, 1), "ci95": [float(lo), float(hi)], "episodes": n}

"""Summaries of closed-loop traces, as thesis 7.3.1 reports them: medians with first and third quartiles.

The thesis pools its per-step metrics over 100 trajectories and reports medians because resets
produce aberrant cost values; we pool every step of every episode until it ends (a fallen episode
contributes its steps up to the fall) and give the number of episodes and of pooled values.
"""

from __future__ import annotations

import numpy as np

from dls_quadruped.closed_loop.runner import ClosedLoopTraces
from dls_quadruped.eval import metrics as M
from dls_quadruped.robots.aliengo import constants as C

SETTLE_S = 2.0
"""[s] start-up transient excluded from the velocity-tracking error and the cost of transport."""


def cost_of_transport(traces: ClosedLoopTraces, settle_s: float = SETTLE_S) -> np.ndarray:
    """(E,) per-episode CoT (eq. 4.3.7) = mean motor power / (m g mean horizontal speed) over the
    steps after the settle (NaN for an episode that ended before)."""
    settle = round(settle_s / traces.step_dt)
    p, v = traces.power[settle:].astype(float), traces.speed[settle:].astype(float)
    ok = np.isfinite(p) & np.isfinite(v)
    count = ok.sum(0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_p = np.where(count > 0, np.where(ok, p, 0.0).sum(0) / count, np.nan)
        mean_v = np.where(count > 0, np.where(ok, v, 0.0).sum(0) / count, np.nan)
        return mean_p / (C.TOTAL_MASS * C.GRAVITY * mean_v)


def summarize(traces: ClosedLoopTraces, settle_s: float = SETTLE_S) -> dict:
    """JSON-able metrics of one controller's episodes (see the module docstring)."""
    e = traces.reward.shape[1]
    survived = int((~traces.fell).sum())
    settle = round(settle_s / traces.step_dt)
    out = {
        "controller": traces.controller,
        "episodes": e,
        "survival": {"rate": survived / e if e else float("nan"), "survived": survived, "n": e,
                     "ci95": list(M.wilson_interval(survived, e))},
        "rl_reward": {**M.median_iqr(traces.reward), "mean": M.mean_ci(traces.reward)["mean"]},
        "rl_reward_episode_mean": M.mean_ci(np.nanmean(traces.reward, axis=0)),
        "initial_cost": M.median_iqr(traces.initial_cost),
        "vel_error": M.median_iqr(traces.vel_error[settle:]),
        "cost_of_transport": M.median_iqr(cost_of_transport(traces, settle_s)),
    }
    if np.isfinite(traces.rollout_cost).any():
        n = traces.step_costs.shape[-1]
        winners = traces.winner[traces.winner >= 0]
        out.update({
            "rollout_cost": M.median_iqr(traces.rollout_cost),
            "mpc_initial_cost": M.median_iqr(traces.mpc_initial_cost),
            "horizon_cost": [M.median_iqr(traces.step_costs[..., k]) for k in range(n)],
            "warm_start_won": {str(g): float((winners == g).mean()) for g in np.unique(winners)} if winners.size else {},
            "mpc_fallbacks": traces.mpc_fallbacks,
            "student_fallbacks": traces.student_fallbacks,
        })
    out["timing"] = dict(traces.timing)
    return out

"""Summaries of closed-loop traces: thesis 7.3.1's medians and quartiles, computed per episode first.

Every per-step metric (RL reward, initial cost, velocity error; per solve: rollout costs) is reduced
to one value per episode (its median over the episode's steps until it ended), then summarised across
episodes: median, first and third quartiles, and a 95 % interval of the median from a two-level
bootstrap over episodes and sampler seeds (``eval.metrics.episode_summary``). So a robot that fell
after 1 s weighs as much as one that walked 15 s, and correlated steps of one episode are not counted
as independent. ``pooled`` keeps the thesis's own statistic, the median over every step of every
episode. The per-episode values are kept (``per_episode``), so two controllers can be compared by
their paired differences on the same episodes (``eval.metrics.paired_difference``).

Sampler seeds: a run of S seeds on E episodes holds E x S envs, env ``s E + e`` playing episode e with
seed s (``replicas``); per-episode values are (S, E) arrays.

Rollout cost: ``rollout_cost`` is the state-only cost of the chosen sample, the comparison figure
(``mpc/cost.py``: the input term is zero for a naive warm start by construction); ``rollout_cost_full``
is the J the sampler minimised. The initial cost is a state cost by definition (no input at x_0).

By term (for paired differences only, under ``per_episode``): ``initial_term_<name>`` and
``initial_cost_mean`` are per-episode means of the initial cost's terms and total (means add up, medians do
not); ``rollout_term_<name>`` and ``rollout_terms_mean`` the same for the chosen sample's state rollout cost,
over the solves that record it (every ``horizon_cost_every``-th, from the reference rollout).
"""

from __future__ import annotations

import numpy as np

from dls_quadruped.closed_loop.loop import ClosedLoopTraces
from dls_quadruped.eval import metrics as M
from dls_quadruped.mpc.cost import STATE_TERMS
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


def winner_switches_per_s(winner: np.ndarray, step_dt: float) -> np.ndarray:
    """(T, S, E) warm-start group of each solve's winner (-1: no valid solve) -> (E,) switches per second:
    the number of consecutive valid solves whose winning group differs, over the time those solves span
    (NaN for an episode with fewer than two valid solves). Fig. 34's "switches per second"."""
    w = np.asarray(winner).reshape(-1, winner.shape[-1])  # solves in time order
    period = step_dt / winner.shape[1]
    out = np.full(w.shape[1], np.nan)
    for e in range(w.shape[1]):
        col = w[:, e][w[:, e] >= 0]
        if col.size >= 2:
            out[e] = float((col[1:] != col[:-1]).sum()) / ((col.size - 1) * period)
    return out


def per_episode_median(x: np.ndarray) -> np.ndarray:
    """(T, ..., E) per-step values (NaN after the episode's end) -> (E,) median of each episode's finite values."""
    flat = np.asarray(x, dtype=float).reshape(-1, x.shape[-1])
    out = np.full(flat.shape[1], np.nan)
    for e in range(flat.shape[1]):  # E is small (episodes of one cell); nanmedian warns on empty columns
        col = flat[:, e]
        col = col[np.isfinite(col)]
        if col.size:
            out[e] = np.median(col)
    return out


def per_episode_mean(x: np.ndarray) -> np.ndarray:
    """(T, E) per-step values (NaN after the episode's end) -> (E,) mean of each episode's finite values (NaN for
    none). Means add up where medians do not: the terms' means sum to the total's."""
    flat = np.asarray(x, dtype=float).reshape(-1, x.shape[-1])
    ok = np.isfinite(flat)
    count = ok.sum(0)
    total = np.where(ok, flat, 0.0).sum(0)
    return np.where(count > 0, total / np.maximum(count, 1), np.nan)


def _units(values: np.ndarray, replicas: int) -> np.ndarray:
    """(E x S,) env values -> (S, E): env s E + e is episode e with sampler seed s."""
    return np.asarray(values, dtype=float).reshape(replicas, -1)


def summarize(traces: ClosedLoopTraces, settle_s: float = SETTLE_S, replicas: int = 1) -> dict:
    """JSON-able metrics of one controller's episodes (see the module docstring).

    Args:
        traces: one run; its env count must be a multiple of ``replicas``.
        settle_s: [s] start-up left out of the velocity error and the CoT.
        replicas: S sampler seeds on the same episodes (env s E + e = episode e, seed s).
    """
    n = traces.reward.shape[1]
    if replicas < 1 or n % replicas:
        raise ValueError(f"replicas must divide the {n} envs, got {replicas}")
    episodes = n // replicas
    settle = round(settle_s / traces.step_dt)
    survived_env = (~traces.fell).astype(float)
    survived = int(survived_env.sum())
    per_ep = {
        "rl_reward": per_episode_median(traces.reward),
        "rl_return": np.nansum(np.asarray(traces.reward, dtype=float), axis=0),  # sum of the per-step rewards
        "initial_cost": per_episode_median(traces.initial_cost),
        "vel_error": per_episode_median(traces.vel_error[settle:]),
        "cost_of_transport": cost_of_transport(traces, settle_s),
        "survived": survived_env,
    }
    # the initial cost term by term as per-episode means (they add up to ``initial_cost_mean``): paired
    # differences of two controllers show which terms carry a gap (docs/experiments/warm_start.md)
    per_ep["initial_cost_mean"] = per_episode_mean(traces.initial_cost)
    for i, name in enumerate(STATE_TERMS):
        per_ep[f"initial_term_{name}"] = per_episode_mean(traces.initial_cost_terms[..., i])
    stairs = (traces.terrain or {}).get("stairs")
    if stairs is not None:
        fraction, top = stairs_episodes(traces)
        per_ep.update({"climbed_fraction": fraction, "reached_top": top.astype(float)})
    mpc = bool(np.isfinite(traces.rollout_cost).any())
    if mpc:
        per_ep.update({"winner_switches_per_s": winner_switches_per_s(traces.winner, traces.step_dt),
                       "rollout_cost": per_episode_median(traces.rollout_state_cost),
                       "rollout_cost_full": per_episode_median(traces.rollout_cost),
                       "mpc_initial_cost": per_episode_median(traces.mpc_initial_cost)})
        terms = traces.rollout_state_terms
        if terms is not None and np.isfinite(terms).any():
            # the chosen sample's state cost by term, per-episode means over the solves that record them (every
            # ``horizon_cost_every``-th); ``rollout_terms_mean`` is their sum, the same solves' state cost
            finite = np.where(np.isfinite(terms).all(-1, keepdims=True), terms, np.nan)
            per_ep["rollout_terms_mean"] = per_episode_mean(finite.sum(-1))
            for i, name in enumerate(STATE_TERMS):
                per_ep[f"rollout_term_{name}"] = per_episode_mean(finite[..., i])
    units = {k: _units(v, replicas) for k, v in per_ep.items()}
    out = {
        "controller": traces.controller,
        "episodes": episodes,
        "replicas": replicas,
        "survival": {"rate": survived / n if n else float("nan"), "survived": survived, "n": n,
                     "ci95": list(M.wilson_interval(survived, n)),
                     "ci95_bootstrap": M.bootstrap_ci(units["survived"], np.nanmean),
                     # copies of one episode are not independent: Wilson's interval with the E episodes as
                     # the trials (conservative, and unlike the bootstrap not a point at 0 % or 100 %)
                     "ci95_episodes": (list(M.wilson_interval(survived / n * episodes, episodes)) if n
                                       else [np.nan] * 2)},
        "rl_reward_episode_mean": M.mean_ci(np.nanmean(traces.reward, axis=0)),
        "per_episode": {k: v.tolist() for k, v in units.items()},
    }
    pooled = {"rl_reward": traces.reward, "initial_cost": traces.initial_cost, "vel_error": traces.vel_error[settle:]}
    if mpc:
        pooled.update({"rollout_cost": traces.rollout_state_cost, "rollout_cost_full": traces.rollout_cost,
                       "mpc_initial_cost": traces.mpc_initial_cost})
    for key, v in units.items():
        if key in ("survived", "reached_top"):  # rates: ``survival`` and ``stairs`` hold them with their intervals
            continue
        if key.startswith(("initial_term_", "rollout_term")) or key == "initial_cost_mean":
            continue  # per-episode values for paired differences; ``initial_cost_terms`` summarises the terms
        out[key] = M.episode_summary(v)
        if key in pooled:
            out[key]["pooled"] = M.median_iqr(pooled[key])
    if mpc:
        winners = traces.winner[traces.winner >= 0]
        horizon = traces.step_costs.shape[-1]
        out.update({
            "horizon_cost": [M.episode_summary(_units(per_episode_median(traces.step_state_costs[..., k]), replicas))
                             for k in range(horizon)],
            "horizon_cost_full": [M.episode_summary(_units(per_episode_median(traces.step_costs[..., k]), replicas))
                                  for k in range(horizon)],
            "warm_start_won": ({str(g): float((winners == g).mean()) for g in np.unique(winners)} if winners.size
                               else {}),
            "mpc_fallbacks": traces.mpc_fallbacks,
            "student_fallbacks": traces.student_fallbacks,
        })
    # which part of the initial cost is height, sway, roll...: each term's per-episode median, across episodes
    out["initial_cost_terms"] = {name: M.episode_summary(_units(per_episode_median(traces.initial_cost_terms[..., i]),
                                                                 replicas))
                                 for i, name in enumerate(STATE_TERMS)}
    if traces.terrain is not None:  # survival per terrain type and per row, Wilson's interval, the episodes as trials
        t = traces.terrain
        out["survival_per_type"] = _survival_by(survived_env, np.asarray(t["type"]), len(t["types"]), replicas,
                                                labels=t["types"])
        out["survival_per_row"] = _survival_by(survived_env, np.asarray(t["row"]), t["rows"], replicas)
    if stairs is not None:
        out["stairs"] = stairs_summary(np.asarray(traces.terrain["row"]), stairs["heights"], stairs["steps"],
                                       survived_env, per_ep["reached_top"], per_ep["climbed_fraction"], replicas)
    out["timing"] = dict(traces.timing)
    return out


def stairs_episodes(traces: ClosedLoopTraces) -> tuple[np.ndarray, np.ndarray]:
    """The stairs scenario's per-robot (climbed fraction, reached the top), as the eval suite computes them
    (``eval.stairs.climbed_fraction``, ``reached_top``): the highest terrain level under the base over the
    robot's first episode, above its platform (``terrain["origin_z"]``), over the flight steps x h of its row.

    Needs ``traces.ground_z`` and ``traces.terrain`` with ``row``, ``origin_z`` and ``stairs`` = {"heights": one
    step height per terrain row, "steps": steps per flight} (``closed_loop.episodes.run_controllers``)."""
    from dls_quadruped.eval.stairs import climbed_fraction, reached_top

    t = traces.terrain
    if traces.ground_z is None or t is None or "stairs" not in t:
        raise ValueError("stairs metrics need traces.ground_z and traces.terrain['stairs'] (the stairs scenario)")
    flight = t["stairs"]["steps"] * np.asarray(t["stairs"]["heights"], dtype=float)[np.asarray(t["row"])]
    ground_z = np.asarray(traces.ground_z, dtype=float)
    valid = np.isfinite(ground_z)
    fraction = climbed_fraction(np.where(valid, ground_z, 0.0), valid, np.asarray(t["origin_z"], dtype=float), flight)
    return fraction, reached_top(fraction, flight)


def stairs_summary(row: np.ndarray, heights, steps: int, survived: np.ndarray, top: np.ndarray,
                   fraction: np.ndarray, replicas: int) -> dict:
    """Per step height (terrain row): survival and success (reached the top) over its robots with Wilson's
    interval, the episodes as the trials; the climbed fraction's mean over its robots with a two-level bootstrap
    interval (episodes and sampler seeds, ``eval.metrics.bootstrap_ci``). Robot s E + e plays episode e
    (``replicas`` S)."""
    heights = [float(h) for h in heights]
    per_height = []
    episode_row = np.asarray(row).reshape(replicas, -1)[0]
    frac = _units(fraction, replicas)
    for g, (sv, tp) in enumerate(zip(_survival_by(survived, row, len(heights), replicas),
                                     _survival_by(np.asarray(top, dtype=float), row, len(heights), replicas))):
        per_height.append({"step_height": heights[g], "episodes": sv["episodes"], "robots": sv["robots"],
                           "survival": {k: sv[k] for k in ("rate", "ci95_episodes")},
                           "success": {k: tp[k] for k in ("rate", "ci95_episodes")},
                           "climbed_fraction": _mean_bootstrap(frac[:, episode_row == g])})
    return {"heights": heights, "steps_per_flight": int(steps), "episode_row": episode_row.tolist(),
            "per_height": per_height}


def _mean_bootstrap(units: np.ndarray) -> dict:
    """{mean, ci95, episodes} of (S, E) per-robot values (NaN: no value)."""
    units = np.asarray(units, dtype=float)
    if not np.isfinite(units).any():
        return {"mean": float("nan"), "ci95": [float("nan")] * 2, "episodes": int(units.shape[1])}
    return {"mean": float(np.nanmean(units)), "ci95": M.bootstrap_ci(units, np.nanmean),
            "episodes": int(units.shape[1])}


def _survival_by(survived: np.ndarray, group: np.ndarray, count: int, replicas: int,
                 labels: list[str] | None = None) -> list[dict]:
    """Survival of the robots of each group value 0 .. count-1: rate over its robots, Wilson's interval
    with its episodes (robots / replicas) as the trials."""
    out = []
    for g in range(count):
        sel = group == g
        n = int(sel.sum())
        rate = float(survived[sel].mean()) if n else float("nan")
        episodes = n / replicas
        lo, hi = M.wilson_interval(rate * episodes, episodes) if n else (float("nan"), float("nan"))
        out.append({"group": labels[g] if labels else g, "rate": rate, "robots": n, "episodes": episodes,
                    "ci95_episodes": [lo, hi]})
    return out


def compare(a: dict, b: dict, metrics: tuple[str, ...] = ("rl_reward", "initial_cost", "rollout_cost", "vel_error",
                                                          "survived", "reached_top", "climbed_fraction")) -> dict:
    """Paired differences a - b of two summaries of the same episodes (``per_episode`` values): per metric
    {mean, ci95, relative, relative_ci95, episodes}; metrics missing from either side are left out."""
    pa, pb = a["per_episode"], b["per_episode"]
    if len(pa["rl_reward"][0]) != len(pb["rl_reward"][0]):
        raise ValueError(f"{a['controller']} and {b['controller']} were not run on the same episodes "
                         f"({len(pa['rl_reward'][0])} vs {len(pb['rl_reward'][0])})")
    return {k: M.paired_difference(np.array(pa[k]), np.array(pb[k])) for k in metrics if k in pa and k in pb}

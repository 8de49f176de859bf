"""``omni``: success over a grid of velocity directions x magnitudes and the 90 %-success isoline
(thesis Fig. 21).

Every episode is commanded (m cos(theta), m sin(theta), 0) in the base frame for its whole 15 s,
theta from ``DIRECTIONS`` (0 = forward, 90 deg = left) and m from ``MAGNITUDES`` (``--episodes``
per cell), on the evaluation env of ``simple`` (flat, no noise, no perturbation). An episode
*succeeds* when it survives and its mean planar velocity after a 2 s settle is within
max(``TOLERANCE`` x m, ``TOLERANCE_ABS``) of the command (|mean v_xy - cmd_xy| <= max(0.25 m, 0.1 m/s)). Per cell:
success and survival rates (Wilson 95 %). Per direction: the isoline, the edge of the region where the rate is at
least 90 % (``metrics.threshold_crossing(outermost=True)``: after the largest magnitude at or above
90 %, linear interpolation to the next grid magnitude; the grid end when the last one is at or
above; a failure at a low magnitude, e.g. drift above the 0.1 m/s floor, shows in the cells, not
in the isoline), with a 95 % interval (``metrics.crossing_interval``), for success and for survival.
Thesis: base goes "50 % faster in all directions" than its 1 m/s training range; rough, speed and
climb match their training command distributions.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dls_quadruped.eval import metrics as M
from dls_quadruped.eval import sweep as S
from dls_quadruped.eval.rollout import Recording
from dls_quadruped.eval.scenario import EvalOptions, Scenario
from dls_quadruped.eval.velocity_tracking import SETTLE_S, flat_task

DIRECTIONS_DEG = tuple(range(0, 360, 45))
"""[deg] command directions in the base frame (0 forward, 90 left)."""
MAGNITUDES = tuple(round(0.25 * k, 2) for k in range(1, 9))
"""[m/s] command magnitudes 0.25 ... 2.0."""
TOLERANCE = 0.25
"""Success: |mean v_xy - cmd_xy| <= max(TOLERANCE x |cmd_xy|, TOLERANCE_ABS)."""
TOLERANCE_ABS = 0.1
"""[m/s] floor of the tolerance (a 25 % band is tighter than the drift of a good walk at 0.25 m/s)."""
LEVEL = 0.9
"""Rate whose isoline is reported (thesis: 90 %)."""


def grid_commands(directions_deg: tuple[float, ...], magnitudes: tuple[float, ...]) -> np.ndarray:
    """(D M, 3) commands, direction-major: row d M + m is (mag_m cos(theta_d), mag_m sin(theta_d), 0)."""
    th = np.deg2rad(np.asarray(directions_deg, dtype=float))[:, None]
    mag = np.asarray(magnitudes, dtype=float)[None, :]
    return np.stack([mag * np.cos(th), mag * np.sin(th), np.zeros_like(mag * th)], axis=-1).reshape(-1, 3)


def success_flags(rec: Recording, settle_s: float = SETTLE_S, tolerance: float = TOLERANCE,
                  tolerance_abs: float = TOLERANCE_ABS) -> np.ndarray:
    """(E,) survived and |mean v_xy after the settle - cmd_xy| <= max(tolerance |cmd_xy|, tolerance_abs)."""
    mean_v = M.masked_mean(rec.probes["velocity"][..., :2], S.settled(rec, settle_s))  # (E, 2)
    err = np.linalg.norm(mean_v - rec.command[:, :2], axis=-1)
    with np.errstate(invalid="ignore"):
        bound = np.maximum(tolerance * np.linalg.norm(rec.command[:, :2], axis=-1), tolerance_abs)
        return ~rec.fell.astype(bool) & (err <= bound)


def summarize(rec: Recording, group: np.ndarray, directions_deg: tuple[float, ...], magnitudes: tuple[float, ...],
              settle_s: float = SETTLE_S) -> dict:
    """Per-cell rates and per-direction isolines (module docstring)."""
    D, K = len(directions_deg), len(magnitudes)
    ok = success_flags(rec, settle_s)
    mean_v = M.masked_mean(rec.probes["velocity"], S.settled(rec, settle_s))
    success = M.grouped_rate(ok, group, D * K)
    survival = S.survival_of(rec, group, D * K)
    isolines = []
    for d, theta in enumerate(directions_deg):
        entry = {"direction_deg": theta}
        for name, cells in (("success", success), ("survival", survival)):
            row = cells[d * K:(d + 1) * K]
            k = np.array([c["k"] for c in row])
            n = np.array([c["n"] for c in row])
            rates = np.array([c["rate"] for c in row])
            entry[name] = {"magnitude": M.threshold_crossing(magnitudes, rates, LEVEL, outermost=True),
                           "ci95": M.crossing_interval(magnitudes, k, n, LEVEL, seed=d, outermost=True),
                           "beyond_grid": bool(rates[-1] >= LEVEL), "below_grid": bool(not (rates >= LEVEL).any())}
        isolines.append(entry)
    return {"settle_s": settle_s, "tolerance": TOLERANCE, "tolerance_abs": TOLERANCE_ABS, "level": LEVEL,
            "directions_deg": list(directions_deg),
            "magnitudes": list(magnitudes),
            "cells": [{"direction_deg": directions_deg[g // K], "magnitude": magnitudes[g % K], "success": success[g],
                       "survival": survival[g]} for g in range(D * K)],
            "isolines": isolines,
            "isoline_success_mean": M.mean_ci(np.array([i["success"]["magnitude"] for i in isolines])),
            "isoline_survival_mean": M.mean_ci(np.array([i["survival"]["magnitude"] for i in isolines])),
            "per_episode": {"command": rec.command.round(4).tolist(), "mean_velocity": np.round(mean_v, 4).tolist(),
                            "success": ok.tolist(), "fell": rec.fell.astype(bool).tolist()}}


def evaluate(policy_path: Path, opts: EvalOptions) -> dict:
    cmd, group = S.repeat_conditions(grid_commands(DIRECTIONS_DEG, MAGNITUDES), opts.episodes)
    rec, _ = S.run(flat_task(cmd, opts), policy_path, opts, len(cmd), ["velocity"])
    return {**S.header(NAME, DESCRIPTION, policy_path, opts, rec, opts.episodes, len(DIRECTIONS_DEG) * len(MAGNITUDES)),
            **summarize(rec, group, DIRECTIONS_DEG, MAGNITUDES)}


def plot(res: dict, path: Path) -> None:
    plt = S.pyplot()
    D, K = len(res["directions_deg"]), len(res["magnitudes"])
    rate = np.array([c["success"]["rate"] for c in res["cells"]]).reshape(D, K)
    fig = plt.figure(figsize=(11, 4.5))
    ax0 = fig.add_subplot(1, 2, 1)
    im = ax0.imshow(100 * rate, origin="lower", aspect="auto", vmin=0, vmax=100, cmap="viridis")
    ax0.set_xticks(range(K), [f"{m:g}" for m in res["magnitudes"]], fontsize=7)
    ax0.set_yticks(range(D), [f"{d:g}" for d in res["directions_deg"]], fontsize=7)
    ax0.set_xlabel("command magnitude [m/s]")
    ax0.set_ylabel("command direction [deg] (0 forward, 90 left)")
    fig.colorbar(im, ax=ax0, label=f"success [%] (n = {res['episodes_per_condition']} per cell)")
    ax1 = fig.add_subplot(1, 2, 2, projection="polar")
    th = np.deg2rad(np.array(res["directions_deg"] + res["directions_deg"][:1], dtype=float))
    for name, style in (("success", "-o"), ("survival", "--s")):
        m = np.array([i[name]["magnitude"] for i in res["isolines"]], dtype=float)
        lo = np.array([i[name]["ci95"][0] for i in res["isolines"]], dtype=float)
        hi = np.array([i[name]["ci95"][1] for i in res["isolines"]], dtype=float)
        line, = ax1.plot(th, np.r_[m, m[:1]], style, label=f"{100 * res['level']:.0f} % {name}")
        ax1.fill_between(th, np.r_[lo, lo[:1]], np.r_[hi, hi[:1]], color=line.get_color(), alpha=0.15)
    ax1.plot(np.linspace(0, 2 * np.pi, 100), np.ones(100), color="0.6", lw=1, label="1 m/s (base training)")
    ax1.set_rmax(max(res["magnitudes"]))
    ax1.legend(fontsize=7, loc="lower left", bbox_to_anchor=(0.8, -0.1))
    fig.suptitle(f"omni: {Path(res['policy']).name}, isolines of {100 * res['level']:.0f} % (95 % band); "
                 f"success = survived and |v - cmd| <= max({res['tolerance']:g} |cmd|, {res['tolerance_abs']:g} m/s)",
                 fontsize=9)
    S.savefig(fig, path)


def summary(res: dict) -> str:
    lines = [f"[eval] omni: {res['policy']}, {res['episodes_per_condition']} episodes x {res['conditions']} cells"]
    for i in res["isolines"]:
        s, v = i["success"], i["survival"]
        lines.append(f"  {i['direction_deg']:5.0f} deg: {100 * res['level']:.0f} % success up to {s['magnitude']:.2f} "
                     f"[{s['ci95'][0]:.2f}, {s['ci95'][1]:.2f}] m/s{' (grid end)' if s['beyond_grid'] else ''}"
                     f"{' (below 90 % everywhere)' if s['below_grid'] else ''}, "
                     f"survival up to {v['magnitude']:.2f} [{v['ci95'][0]:.2f}, {v['ci95'][1]:.2f}] m/s")
    return "\n".join(lines)


NAME = "omni"
DESCRIPTION = ("success over 8 directions x magnitudes 0.25-2 m/s, flat; 90 %-success isoline per direction "
               "(Fig. 21)")
SCENARIO = Scenario(NAME, DESCRIPTION, evaluate, plot, default_episodes=3, summary=summary)

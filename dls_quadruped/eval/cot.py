"""``cot``: cost of transport vs commanded forward speed on flat ground (thesis Fig. 22, eq. 4.3.7).

The runs are ``speed``'s (``speed.forward_sweep``: (v, 0, 0) per episode, flat, no disturbance).
An episode's CoT is its energy over m g times the distance its base travelled, after a 2 s
settle and before it ended::

    CoT_e = sum_t P_t / (m g sum_t |v_xy,t|),   P_t = sum_j max(tau_j qdot_j + alpha tau_j^2, 0)

(the power numerator of eq. 4.3.7 / ``kernels.cost_of_transport``, alpha = 0.3 W/(N m)^2, read at
the policy rate; m g the robot's weight). Per speed: mean CoT over episodes with its 95 %
interval, the mean mechanical-plus-Joule power [W] and the achieved speed; survival per speed
as in ``speed``. The thesis (l.1213): CoT "from 2 at 0.5 m/s down to slightly less than 1 at
2.5 m/s", like Yang et al. 2021's A1.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dls_quadruped.eval import metrics as M
from dls_quadruped.eval import sweep as S
from dls_quadruped.eval.rollout import Recording
from dls_quadruped.eval.scenario import EvalOptions, Scenario
from dls_quadruped.eval.speed import SPEEDS, forward_sweep
from dls_quadruped.eval.velocity_tracking import SETTLE_S

THESIS_COT = {0.5: 2.0, 2.5: 1.0}
"""Thesis 7.1 (Fig. 22 text): CoT about 2 at 0.5 m/s, slightly below 1 at 2.5 m/s."""


def episode_cot(power: np.ndarray, speed_h: np.ndarray, ok: np.ndarray, weight: float) -> np.ndarray:
    """(E,) CoT of each episode over its ``ok`` steps: sum P / (m g sum |v_xy|); NaN without a step.

    Args:
        power: (T, E) [W]; speed_h: (T, E) [m/s]; ok: (T, E) bool; weight: m g [N].
    """
    energy = np.where(ok, power, 0.0).sum(axis=0)                  # [W step] = [J] / dt
    distance = np.where(ok, speed_h, 0.0).sum(axis=0)              # [m/s step] = [m] / dt
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(ok.any(axis=0) & (distance > 0), energy / (weight * distance), np.nan)


def summarize(rec: Recording, group: np.ndarray, speeds: tuple[float, ...], weight: float,
              settle_s: float = SETTLE_S) -> dict:
    """Per-speed CoT, power and achieved speed (module docstring)."""
    n = len(speeds)
    ok = S.settled(rec, settle_s)
    cot = episode_cot(rec.probes["power"], rec.probes["speed_h"], ok, weight)
    power = M.masked_mean(rec.probes["power"], ok)
    v_h = M.masked_mean(rec.probes["speed_h"], ok)
    rows = []
    for v, surv, c, p, a in zip(speeds, S.survival_of(rec, group, n), M.grouped_mean(cot, group, n),
                                M.grouped_mean(power, group, n), M.grouped_mean(v_h, group, n)):
        rows.append({"command_v_x": v, "cot": c, "power_w": p, "achieved_speed_h": a, "survival": surv})
    return {"settle_s": settle_s, "speeds": list(speeds), "robot_weight_n": weight, "power_alpha": S.POWER_ALPHA,
            "per_speed": rows, "thesis": {str(k): v for k, v in THESIS_COT.items()},
            "per_episode": {"command_v_x": rec.command[:, 0].round(4).tolist(), "cot": np.round(cot, 4).tolist(),
                            "fell": rec.fell.astype(bool).tolist()}}


def evaluate(policy_path: Path, opts: EvalOptions) -> dict:
    rec, group, facts = forward_sweep(policy_path, opts, SPEEDS, ["power", "speed_h"])
    return {**S.header(NAME, DESCRIPTION, policy_path, opts, rec, opts.episodes, len(SPEEDS)),
            **summarize(rec, group, SPEEDS, facts["robot_weight_n"])}


def plot(res: dict, path: Path) -> None:
    plt = S.pyplot()
    rows = res["per_speed"]
    v = np.array([r["achieved_speed_h"]["mean"] for r in rows], dtype=float)
    c = np.array([r["cot"]["mean"] for r in rows], dtype=float)
    lo = np.array([r["cot"]["ci95"][0] for r in rows], dtype=float)
    hi = np.array([r["cot"]["ci95"][1] for r in rows], dtype=float)
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.errorbar(v, c, yerr=S.yerr(c, lo, hi), marker="o", capsize=3,
                label="ours: mean over episodes (95 % CI)")
    for cmd, r in zip(res["speeds"], rows):
        if np.isfinite(r["achieved_speed_h"]["mean"] or np.nan):
            ax.annotate(f"{cmd:g}", (r["achieved_speed_h"]["mean"], r["cot"]["mean"]), fontsize=6,
                        textcoords="offset points", xytext=(3, 3))
    ax.plot(list(THESIS_COT), list(THESIS_COT.values()), "s--", color="0.5", label="thesis text (2 -> <1)")
    ax.set_xlabel("achieved speed |v_xy| [m/s] (labels: commanded v_x)")
    ax.set_ylabel("cost of transport (eq. 4.3.7)")
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(f"CoT: {Path(res['policy']).name}, {res['episodes_per_condition']} episodes per speed", fontsize=10)
    S.savefig(fig, path)


def summary(res: dict) -> str:
    lines = [f"[eval] cot: {res['policy']}, {res['episodes_per_condition']} episodes x {res['conditions']} speeds"]
    for r in res["per_speed"]:
        c, a = r["cot"], r["achieved_speed_h"]
        lines.append(f"  v_cmd {r['command_v_x']:.2f}: CoT {c['mean']:.3f} [{c['ci95'][0]:.3f}, {c['ci95'][1]:.3f}] "
                     f"(n = {c['n']}) at {a['mean']:.3f} m/s, power {r['power_w']['mean']:.0f} W, "
                     f"survival {S.pct(r['survival'])}")
    return "\n".join(lines)


NAME = "cot"
DESCRIPTION = "cost of transport (eq. 4.3.7) vs commanded forward speed 0.25-2.5 m/s, flat (Fig. 22)"
SCENARIO = Scenario(NAME, DESCRIPTION, evaluate, plot, default_episodes=8, summary=summary)

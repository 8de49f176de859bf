"""``speed``: survival and achieved speed vs commanded forward speed on flat ground (thesis Fig. 20).

Every episode is commanded (v, 0, 0) for its whole 15 s, v from ``SPEEDS`` (``--episodes`` per
speed), on the evaluation env of ``simple`` (``velocity_tracking.flat_task``: flat, no noise, no
perturbation, Table-4 reward). Reported per speed: survival (Wilson 95 %), the achieved forward
speed (per-episode mean base-frame v_x after a 2 s settle; mean over episodes with its 95 %
interval; a fallen episode counts with what it ran after the settle) and its ratio to the
command; over speeds: the speed at which survival first drops below 90 % (linear interpolation
between grid speeds, 95 % interval from ``metrics.crossing_interval``) and the highest mean achieved speed.
``forward_sweep`` is shared with ``cot`` and ``gait``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dls_quadruped.eval import metrics as M
from dls_quadruped.eval import sweep as S
from dls_quadruped.eval.rollout import Recording
from dls_quadruped.eval.scenario import EvalOptions, Scenario
from dls_quadruped.eval.velocity_tracking import SETTLE_S, flat_task

SPEEDS = tuple(round(0.25 * k, 2) for k in range(1, 11))
"""[m/s] commanded forward speeds: 0.25 ... 2.5 (base trained to 1 m/s, speed to 2.1 m/s)."""
SURVIVAL_LEVEL = 0.9
"""Survival level whose crossing is reported."""


def forward_commands(speeds: tuple[float, ...], per: int) -> tuple[np.ndarray, np.ndarray]:
    """((len(speeds) per, 3) commands (v, 0, 0), (len(speeds) per,) speed index)."""
    return S.repeat_conditions(np.array([[v, 0.0, 0.0] for v in speeds]), per)


def forward_sweep(policy_path: Path, opts: EvalOptions, speeds: tuple[float, ...],
                  probes: list[str]) -> tuple[Recording, np.ndarray, dict]:
    """Run ``opts.episodes`` episodes per forward speed on flat ground; (recording, speed index, env facts)."""
    cmd, group = forward_commands(speeds, opts.episodes)
    rec, facts = S.run(flat_task(cmd, opts), policy_path, opts, len(cmd), probes)
    return rec, group, facts


def summarize(rec: Recording, group: np.ndarray, speeds: tuple[float, ...], settle_s: float = SETTLE_S) -> dict:
    """Per-speed survival and achieved speed (module docstring)."""
    n = len(speeds)
    ok = S.settled(rec, settle_s)
    v_x = M.masked_mean(rec.probes["velocity"][..., 0], ok)                # (E,) achieved forward speed
    survival = S.survival_of(rec, group, n)
    achieved = M.grouped_mean(v_x, group, n)
    ratio = M.grouped_mean(v_x / rec.command[:, 0], group, n)
    k = np.array([s["k"] for s in survival])
    counts = np.array([s["n"] for s in survival])
    rates = np.array([s["rate"] for s in survival])
    means = np.array([a["mean"] for a in achieved])
    best = int(np.nanargmax(means)) if np.isfinite(means).any() else 0
    return {
        "settle_s": settle_s,
        "speeds": list(speeds),
        "per_speed": [{"command_v_x": v, "survival": s, "achieved_v_x": a, "achieved_over_commanded": r}
                      for v, s, a, r in zip(speeds, survival, achieved, ratio)],
        "survival_crossing": {"level": SURVIVAL_LEVEL, "speed": M.threshold_crossing(speeds, rates, SURVIVAL_LEVEL),
                              "ci95": M.crossing_interval(speeds, k, counts, SURVIVAL_LEVEL),
                              "note": "commanded speed where survival first drops below the level (grid end "
                                      "if never)"},
        "max_achieved_v_x": {"command_v_x": speeds[best], **achieved[best]},
        "per_episode": {"command_v_x": rec.command[:, 0].round(4).tolist(), "achieved_v_x": np.round(v_x, 4).tolist(),
                        "fell": rec.fell.astype(bool).tolist(),
                        "length_s": (rec.length * rec.step_dt).round(3).tolist()},
    }


def evaluate(policy_path: Path, opts: EvalOptions) -> dict:
    rec, group, _ = forward_sweep(policy_path, opts, SPEEDS, ["velocity"])
    return {**S.header(NAME, DESCRIPTION, policy_path, opts, rec, opts.episodes, len(SPEEDS)),
            **summarize(rec, group, SPEEDS)}


def plot(res: dict, path: Path) -> None:
    plt = S.pyplot()
    v = np.array(res["speeds"])
    surv = res["per_speed"]
    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(11, 4))
    rate = np.array([100 * s["survival"]["rate"] for s in surv])
    lo = np.array([100 * s["survival"]["ci95"][0] for s in surv])
    hi = np.array([100 * s["survival"]["ci95"][1] for s in surv])
    ax0.errorbar(v, rate, yerr=S.yerr(rate, lo, hi), marker="o", capsize=3)
    ax0.axhline(100 * SURVIVAL_LEVEL, color="0.6", ls="--", lw=1)
    ax0.set_xlabel("commanded v_x [m/s]")
    ax0.set_ylabel("survival [%] (95 % Wilson)")
    ax0.set_ylim(-5, 105)
    ach = np.array([s["achieved_v_x"]["mean"] for s in surv], dtype=float)
    alo = np.array([s["achieved_v_x"]["ci95"][0] for s in surv], dtype=float)
    ahi = np.array([s["achieved_v_x"]["ci95"][1] for s in surv], dtype=float)
    ax1.plot([0, v.max()], [0, v.max()], color="0.6", lw=1, label="achieved = commanded")
    ax1.errorbar(v, ach, yerr=S.yerr(ach, alo, ahi), marker="o", capsize=3,
                 label="mean over episodes (95 % CI)")
    ax1.set_xlabel("commanded v_x [m/s]")
    ax1.set_ylabel(f"achieved v_x [m/s] (mean after {res['settle_s']:g} s)")
    ax1.legend(fontsize=8)
    for ax in (ax0, ax1):
        ax.grid(alpha=0.3)
    fig.suptitle(f"speed sweep: {Path(res['policy']).name}, {res['episodes_per_condition']} episodes per speed",
                 fontsize=10)
    S.savefig(fig, path)


def summary(res: dict) -> str:
    lines = [f"[eval] speed: {res['policy']}, {res['episodes_per_condition']} episodes x {res['conditions']} speeds"]
    for s in res["per_speed"]:
        a = s["achieved_v_x"]
        lines.append(f"  v_cmd {s['command_v_x']:.2f}: survival {S.pct(s['survival'])}, achieved {a['mean']:.3f} "
                     f"[{a['ci95'][0]:.3f}, {a['ci95'][1]:.3f}] m/s")
    c = res["survival_crossing"]
    lines.append(f"  survival < {100 * c['level']:.0f} % from {c['speed']:.2f} m/s [{c['ci95'][0]:.2f}, "
                 f"{c['ci95'][1]:.2f}]")
    return "\n".join(lines)


NAME = "speed"
DESCRIPTION = "forward-speed sweep 0.25-2.5 m/s on flat ground: survival and achieved speed per speed (Fig. 20)"
SCENARIO = Scenario(NAME, DESCRIPTION, evaluate, plot, default_episodes=16, summary=summary)

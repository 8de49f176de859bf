"""``gait``: contact (Hildebrand) diagrams and step frequency vs forward speed (thesis Fig. 23).

The runs are ``speed``'s (``speed.forward_sweep``: (v, 0, 0) per episode, flat, no disturbance),
recording the foot contacts (vertical ground force > 1 N, legs FL, FR, RL, RR) and the applied
latent gait (f [Hz], d) at 50 Hz. Per speed, over the steps after a 2 s settle and before the
episode ended, each a mean over episodes with its 95 % interval:

* ``f_policy``: the latent action's step frequency f [Hz], mean over legs and steps;
* ``f_contacts``: touch-downs (contact after at least ``MIN_AIR_S`` without) per leg per second,
  mean over legs: the step frequency the feet actually show; ``contact_rising_edges_per_s``
  counts every rising edge (a bouncing foot several times);
* ``duty_policy`` (d of the action) and ``duty_contacts`` (fraction of the time in contact);
* ``sync``: for the leg pairs ``diagonal`` (FL-RR, FR-RL), ``lateral`` (FL-RL, FR-RR), ``front``
  (FL-FR) and ``rear`` (RL-RR), the fraction of steps on which both legs share their contact
  state. A trot has diagonal ~1, lateral and front/rear well below; a gallop-like rear pair
  (thesis: speed policy above 1.1 m/s) shows as rear sync rising while diagonal sync falls.

The plot: one Hildebrand diagram (contact bars per leg over ``WINDOW_S``) of one episode per
speed (the first that survived the window), and f and sync vs speed. The JSON keeps those
windows (``diagrams``: one '0'/'1' string per leg).
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

LEGS = ("FL", "FR", "RL", "RR")
PAIRS = {"diagonal": ((0, 3), (1, 2)), "lateral": ((0, 2), (1, 3)), "front": ((0, 1),), "rear": ((2, 3),)}
"""Leg pairs (indices into ``LEGS``) whose contact agreement is reported."""
MIN_AIR_S = 0.06
"""[s] a touch-down counts after at least this long without contact (3 policy steps; a swing at
f <= 3 Hz and d <= 0.8 lasts >= 67 ms), so a bouncing foot is one touch-down."""
WINDOW_S = 2.0
"""[s] length of each Hildebrand diagram, starting at the settle."""


def touchdown_rate(contact: np.ndarray, ok: np.ndarray, step_dt: float, min_air_steps: int = 1) -> np.ndarray:
    """(E, 4) touch-downs per second of each leg: steps in contact after ``min_air_steps``
    consecutive steps without, all of them ``ok`` (1: every rising edge, a bounce included).

    Args:
        contact: (T, E, 4) 0/1; ok: (T, E) bool; step_dt: [s]; min_air_steps: >= 1.
    """
    c = contact > 0.5
    k = int(min_air_steps)
    T = c.shape[0]
    span = np.ones(ok[k:].shape, bool)                            # (T-k, E) steps t-k..t all valid
    air = np.ones(c[k:].shape, bool)                              # (T-k, E, 4) feet off at t-k..t-1
    for j in range(1, k + 1):
        span &= ok[k - j:T - j]
        air &= ~c[k - j:T - j]
    span &= ok[k:]
    touch = c[k:] & air & span[..., None]
    seconds = span.sum(axis=0) * step_dt                          # (E,)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(seconds[:, None] > 0, touch.sum(axis=0) / seconds[:, None], np.nan)


def pair_sync(contact: np.ndarray, ok: np.ndarray) -> dict[str, np.ndarray]:
    """{pair name: (E,) fraction of ``ok`` steps on which the pair's legs share their contact state}."""
    c = contact > 0.5
    out = {}
    for name, pairs in PAIRS.items():
        same = np.mean([c[..., a] == c[..., b] for a, b in pairs], axis=0)  # (T, E)
        out[name] = M.masked_mean(same, ok)
    return out


def diagrams(rec: Recording, group: np.ndarray, speeds: tuple[float, ...], settle_s: float) -> list[dict]:
    """Per speed, the contact pattern of the first episode still running at the end of the window."""
    k0 = round(settle_s / rec.step_dt)
    k1 = k0 + round(WINDOW_S / rec.step_dt)
    out = []
    for g, v in enumerate(speeds):
        ids = np.nonzero(group == g)[0]
        full = [i for i in ids if k1 <= rec.valid.shape[0] and rec.valid[k0:k1, i].all()]
        if not full:
            out.append({"command_v_x": v, "episode": None, "contact": None})
            continue
        i = int(full[0])
        window = rec.probes["contact"][k0:k1, i] > 0.5          # (W, 4)
        out.append({"command_v_x": v, "episode": i, "start_s": k0 * rec.step_dt,
                    "contact": {leg: "".join("1" if x else "0" for x in window[:, j]) for j, leg in enumerate(LEGS)}})
    return out


def summarize(rec: Recording, group: np.ndarray, speeds: tuple[float, ...], settle_s: float = SETTLE_S) -> dict:
    """Per-speed gait figures (module docstring)."""
    n = len(speeds)
    ok = S.settled(rec, settle_s)
    contact = rec.probes["contact"]
    per = {
        "f_policy": M.masked_mean(rec.probes["freq"].mean(axis=-1), ok),
        "f_contacts": touchdown_rate(contact, ok, rec.step_dt, round(MIN_AIR_S / rec.step_dt)).mean(axis=-1),
        "contact_rising_edges_per_s": touchdown_rate(contact, ok, rec.step_dt).mean(axis=-1),
        "duty_policy": M.masked_mean(rec.probes["duty"].mean(axis=-1), ok),
        "duty_contacts": M.masked_mean(contact.mean(axis=-1), ok),
    }
    sync = pair_sync(contact, ok)
    rows = []
    survival = S.survival_of(rec, group, n)
    for g, v in enumerate(speeds):
        row = {"command_v_x": v, "survival": survival[g]}
        row.update({k: M.mean_ci(x[group == g]) for k, x in per.items()})
        row["sync"] = {k: M.mean_ci(x[group == g]) for k, x in sync.items()}
        rows.append(row)
    return {"settle_s": settle_s, "speeds": list(speeds), "legs": list(LEGS),
            "pairs": {k: [[LEGS[a], LEGS[b]] for a, b in v] for k, v in PAIRS.items()},
            "per_speed": rows, "diagrams": diagrams(rec, group, speeds, settle_s)}


def evaluate(policy_path: Path, opts: EvalOptions) -> dict:
    rec, group, _ = forward_sweep(policy_path, opts, SPEEDS, ["contact", "freq", "duty"])
    return {**S.header(NAME, DESCRIPTION, policy_path, opts, rec, opts.episodes, len(SPEEDS)),
            **summarize(rec, group, SPEEDS)}


def _band(ax, rows, key, sub=None, **kw):
    x = np.array([r["command_v_x"] for r in rows])
    get = (lambda r: r[key]) if sub is None else (lambda r: r[key][sub])
    m = np.array([get(r)["mean"] for r in rows], dtype=float)
    lo = np.array([get(r)["ci95"][0] for r in rows], dtype=float)
    hi = np.array([get(r)["ci95"][1] for r in rows], dtype=float)
    ax.errorbar(x, m, yerr=S.yerr(m, lo, hi), marker="o", capsize=2, **kw)


def plot(res: dict, path: Path) -> None:
    plt = S.pyplot()
    shown = [d for d in res["diagrams"] if d["contact"] is not None]
    nrows = max(len(shown), 2)
    half = nrows // 2
    fig = plt.figure(figsize=(12, 2.0 + 0.55 * nrows))
    grid = fig.add_gridspec(nrows, 2, width_ratios=[1.6, 1])
    for row, d in enumerate(shown):
        ax = fig.add_subplot(grid[row, 0])
        for j, leg in enumerate(LEGS):
            on = np.array([c == "1" for c in d["contact"][leg]])
            t = np.arange(len(on)) * WINDOW_S / len(on)
            ax.fill_between(t, j - 0.4, j + 0.4, where=on, step="post", color="k", lw=0)
        ax.set_yticks(range(4), LEGS, fontsize=6)
        ax.set_ylim(3.6, -0.6)
        ax.set_ylabel(f"{d['command_v_x']:g} m/s", fontsize=7)
        ax.tick_params(axis="x", labelsize=6, labelbottom=row == len(shown) - 1)
    if shown:
        ax.set_xlabel(f"time after the {res['settle_s']:g} s settle [s] (black: foot in contact)", fontsize=8)
    ax_f = fig.add_subplot(grid[:half, 1])
    rows = res["per_speed"]
    _band(ax_f, rows, "f_policy", label="f of the action")
    _band(ax_f, rows, "f_contacts", label="touch-downs per leg per s")
    ax_f.set_ylabel("step frequency [Hz]")
    ax_f.legend(fontsize=7)
    ax_f.grid(alpha=0.3)
    ax_s = fig.add_subplot(grid[half:, 1])
    for name in PAIRS:
        _band(ax_s, rows, "sync", name, label=name)
    ax_s.set_xlabel("commanded v_x [m/s]")
    ax_s.set_ylabel("pair contact agreement")
    ax_s.set_ylim(0, 1.05)
    ax_s.legend(fontsize=7, ncol=2)
    ax_s.grid(alpha=0.3)
    fig.suptitle(f"gait: {Path(res['policy']).name}, {res['episodes_per_condition']} episodes per speed", fontsize=10)
    S.savefig(fig, path)


def summary(res: dict) -> str:
    lines = [f"[eval] gait: {res['policy']}, {res['episodes_per_condition']} episodes x {res['conditions']} speeds"]
    for r in res["per_speed"]:
        s = r["sync"]
        lines.append(f"  v_cmd {r['command_v_x']:.2f}: f {r['f_policy']['mean']:.2f} Hz (action), "
                     f"{r['f_contacts']['mean']:.2f} Hz (touch-downs; "
                     f"{r['contact_rising_edges_per_s']['mean']:.2f} rising edges/s), "
                     f"duty {r['duty_contacts']['mean']:.2f}; "
                     f"sync diag {s['diagonal']['mean']:.2f} lat {s['lateral']['mean']:.2f} "
                     f"front {s['front']['mean']:.2f} rear {s['rear']['mean']:.2f}; survival {S.pct(r['survival'])}")
    return "\n".join(lines)


NAME = "gait"
DESCRIPTION = "contact diagrams, step frequency and leg-pair synchrony vs forward speed 0.25-2.5 m/s, flat (Fig. 23)"
SCENARIO = Scenario(NAME, DESCRIPTION, evaluate, plot, default_episodes=8, summary=summary)

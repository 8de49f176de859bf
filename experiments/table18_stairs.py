"""The stairs part of ``table18_multi_policy.py`` (past the thesis): the terrain-blind vs terrain-aware MPC on the
eval suite's stairs, per step height: success, survival, climbed fraction, paired aware - blind differences
(``stairs.md``/``.csv``, ``stairs.png``). The cells themselves are the script's ``stairs_cells``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dls_quadruped.closed_loop.episodes import STAIRS_HEIGHTS
from dls_quadruped.eval import metrics as EM
from experiments.output import pyplot, save

STAIRS_SECONDS = 15.0
"""[s] stairs episodes (the eval suite's): the top of the flight is 2.5 m from the start, 5-8 s at 0.3-0.5 m/s."""


STAIRS_VARIANTS = (("base warm start, blind", "ws_base_stairs_blind"),
                   ("base warm start, aware", "ws_base_stairs_aware"),
                   ("naive, blind", "naive_stairs_blind"), ("naive, aware", "naive_stairs_aware"),
                   ("base alone", "alone_base_stairs"))
STAIRS_PAIRS = {"ws_base_stairs_aware": "ws_base_stairs_blind", "naive_stairs_aware": "naive_stairs_blind"}
"""aware cell -> its blind twin: the paired aware - blind differences."""


def _rate(r: dict, n: str) -> str:
    lo, hi = r["ci95_episodes"]
    return f"{100 * r['rate']:.0f} % [{100 * lo:.0f}, {100 * hi:.0f}] (n={n})"


def _stairs_paired(results: dict, a: str, b: str, key: str, height: int | None) -> str:
    """Paired a - b of per-episode ``key`` on the episodes of one height index (None: all), in points."""
    sa, sb = results.get(a) or {}, results.get(b) or {}
    if "stairs" not in sa or "stairs" not in sb:
        return "-"
    rows = np.asarray(sa["stairs"]["episode_row"])
    sel = np.ones(len(rows), bool) if height is None else rows == height
    d = EM.paired_difference(np.array(sa["per_episode"][key])[:, sel], np.array(sb["per_episode"][key])[:, sel])
    return f"{100 * d['mean']:+.0f} [{100 * d['ci95'][0]:+.0f}, {100 * d['ci95'][1]:+.0f}]"


def _pooled(s: dict, key: str) -> dict:
    """``key`` (reached_top or survived) over every episode of a stairs cell: rate, Wilson with the episodes."""
    v = np.asarray(s["per_episode"][key], dtype=float)
    e = v.shape[1]
    rate = float(np.nanmean(v))
    return {"rate": rate, "ci95_episodes": list(EM.wilson_interval(rate * e, e))}


def stairs_rows(results: dict) -> list[dict]:
    """One row per controller and step height (and all heights): success, survival, climbed fraction,
    and for an aware cell its paired difference from the blind one (points, mean over episodes [95 % CI])."""
    rows = []
    for label, name in STAIRS_VARIANTS:
        s = results.get(name)
        if not s or "skipped" in s:
            rows.append({"Controller": label, "success": f"skipped: {s['skipped']}" if s else "-"})
            continue
        st, reps = s["stairs"], s.get("replicas", 1)
        twin = STAIRS_PAIRS.get(name)
        for g, r in enumerate([*st["per_height"], None]):
            if r is None:
                episodes = len(st["episode_row"])
                top, sv = _pooled(s, "reached_top"), _pooled(s, "survived")
                frac = np.asarray(s["per_episode"]["climbed_fraction"], dtype=float)
                c = {"mean": float(np.nanmean(frac)), "ci95": EM.bootstrap_ci(frac, np.nanmean)}
                height, g = "all", None
            else:
                episodes, top, sv, c = int(r["episodes"]), r["success"], r["survival"], r["climbed_fraction"]
                height = f"{100 * r['step_height']:g}"
            n = f"{episodes}x{reps}" if reps > 1 else f"{episodes}"
            row = {"Controller": label, "step height [cm]": height, "success": _rate(top, n),
                   "survival": _rate(sv, n),
                   "climbed": f"{100 * c['mean']:.0f} % [{100 * c['ci95'][0]:.0f}, {100 * c['ci95'][1]:.0f}]"}
            if twin:
                row["Δ success aware - blind"] = _stairs_paired(results, name, twin, "reached_top", g)
                row["Δ climbed aware - blind"] = _stairs_paired(results, name, twin, "climbed_fraction", g)
                row["Δ survival aware - blind"] = _stairs_paired(results, name, twin, "survived", g)
            rows.append(row)
    return rows


STAIRS_COLUMNS = ["Controller", "step height [cm]", "success", "survival", "climbed", "Δ success aware - blind",
                  "Δ climbed aware - blind", "Δ survival aware - blind"]


def stairs_figure(results: dict, path: Path) -> None:
    """Success and climbed fraction vs step height, every stairs cell."""
    plt = pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(15, 4))
    for i, (label, name) in enumerate(STAIRS_VARIANTS):
        s = results.get(name) or {}
        if "stairs" not in s:
            continue
        per = s["stairs"]["per_height"]
        h = 100 * np.array([r["step_height"] for r in per])
        style = "--" if "blind" in label else "-"
        for ax, key in zip(axes, ("success", "survival", "climbed_fraction")):
            v = np.array([100 * (r[key]["mean"] if key == "climbed_fraction" else r[key]["rate"]) for r in per])
            ci = np.array([r[key]["ci95"] if key == "climbed_fraction" else r[key]["ci95_episodes"] for r in per])
            ax.errorbar(h + 0.3 * (i - 2), v, yerr=[v - 100 * ci[:, 0], 100 * ci[:, 1] - v], fmt="o" + style,
                        capsize=2, color=f"C{i // 2 if 'alone' not in label else 2}", label=label)
    for ax, title in zip(axes, ("reached the top [%]", "survived [%]", "mean climbed fraction of the flight [%]")):
        ax.set_xlabel("step height [cm]")
        ax.set_title(title, fontsize=9)
        ax.set_ylim(-5, 105)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle("stairs (6-step flight, v_x 0.3-0.5 m/s): MPC blind (stance_feet, dashed) vs aware "
                 "(terrain map, solid); 95 % intervals, episodes as trials", fontsize=9)
    save(fig, path)


def write_stairs(args, results: dict) -> None:
    from experiments.output import write_table

    seconds = args.seconds if args.seconds_given else STAIRS_SECONDS
    write_table(stairs_rows(results), STAIRS_COLUMNS, args.out / "stairs",
                f"Stairs, blind vs terrain-aware MPC ({args.scale}: {args.episodes} episodes per step height x "
                f"{seconds:g} s, heights {', '.join(f'{100 * h:g}' for h in STAIRS_HEIGHTS)} cm, "
                f"{args.sampler_seeds} sampler seeds per MPC episode; success and survival: Wilson 95 % with the "
                f"episodes as trials; climbed: mean, two-level bootstrap; Δ: paired, points, mean over episodes "
                f"[95 % CI])")
    stairs_figure(results, args.out / "stairs.png")

"""Table 18 and Figs. 31-34 (thesis 7.4, RQ2): several policies warm-starting one MPC.

Warm starts base, speed, rough (one student each) and base + speed, rough + speed (two students, equal
shares of the M = 10 000 samples, one batched solve), first-spline, H = 10, dt = 0.02 s, forces
only, beside each expert alone (``rl_baseline`` with that expert), every cell on the same scheduled
episodes (paired):

* Table 18 / Fig. 31: the simple task (flat, no disturbance): RL reward per step and per episode (the
  sum of the per-step rewards), initial cost, survival; each warm start's paired difference from the
  same policy alone (a two-policy row: from each of its policies alone).
* Fig. 32: survival on the survival task (``--scenario survival`` of the closed loop: terrain, pushes,
  friction, wrench; the MPC terrain-blind, planning on the ground its feet stand on) per warm start
  vs the policy alone.
* Fig. 33: base, speed, base + speed and base / speed alone at forward 0.1 / 0.5 / 1.5 m/s: survival
  and initial cost.
* Fig. 34: which group won each solve of base + speed at the three speeds (robot 0 over time) and
  the winner switches per second (per episode, then across episodes).
* Past the thesis: base + speed with arbitration (``mpc/arbitration.py``): a
  switching cost s added to every sample outside the last winner's group, and the same with the
  groups compared by a running average of their best cost (smoothing beta), on the simple task, the
  survival task and the three speeds.
* Past the thesis: the terrain-blind MPC (``stance_feet``) vs the terrain-aware one
  (``terrain``: it plans on the terrain map) on the eval suite's stairs (``--scenario stairs`` of the
  closed loop: a 6-step ``stairs_up`` flight per step height 5 / 10 / 15 / 20 cm, v_x ~ U[0.3, 0.5] m/s,
  ``--episodes`` per height, 15 s at every scale unless ``--seconds``: the top is 2.5 m away), with base's warm start
  and the naive one, beside base alone: per height, success (the base reached the top), survival and
  the climbed fraction of the flight, and the paired aware - blind differences. ``--stairs`` runs
  this part alone (``stairs.md``, ``stairs.png``).

Students: ``docs/policies/<expert>_student_first_spline_h10.pt`` (``--policy-dir``); a missing one
skips its cells with a note.

``--seed-students DIR``: Fig. 32's primary contrast only (base's warm start − base alone on the survival task),
base's MPC warm-started once per training seed's student (``<dir>/first-spline_H10_dt0.02_seed<k>/exported/
student.pt2``, k = 0, 1, 2; cells ``ws_base_survival_seed<k>``) and merged into one row (intervals over episodes
and students, ``experiments/warm_start_seeds.py``); writes ``fig32_seeds.md/.csv``. The 100-episode run of
``docs/experiments/primary_cells_plan.md``:

    python -m experiments.table18_multi_policy --scale thesis --seed 1 --sampler-seeds 1 \
        --seed-students docs/policies/seed_students --out docs/experiments/fig32_thesis

    python -m experiments.table18_multi_policy --scale small
    python -m experiments.table18_multi_policy --scale small --stairs   # stairs, blind vs aware
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dls_quadruped.cli import UserError, run_cli
from dls_quadruped.closed_loop.episodes import STAIRS_HEIGHTS
from dls_quadruped.core.json_io import write_json
from experiments.output import pyplot, save
from experiments.rl_common import Policies
from experiments.table18_stairs import STAIRS_SECONDS, write_stairs
from experiments.warm_start_common import REPO, Cell, parse_args, run_cells
from experiments.warm_start_tables import finish, med, paired, survival, write_config

WARM_STARTS = (("base",), ("speed",), ("rough",), ("base", "speed"), ("rough", "speed"))
EXPERTS = ("base", "speed", "rough")
SPEEDS = (0.1, 0.5, 1.5)
SPEED_WARM_STARTS = (("base",), ("speed",), ("base", "speed"))
ARBITRATION = {"s1000": {"switching_cost": 1000.0},
               "s300_b0.9": {"switching_cost": 300.0, "group_cost_smoothing": 0.9}}
"""base + speed with arbitration: tag -> SamplerConfig overrides (s in the cost units of eq. 3.2.1)."""
STAIRS_GROUNDS = (("blind", "stance_feet"), ("aware", "terrain"))
"""(tag, ground the MPC plans on) of the stairs cells."""
THESIS = {  # warm start: (RL reward, Δ %, initial cost, Δ %, survival %, Δ points) -- Table 18 (simple task)
    "base": (526.5, -0.6, 26.7, -57.3, 100, 0), "speed": (445.8, 6.4, 106.7, -69.7, 74, -26),
    "rough": (388.0, -12.3, 203.7, -32.8, 96, -2), "base + speed": (364.1, None, 91.9, None, 84, None),
    "rough + speed": (429.2, None, 94.9, None, 93, None),
}


def _label(ws: tuple[str, ...], tag: str = "") -> str:
    return " + ".join(ws) + (f" ({tag})" if tag else "")


def _ws_cell(ws: tuple[str, ...], policies: Policies, suffix: str = "", tag: str = "", **kw) -> Cell:
    students = tuple(str(policies.student(n)) for n in ws)
    return Cell(f"ws_{'+'.join(ws)}{f'_{tag}' if tag else ''}{suffix}", "rl_warm_start", students=students,
                sampler=dict(ARBITRATION[tag]) if tag else {}, row={"Warm start": _label(ws, tag)}, **kw)


def _alone_cell(name: str, policies: Policies, suffix: str = "", **kw) -> Cell:
    return Cell(f"alone_{name}{suffix}", "rl_baseline", policy=str(policies.expert(name)),
                row={"Warm start": f"{name} alone"}, **kw)


def stairs_cells(policies: Policies) -> list[Cell]:
    """Item 6: base's warm start and the naive one, each blind and aware, and base alone, on the stairs."""
    kw = {"scenario": "stairs", "seconds": STAIRS_SECONDS}
    out = []
    for tag, ground in STAIRS_GROUNDS:
        out.append(_ws_cell(("base",), policies, f"_stairs_{tag}", ground=ground, **kw))
        out.append(Cell(f"naive_stairs_{tag}", "naive_warm_start", ground=ground, row={"Warm start": "naive"}, **kw))
    out.append(_alone_cell("base", policies, "_stairs", **kw))
    return out


def cells(policies: Policies) -> list[Cell]:
    out = [_ws_cell(ws, policies) for ws in WARM_STARTS] + [_alone_cell(n, policies) for n in EXPERTS]
    out += [_ws_cell(ws, policies, "_survival", scenario="survival") for ws in WARM_STARTS]
    out += [_alone_cell(n, policies, "_survival", scenario="survival") for n in EXPERTS]
    for v in SPEEDS:
        out += [_ws_cell(ws, policies, f"_v{v:g}", vx=v) for ws in SPEED_WARM_STARTS]
        out += [_alone_cell(n, policies, f"_v{v:g}", vx=v) for n in ("base", "speed")]
    for tag in ARBITRATION:
        out += [_ws_cell(("base", "speed"), policies, "", tag),
                _ws_cell(("base", "speed"), policies, "_survival", tag, scenario="survival")]
        out += [_ws_cell(("base", "speed"), policies, f"_v{v:g}", tag, vx=v) for v in SPEEDS]
    return out + stairs_cells(policies)


def fig32_seed_cells(policies: Policies, students: Path) -> tuple[list[Cell], dict[str, list[str]]]:
    """``--seed-students``: base alone and base's warm start once per training seed's student, survival task."""
    from experiments.warm_start_seeds import seed_student_cells

    return seed_student_cells([_alone_cell("base", policies, "_survival", scenario="survival"),
                               Cell("ws_base_survival", "rl_warm_start", scenario="survival",
                                    row={"Warm start": "base"})], students)


def fig32_seed_rows(results: dict, seeded: dict[str, list[str]]) -> list[dict]:
    """The merged warm-start row (students pooled) beside base alone, and each student's own row."""
    rows = []
    for name in ("ws_base_survival", *seeded.get("ws_base_survival", [])):
        s = results.get(name)
        merged = name == "ws_base_survival"
        label = (f"base warm ({len(seeded[name])} students)" if merged
                 else f"base warm, student {name.rsplit('_seed', 1)[1]}")
        if not s or "skipped" in s:
            rows.append({"Warm start": label, "survival": "skipped" if s else "-"})
            continue
        rows.append({"Warm start": label, "survival": survival(s),
                     "Δ survival (paired, fraction)": paired(results, name, "alone_base_survival", "survived",
                                                             digits=3),
                     "Δ return (paired)": paired(results, name, "alone_base_survival", "rl_return")})
    s = results.get("alone_base_survival")
    if s and "skipped" not in s:
        rows.append({"Warm start": "base alone", "survival": survival(s)})
    return rows


def _deltas(results: dict, ws: tuple[str, ...], suffix: str, key: str, relative: bool, digits: int = 1,
            tag: str = "") -> str:
    """Paired difference of the warm start from each of its policies alone (same episodes)."""
    parts = []
    for n in ws:
        d = paired(results, f"{_name(ws, tag)}{suffix}", f"alone_{n}{suffix}", key, digits=digits, relative=relative)
        parts.append(d if len(ws) == 1 else f"vs {n}: {d}")
    return "; ".join(parts)


def _name(ws: tuple[str, ...], tag: str = "") -> str:
    return f"ws_{'+'.join(ws)}{f'_{tag}' if tag else ''}"


def _variants() -> list[tuple[tuple[str, ...], str]]:
    return [(ws, "") for ws in WARM_STARTS] + [(("base", "speed"), tag) for tag in ARBITRATION]


def table18_rows(results: dict) -> list[dict]:
    rows = []
    for ws, tag in _variants():
        s = results.get(_name(ws, tag))
        row = {"Warm start": _label(ws, tag)}
        th = THESIS.get(_label(ws), (None,) * 6) if not tag else (None,) * 6
        if not s or "skipped" in s:
            row["RL reward / step"] = f"skipped: {s['skipped']}" if s else "-"
        else:
            row.update({
                "RL reward / step": med(s["rl_reward"], 3),
                "Δ reward (paired, %)": _deltas(results, ws, "", "rl_reward", True, tag=tag),
                "RL return / episode": med(s["rl_return"], 0),
                "Initial cost": med(s["initial_cost"]),
                "Δ initial (paired, %)": _deltas(results, ws, "", "initial_cost", True, tag=tag),
                "Rollout cost (state)": med(s.get("rollout_cost")),
                "Rollout J (full)": med(s.get("rollout_cost_full")),
                "Survival": survival(s),
                "Δ survival (paired, fraction)": _deltas(results, ws, "", "survived", False, digits=2, tag=tag),
                "group wins": " / ".join(f"{100 * v:.0f} %" for v in (s.get("warm_start_won") or {}).values()),
                "switches / s": med(s.get("winner_switches_per_s"), 2),
            })
        names = ("thesis RL reward", "thesis Δ %", "thesis IC", "thesis Δ IC %", "thesis survival %")
        row.update({name: value if value is not None else "" for name, value in zip(names, th)})
        rows.append(row)
    for n in EXPERTS:
        s = results.get(f"alone_{n}")
        if s and "skipped" not in s:
            rows.append({"Warm start": f"{n} alone", "RL reward / step": med(s["rl_reward"], 3),
                         "RL return / episode": med(s["rl_return"], 0), "Initial cost": med(s["initial_cost"]),
                         "Survival": survival(s)})
    return rows


def _value(results: dict, name: str, key: str) -> float | None:
    s = results.get(name) or {}
    if "skipped" in s or not s:
        return None
    if key == "survival":
        return 100 * s["survival"]["rate"]
    return (s.get(key) or {}).get("median")


def figure(results: dict, path: Path) -> None:
    """Figs. 31-34 in one sheet."""
    plt = pyplot()
    fig, axes = plt.subplots(2, 3, figsize=(15, 8))
    labels = [_label(ws) for ws in WARM_STARTS]
    x = np.arange(len(WARM_STARTS))
    # Fig. 31: reward and initial cost on the simple task, warm start vs the (first) policy alone
    for ax, key, title in ((axes[0, 0], "rl_reward", "RL reward per step"),
                           (axes[0, 1], "initial_cost", "initial cost")):
        ours = [_value(results, f"ws_{'+'.join(ws)}", key) for ws in WARM_STARTS]
        alone = [_value(results, f"alone_{ws[0]}", key) for ws in WARM_STARTS]
        ax.bar(x - 0.2, [v or 0 for v in ours], 0.4, label="warm start")
        ax.bar(x + 0.2, [v or 0 for v in alone], 0.4, label="policy alone (first)")
        ax.set_xticks(x, labels, rotation=20, fontsize=7)
        ax.set_title(f"Fig. 31: {title}, simple task (median)", fontsize=9)
        ax.legend(fontsize=7)
    # Fig. 32: survival on the survival task
    ax = axes[0, 2]
    ours = [_value(results, f"ws_{'+'.join(ws)}_survival", "survival") for ws in WARM_STARTS]
    alone = [_value(results, f"alone_{ws[0]}_survival", "survival") for ws in WARM_STARTS]
    ax.bar(x - 0.2, [v or 0 for v in ours], 0.4, label="warm start")
    ax.bar(x + 0.2, [v or 0 for v in alone], 0.4, label="policy alone (first)")
    ax.set_xticks(x, labels, rotation=20, fontsize=7)
    ax.set_ylabel("survival [%]")
    ax.set_title("Fig. 32: survival task", fontsize=9)
    ax.legend(fontsize=7)
    # Fig. 33: survival and initial cost vs speed
    for ax, key, ylabel in ((axes[1, 0], "survival", "survival [%]"), (axes[1, 1], "initial_cost", "initial cost")):
        for i, ws in enumerate(SPEED_WARM_STARTS):
            ax.plot(SPEEDS, [_value(results, f"ws_{'+'.join(ws)}_v{v:g}", key) for v in SPEEDS], "o-", color=f"C{i}",
                    label=_label(ws))
        for i, n in enumerate(("base", "speed")):
            ax.plot(SPEEDS, [_value(results, f"alone_{n}_v{v:g}", key) for v in SPEEDS], "o:", color=f"C{i}",
                    label=f"{n} alone")
        ax.set_xlabel("forward speed [m/s]")
        ax.set_ylabel(ylabel)
        ax.set_title(f"Fig. 33: {ylabel} vs speed", fontsize=9)
        ax.legend(fontsize=7)
    axes[1, 1].set_yscale("log")
    # Fig. 34: winning group of base + speed over time (robot 0, first 2 s), per speed
    ax = axes[1, 2]
    for i, v in enumerate(SPEEDS):
        trace = (results.get(f"ws_base+speed_v{v:g}") or {}).get("winner_trace_robot0")
        if not trace:
            continue
        w = np.asarray(trace[:200], dtype=float)
        w[w < 0] = np.nan
        ax.step(np.arange(len(w)) * 0.01, w + 1.2 * i, where="post", label=f"{v:g} m/s")
    ax.set_yticks([0, 1, 1.2, 2.2, 2.4, 3.4], ["base", "speed"] * 3, fontsize=7)
    ax.set_xlabel("time [s] (100 Hz solves)")
    ax.set_title("Fig. 34: winning group of base + speed (robot 0)", fontsize=9)
    ax.legend(fontsize=7)
    save(fig, path)


def speed_rows(results: dict) -> list[dict]:
    rows = []
    variants = [(ws, "") for ws in SPEED_WARM_STARTS] + [(("base", "speed"), t) for t in ARBITRATION] \
        + [(("base alone",), ""), (("speed alone",), "")]
    for ws, tag in variants:
        alone = ws[0].endswith("alone")
        row = {"Warm start": ws[0] if alone else _label(ws, tag)}
        for v in SPEEDS:
            name = f"alone_{ws[0].split()[0]}_v{v:g}" if alone else f"{_name(ws, tag)}_v{v:g}"
            s = results.get(name)
            if not s or "skipped" in s:
                row[f"survival {v:g}"] = "skipped" if s else "-"
                continue
            row[f"survival {v:g}"] = survival(s)
            row[f"IC {v:g}"] = med(s["initial_cost"])
            if not alone and len(ws) > 1:
                row[f"switches/s {v:g}"] = med(s.get("winner_switches_per_s"), 2)
        rows.append(row)
    return rows


def survival_rows(results: dict) -> list[dict]:
    rows = []
    for ws, tag in _variants():
        s = results.get(f"{_name(ws, tag)}_survival")
        row = {"Warm start": _label(ws, tag)}
        if not s or "skipped" in s:
            row["survival"] = "skipped" if s else "-"
        else:
            row.update({"survival": survival(s), "switches / s": med(s.get("winner_switches_per_s"), 2),
                        "Δ survival (paired, fraction)": _deltas(results, ws, "_survival", "survived", False, digits=2,
                                                                 tag=tag)})
        rows.append(row)
    for n in EXPERTS:
        s = results.get(f"alone_{n}_survival")
        if s and "skipped" not in s:
            rows.append({"Warm start": f"{n} alone", "survival": survival(s)})
    return rows


def _flags(p) -> None:
    p.add_argument("--policy-dir", type=Path, default=REPO / "docs" / "policies",
                   help="folder of <expert>_actor.pt and <expert>_student_first_spline_h10.pt")
    p.add_argument("--seed-students", type=Path, default=None,
                   help="Fig. 32's primary contrast only: base alone and base's MPC warm-started by each student "
                        "<dir>/first-spline_H10_dt0.02_seed<k>/exported/student.pt2 (k = 0, 1, 2), merged")
    p.add_argument("--stairs", action="store_true",
                   help="run only the stairs cells (blind vs terrain-aware MPC; --episodes per step "
                        "height, 15 s) and write stairs.md/.csv and stairs.png")


def main() -> None:
    args = parse_args(__doc__, "table18_multi_policy", _flags)
    if args.stairs and args.seed_students:
        raise UserError("table18_multi_policy: --seed-students runs Fig. 32's contrast only, not with --stairs")
    if args.stairs:
        args.seconds = args.seconds if args.seconds_given else STAIRS_SECONDS  # what the cells run (config.json)
        todo = stairs_cells(Policies(args.policy_dir, args.variant))
        results = run_cells(todo, args)
        write_stairs(args, results)
        write_json(results, args.out / "results_stairs.json", indent=1)
        write_config(args, todo, {"results": dict(results), "part": "stairs", "episodes_per_step_height": args.episodes,
                                  "step_heights": list(STAIRS_HEIGHTS)})
        print((args.out / "stairs.md").read_text())
        return
    from experiments.output import write_table

    if args.seed_students:
        from experiments.warm_start_seeds import merge_seed_rows

        todo, seeded = fig32_seed_cells(Policies(args.policy_dir, args.variant), args.seed_students)
        results = run_cells(todo, args)
        merge_seed_rows(results, seeded)
        write_table(fig32_seed_rows(results, seeded),
                    ["Warm start", "survival", "Δ survival (paired, fraction)", "Δ return (paired)"],
                    args.out / "fig32_seeds", f"Fig. 32: survival task, base warm − base alone ({args.scale}: "
                    f"{args.episodes} episodes x {args.seconds:g} s, {args.sampler_seeds} sampler seeds per MPC "
                    f"episode, {len(seeded['ws_base_survival'])} students; the MPC terrain-blind)")
        write_json(results, args.out / "results.json", indent=1)
        write_config(args, todo, {"results": dict(results), "part": "fig32_seeds"})
        print((args.out / "fig32_seeds.md").read_text())
        return
    todo = cells(Policies(args.policy_dir, args.variant))
    results = run_cells(todo, args)
    write_stairs(args, results)

    write_table(survival_rows(results), ["Warm start", "survival", "Δ survival (paired, fraction)", "switches / s"],
                args.out / "fig32_survival", f"Fig. 32: survival task ({args.scale}: {args.episodes} episodes x "
                f"{args.seconds:g} s, {args.sampler_seeds} sampler seeds per MPC episode; the MPC terrain-blind)")
    cols = ["Warm start"] + [f"{k} {v:g}" for k in ("survival", "IC", "switches/s") for v in SPEEDS]
    write_table(speed_rows(results), cols, args.out / "fig33_speeds", f"Figs. 33-34: forward speeds ({args.scale})")
    cols = ["Warm start", "RL reward / step", "Δ reward (paired, %)", "RL return / episode", "Initial cost",
            "Δ initial (paired, %)", "Rollout cost (state)", "Rollout J (full)", "Survival",
            "Δ survival (paired, fraction)", "group wins", "switches / s", "thesis RL reward", "thesis Δ %",
            "thesis IC", "thesis Δ IC %", "thesis survival %"]
    finish(args, todo, results, table18_rows(results), cols, "Table 18: multiple warm starts, simple task", figure,
           "fig31_34.png")


if __name__ == "__main__":
    run_cli(main)

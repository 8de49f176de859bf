"""Table 15 and Fig. 28 (thesis 7.3.3): prediction horizon (dt, H) for the RL and naive warm starts,
first-spline, M = 10 000, forces only, simple task; Fig. 28 = the chosen sample's cost at each horizon
step (median over the recorded solves, log scale).

Table 15 is also a training table: each RL row's student is distilled for its (dt, H), so the row is
run with three *training seeds*. The script distils them first (DAgger, first-spline, the
distillation experiments' ``--student-scale``, default ``medium`` = 10 epochs x 10 000 datapoints,
the committed student's settings; the three seeds of a (dt, H) train together, ``distill_common``)
into ``<students>/table15_seeds/`` (resumable: finished runs are kept), then runs one cell per
student (each with the sampler seeds), and merges a row's students with ``merge_training_seeds``
(intervals over students and episodes). The committed student (the demo's, first-spline, H = 10,
dt = 0.02 s) gets a reference row of its own. ``--single-student`` runs the older protocol: one
student per (dt, H) from ``--students`` (``make_students.sh table15``).

    python -m experiments.table15_horizon --scale small
"""

from __future__ import annotations

import argparse
from pathlib import Path

from dls_quadruped.cli import UserError, run_cli
from experiments.output import pyplot, save
from experiments.warm_start_common import COMMITTED_STUDENT, Cell, parse_args, run_cells
from experiments.warm_start_seeds import merge_training_seeds
from experiments.warm_start_tables import finish, med, paired, survival, tabulate

GRID = [(0.02, 5), (0.04, 5), (0.02, 10), (0.02, 15), (0.04, 10), (0.04, 15)]
THESIS = {  # (controller, dt, H): (RL reward, initial cost)
    ("rl_warm_start", 0.02, 5): (2.355, 14.62), ("rl_warm_start", 0.04, 5): (2.348, 25.04),
    ("rl_warm_start", 0.02, 10): (2.346, 32.93), ("rl_warm_start", 0.02, 15): (2.329, 75.92),
    ("rl_warm_start", 0.04, 10): (2.329, 128.4), ("rl_warm_start", 0.04, 15): (2.238, 477.2),
    ("naive_warm_start", 0.02, 5): (2.258, 31.41), ("naive_warm_start", 0.04, 5): (2.255, 31.41),
    ("naive_warm_start", 0.02, 10): (2.248, 28.61), ("naive_warm_start", 0.02, 15): (2.233, 41.11),
    ("naive_warm_start", 0.04, 10): (2.179, 79.81), ("naive_warm_start", 0.04, 15): (1.756, 408.8),
}


def _row(ctrl: str, dt: float, h: int) -> dict:
    return {"Controller": ctrl, "dt [s]": dt, "H": h, "Time H. [s]": round(dt * h, 2)}


def cells(students: dict[tuple[float, int], list[Path]] | None = None) -> tuple[list[Cell], list[Cell]]:
    """(cells to run, table rows). Without ``students`` every row is one cell (the student of an RL row
    found by encoding); with them an RL row is merged from one cell per training seed ``..._seed<k>``,
    and the committed student has a row of its own."""
    runs, rows = [], []
    for ctrl in ("rl_warm_start", "naive_warm_start"):
        for dt, h in GRID:
            row = Cell(f"{ctrl}_dt{dt:g}_H{h}", ctrl, {"dt": dt, "horizon": h}, row=_row(ctrl, dt, h))
            rows.append(row)
            if ctrl == "rl_warm_start" and students is not None:
                runs += [Cell(f"{row.name}_seed{k}", ctrl, row.sampler, row=row.row, student=str(path))
                         for k, path in enumerate(students.get((dt, h), []))]
            else:
                runs.append(row)
        if ctrl == "rl_warm_start" and students is not None:
            ref = Cell("rl_warm_start_dt0.02_H10_committed", ctrl, {"dt": 0.02, "horizon": 10},
                       row=_row("rl_warm_start (committed student)", 0.02, 10), student=str(COMMITTED_STUDENT))
            runs.append(ref)
            rows.append(ref)
    return runs, rows


def _needed(only: list[str] | None) -> list[tuple[float, int]]:
    """The (dt, H) whose students the selected cells need (all without ``--only``)."""
    if not only:
        return list(GRID)
    return [(dt, h) for dt, h in GRID if any(name.startswith(f"rl_warm_start_dt{dt:g}_H{h}_seed") for name in only)]


def train_students(args: argparse.Namespace) -> dict[tuple[float, int], list[Path]]:
    """Distil (or find) the training seeds' students of every needed (dt, H); {(dt, H): [export per seed]}."""
    from dls_quadruped.learning.runner import sha256_file
    from dls_quadruped.learning.student import export_student, metadata
    from experiments import distill_common as dc
    from experiments import distill_eval

    root = args.students / "table15_seeds"
    ns = argparse.Namespace(scale=args.student_scale, out=root, expert=str(args.policy), keep_datasets=False)
    grid = _needed(args.only)
    seeds = dc.SCALES[args.student_scale]["seeds"]
    path = {(dt, h): [root / "exported" / f"first-spline_H{h}_dt{dt:g}_seed{k}.pt" for k in range(seeds)]
            for dt, h in grid}
    todo = [(dt, h) for dt, h in grid if not all(x.is_file() for x in path[(dt, h)])]
    if todo and getattr(args, "shard", None) is not None:  # N shards would each distil the same students
        raise UserError(f"the students of (dt, H) {', '.join(f'({dt:g}, {h})' for dt, h in todo)} are not under "
                        f"{root / 'exported'} yet: distil them first with --students-only (one process), then "
                        "start the --shard processes")
    if todo:
        runs = [dc.Run(f"first-spline_dt{dt:g}_H{h}",
                       {"algorithm": "dagger", "encoding": {"p": "first", "F": "spline", "horizon": h, "dt": dt}})
                for dt, h in todo]
        trained = dc.train_runs(runs, ns)
        for (dt, h), r in zip(todo, runs):
            res = trained[r.name]
            enc = distill_eval.net_encoding(res["config"])
            for k, out in enumerate(path[(dt, h)]):
                meta = metadata(enc, dt, 259, {"stride": round(dt / distill_eval.STEP_DT), "algorithm": "dagger",
                                               "training_seed": res["seeds"][k],
                                               "expert": {"path": str(args.policy), "sha256": sha256_file(args.policy)},
                                               "epochs_trained": res["config"]["train"]["epochs"],
                                               "datapoints_per_epoch": res["config"]["train"]["datapoints_per_epoch"]})
                export_student(distill_eval.trained_student(res["students"][k][0], res["config"]), meta, out)
    return path


def figure(results: dict, path: Path) -> None:
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    for ax, ctrl in zip(axes, ("rl_warm_start", "naive_warm_start")):
        for i, (dt, h) in enumerate(GRID):
            s = results.get(f"{ctrl}_dt{dt:g}_H{h}", {})
            hc = s.get("horizon_cost")
            if not hc:
                continue
            ax.plot(range(1, h + 1), [m["median"] for m in hc], "o-", color=f"C{i}", label=f"dt {dt:g}, H {h}")
        ax.set_yscale("log")
        ax.set_xlabel("horizon step k")
        ax.set_title(f"Fig. 28: {ctrl}, chosen sample's state cost per step (median)", fontsize=9)
        ax.legend(fontsize=7)
    axes[0].set_ylabel("cost of step k")
    save(fig, path)


def columns_with(results: dict):
    """The table's columns; an RL warm start's paired difference is against the naive warm start of the
    same (dt, H) on the same episodes."""

    def columns(c: Cell, s: dict) -> dict:
        hc = s.get("horizon_cost") or []
        ratio = f"{hc[-1]['median'] / hc[0]['median']:.1f}" if hc and hc[0]["median"] else "-"
        ref = f"naive_warm_start_dt{c.sampler['dt']:g}_H{c.sampler['horizon']}" if c.controller == "rl_warm_start" \
            else None
        return {"RL reward": med(s["rl_reward"], 3), "Initial cost": med(s["initial_cost"]),
                "Δ initial vs naive (paired)": paired(results, c.name, ref, "initial_cost") if ref else "",
                "Rollout cost (state)": med(s.get("rollout_cost")), "Rollout J (full)": med(s.get("rollout_cost_full")),
                "Survival": survival(s), "last/first step cost": ratio}

    return columns


def thesis(c: Cell) -> dict:
    th = THESIS.get((c.controller, c.row["dt [s]"], c.row["H"]), (None, None))
    return {"thesis RL reward": th[0] or "-", "thesis initial": th[1] or "-"}


def _flags(p: argparse.ArgumentParser) -> None:
    p.add_argument("--student-scale", choices=("small", "medium", "thesis"), default="medium",
                   help="distillation scale of the RL rows' students (experiments/distill_common.py SCALES)")
    p.add_argument("--single-student", action="store_true",
                   help="one student per (dt, H) from --students (make_students.sh table15), not 3 training seeds")
    p.add_argument("--students-only", action="store_true",
                   help="distil the training seeds' students and stop (before running --shard processes)")


def main() -> None:
    args = parse_args(__doc__, "table15_horizon", _flags)
    students = None if args.single_student else train_students(args)
    if args.students_only:
        print(f"[table15_horizon] students ready under {args.students / 'table15_seeds' / 'exported'}", flush=True)
        return
    todo, rows = cells(students)
    results = run_cells(todo, args)
    if students is not None:
        for row in rows:
            seeds = [results[c.name] for c in todo if c.name.startswith(row.name + "_seed") and c.name in results]
            if row.controller == "rl_warm_start" and row.name not in results and seeds:
                results[row.name] = merge_training_seeds(seeds)
    cols = ["Controller", "dt [s]", "H", "Time H. [s]", "RL reward", "Initial cost", "Δ initial vs naive (paired)",
            "Rollout cost (state)", "Rollout J (full)", "Survival", "last/first step cost", "thesis RL reward",
            "thesis initial"]
    title = "Table 15 (first-spline, M = 10 000, F only" + (")" if students is None else
                                                          f"; RL rows: 3 students x the sampler seeds, "
                                                          f"distilled at the {args.student_scale} scale)")
    finish(args, todo, results, tabulate(rows, results, columns_with(results), thesis), cols, title, figure,
           "fig28.png")


if __name__ == "__main__":
    run_cli(main)

"""Table 11 (thesis 7.2.2): naive imitation vs DAgger, discrete-discrete and first-spline, H = 5,
dt = 0.02 s, mini-batch 64, beta = 0.6^i (20 epochs at thesis scale), 3 training seeds per row.

Two more naive rows per encoding train on the naive row's own data (same seeds, same datapoints)
with another schedule, so that the difference from DAgger is the data and not the schedule:
``naive, DAgger's steps`` (epoch i trains on a random (i + 1) x datapoints_per_epoch of the data:
DAgger's gradient steps and learning rate per step) and ``naive, no lr decay`` (lr 1.0 throughout).

    python -m experiments.table11_naive_vs_dagger --scale small     # minutes on 2 cores
    python -m experiments.table11_naive_vs_dagger --scale thesis
"""

from __future__ import annotations

import time
from pathlib import Path

from dls_quadruped.core.json_io import write_json
from dls_quadruped.eval.provenance import provenance
from dls_quadruped.learning.distill_metrics import sp_difference
from experiments.distill_common import (
    Run,
    parse_args,
    select,
    sp_cell,
    summary_row,
    train_runs,
    write_config,
)
from experiments.distill_eval import evaluate, untrained_returns
from experiments.output import write_table

THESIS = {  # Table 11: (MSE, SP)
    ("naive", "discrete", "discrete"): (0.1546, "68.49 %"), ("dagger", "discrete", "discrete"): (0.2185, "98.91 %"),
    ("naive", "first", "spline"): (0.1613, "55.62 %"), ("dagger", "first", "spline"): (0.1870, "99.30 %"),
}


SCHEDULES = {"Table 7": {}, "DAgger's steps": {"naive_schedule": "dagger_steps"}, "no lr decay": {"lr_decay": 1.0}}


def runs(scale: str) -> list[Run]:
    train = {"batch_size": 64, **({"epochs": 20} if scale == "thesis" else {})}
    out = []
    for algo, p, F in THESIS:
        enc = {"encoding": {"p": p, "F": F, "horizon": 5, "dt": 0.02},
               "selector": {"kind": "exponential", "alpha": 0.6}}
        schedules = SCHEDULES if algo == "naive" else {"Table 7": {}}
        for sched, over in schedules.items():
            suffix = {"Table 7": "", "DAgger's steps": "-dagger-steps", "no lr decay": "-no-decay"}[sched]
            out.append(Run(f"{algo}{suffix}_{p}-{F}", {"algorithm": algo, **enc, "train": {**train, **over}},
                           row={"Algorithm": algo, "schedule": sched, "Encoding (p, F)": f"{p}, {F}"},
                           data_from=f"naive_{p}-{F}" if suffix else None))
    return out


def figure(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(10, 4))
    labels = [f"{r['Algorithm']}\n{r['schedule']}\n{r['Encoding (p, F)']}" for r in rows]
    ours = [r["_sp"] * 100 for r in rows]
    err = [[100 * (r["_sp"] - r["_ci"][0]) for r in rows], [100 * (r["_ci"][1] - r["_sp"]) for r in rows]]
    thesis = [float(r["thesis SP"].rstrip(" %")) for r in rows]
    x = range(len(rows))
    ax.bar([i - 0.2 for i in x], ours, 0.4, yerr=err, label="ours, 3 seeds (95 % CI over seeds and episodes)")
    ax.bar([i + 0.2 for i in x], thesis, 0.4, label="thesis")
    for i, r in zip(x, rows):
        ax.plot([i - 0.2] * len(r["_per_seed"]), [100 * v for v in r["_per_seed"]], "k.", ms=4)
    ax.set_xticks(list(x), labels, fontsize=7)
    ax.set_ylabel("SP [%]")
    ax.axhline(100, color="k", lw=0.8, ls="--")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    t0 = time.monotonic()
    args = parse_args(__doc__, "table11_naive_vs_dagger")
    rs = select(runs(args.scale), args.only)
    trained = train_runs(rs, args)
    t_train = time.monotonic() - t0
    ev = evaluate(trained, args)
    rets = ev["returns"]
    rows, diffs = [], {}
    for r in rs:
        row = {**r.row, **summary_row(trained, ev, r.name)}
        key = (r.row["Algorithm"], *r.row["Encoding (p, F)"].split(", "))
        row["thesis MSE"], row["thesis SP"] = THESIS[key]
        dagger = f"dagger_{key[1]}-{key[2]}"
        if r.row["Algorithm"] == "naive" and dagger in trained:
            r0 = untrained_returns(ev, trained[r.name]["config"])
            d = sp_difference(rets[r.name][-1], rets[dagger][-1], rets["expert"], r0, r0)
            diffs[r.name] = d
            row["SP - DAgger's [95 % CI]"] = sp_cell({"sp": d["difference"], "ci95": d["ci95"]})
        row["_sp"], row["_ci"] = ev["sp"][r.name][-1]["sp"], ev["sp"][r.name][-1]["ci95"]
        row["_per_seed"] = [p["sp"] for p in ev["sp"][r.name][-1]["per_seed"]]
        rows.append(row)
    cols = ["Algorithm", "schedule", "Encoding (p, F)", "MSE [95 % CI]", "SP [95 % CI]", "SP - DAgger's [95 % CI]",
            "SP per seed [%]", "MSE per seed", "survival", "thesis MSE", "thesis SP", "seeds", "SP episodes",
            "test windows", "train datapoints", "gradient steps", "epochs"]
    write_table(rows, cols, args.out / "table",
                f"Table 11, scale {args.scale}: naive IL vs DAgger (H = 5, dt = 0.02 s)")
    write_json({"rows": [{k: v for k, v in r.items() if not k.startswith("_")} for r in rows], "sp": ev["sp"],
                "mse": ev["mse"], "sp_difference_vs_dagger": diffs, "returns": rets, "test_set": ev["test_set"],
                **provenance()},
               args.out / "results.json")
    figure(rows, args.out / "table11.png")
    write_config(args, rs, trained, {"seconds": {"total": time.monotonic() - t0, "training_part": t_train,
                                                 "evaluation": ev["seconds"]}})
    print((args.out / "table.md").read_text())


if __name__ == "__main__":
    main()

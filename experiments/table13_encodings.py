"""Table 13 and Fig. 25 (thesis 7.2.3): DAgger with every encoding (p, F) x dt x H, 36 rows;
Fig. 25 (a) SP vs H and dt for discrete-discrete, (b) SP per encoding at H = 10, dt = 0.02 s;
3 training seeds per row, every row on the same data budget, test states and SP episodes.

    python -m experiments.table13_encodings --scale small
"""

from __future__ import annotations

import time
from pathlib import Path

from dls_quadruped.core.json_io import write_json
from dls_quadruped.eval.provenance import provenance
from dls_quadruped.mpc.config import EncodingConfig
from dls_quadruped.mpc.encodings import encoded_dim
from experiments.distill_common import (
    Run,
    parse_args,
    select,
    summary_row,
    train_runs,
    write_config,
)
from experiments.distill_eval import evaluate
from experiments.output import write_table

ENCODINGS = [("discrete", "discrete"), ("discrete", "spline"), ("spline", "discrete"), ("spline", "spline"),
             ("first", "discrete"), ("first", "spline")]
# Table 13 (MSE, SP), rows 1-36 in the thesis's order: dt, then H, then encoding
THESIS = [
    (0.2193, 98.53), (0.2181, 98.61), (0.1817, 99.11), (0.1846, 98.73), (0.1428, 98.98), (0.1548, 99.06),
    (0.2584, 97.59), (0.3241, 97.39), (0.2701, 97.07), (0.3792, 97.43), (0.1669, 98.51), (0.2282, 98.70),
    (0.3186, 95.97), (0.3948, 96.30), (0.4067, 95.31), (0.6288, 95.60), (0.2049, 97.91), (0.2798, 97.87),
    (0.2007, 98.44), (0.3132, 97.93), (0.2230, 98.44), (0.3311, 97.96), (0.1427, 98.74), (0.2242, 99.08),
    (0.3531, 96.96), (0.4070, 97.34), (0.4574, 95.34), (0.5933, 95.01), (0.2013, 98.19), (0.2666, 98.19),
    (0.3788, 95.63), (0.5386, 95.61), (0.4597, 85.50), (0.7303, 86.75), (0.2099, 98.04), (0.2680, 96.13),
]


def grid() -> list[tuple[int, float, int, str, str]]:
    """(row N°, dt, H, p, F) in the thesis's order."""
    out = []
    for dt in (0.02, 0.04):
        for H in (5, 10, 15):
            for p, F in ENCODINGS:
                out.append((len(out) + 1, dt, H, p, F))
    return out


def runs() -> list[Run]:
    return [Run(f"{n:02d}_{p}-{F}_dt{dt:g}_H{H}", {"algorithm": "dagger",
                                                   "encoding": {"p": p, "F": F, "horizon": H, "dt": dt}},
                group=f"dt{dt:g}_H{H}",
                row={"N°": n, "p": p, "F": F, "dt": dt, "H": H, "Time H.": round(dt * H, 2),
                     "Dim.": encoded_dim(EncodingConfig(p, F, H))}) for n, dt, H, p, F in grid()]


def figure(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 3.8))
    for dt, marker in ((0.02, "o"), (0.04, "s")):
        sel = [r for r in rows if r["p"] == "discrete" and r["F"] == "discrete" and r["dt"] == dt]
        if sel:
            a.errorbar([r["H"] for r in sel], [100 * r["_sp"] for r in sel],
                       yerr=[[100 * (r["_sp"] - r["_ci"][0]) for r in sel],
                             [100 * (r["_ci"][1] - r["_sp"]) for r in sel]],
                       fmt=marker + "-", label=f"ours dt = {dt}")
            a.plot([r["H"] for r in sel], [r["thesis SP"] for r in sel], marker + "--", alpha=0.6,
                   label=f"thesis dt = {dt}")
    a.set_xlabel("H")
    a.set_ylabel("SP [%]")
    a.set_title("(a) discrete-discrete")
    if a.get_legend_handles_labels()[0]:
        a.legend(fontsize=8)
    sel = [r for r in rows if r["H"] == 10 and r["dt"] == 0.02]
    x = range(len(sel))
    b.bar([i - 0.2 for i in x], [100 * r["_sp"] for r in sel], 0.4,
          yerr=[[100 * (r["_sp"] - r["_ci"][0]) for r in sel], [100 * (r["_ci"][1] - r["_sp"]) for r in sel]],
          label="ours, 3 seeds (95 % CI)")
    b.bar([i + 0.2 for i in x], [r["thesis SP"] for r in sel], 0.4, label="thesis")
    b.set_xticks(list(x), [f"{r['p']}\n{r['F']}" for r in sel], fontsize=8)
    b.set_title("(b) H = 10, dt = 0.02 s")
    b.set_ylabel("SP [%]")
    b.legend(fontsize=8)
    fig.suptitle("Fig. 25: SP of the students")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    t0 = time.monotonic()
    args = parse_args(__doc__, "table13_encodings")
    rs = select(runs(), args.only)
    trained = train_runs(rs, args)
    t_train = time.monotonic() - t0
    ev = evaluate(trained, args)
    rows = []
    for r in rs:
        row = {**r.row, **summary_row(trained, ev, r.name)}
        row["thesis MSE"], row["thesis SP"] = THESIS[r.row["N°"] - 1]
        row["_sp"], row["_ci"] = ev["sp"][r.name][-1]["sp"], ev["sp"][r.name][-1]["ci95"]
        rows.append(row)
    cols = ["N°", "p", "F", "dt", "H", "Time H.", "Dim.", "MSE [95 % CI]", "SP [95 % CI]", "SP per seed [%]",
            "MSE per seed", "survival", "thesis MSE", "thesis SP", "seeds", "SP episodes", "test windows",
            "train datapoints", "epochs"]
    write_table(rows, cols, args.out / "table", f"Table 13, scale {args.scale}: DAgger, every encoding x dt x H")
    write_json({"rows": [{k: v for k, v in r.items() if not k.startswith("_")} for r in rows], "sp": ev["sp"],
                "mse": ev["mse"], "returns": ev["returns"], "test_set": ev["test_set"], **provenance()},
               args.out / "results.json")
    figure(rows, args.out / "fig25.png")
    write_config(args, rs, trained, {"seconds": {"total": time.monotonic() - t0, "training_part": t_train,
                                                 "evaluation": ev["seconds"]}})
    print((args.out / "table.md").read_text())


if __name__ == "__main__":
    main()

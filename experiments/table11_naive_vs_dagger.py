"""Table 11 (thesis 7.2.2): naive imitation vs DAgger, discrete-discrete and first-spline, H = 5,
dt = 0.02 s, mini-batch 64, beta = 0.6^i (20 epochs at thesis scale).

    python experiments/table11_naive_vs_dagger.py --scale small     # minutes on 2 cores
    python experiments/table11_naive_vs_dagger.py --scale thesis
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from dls_quadruped.core.json_io import write_json
from experiments.distill_common import (
    Run,
    batched_sp,
    parse_args,
    summary_row,
    train_runs,
    write_config,
    write_table,
)

THESIS = {  # Table 11: (MSE, SP)
    ("naive", "discrete", "discrete"): (0.1546, "68.49 %"), ("dagger", "discrete", "discrete"): (0.2185, "98.91 %"),
    ("naive", "first", "spline"): (0.1613, "55.62 %"), ("dagger", "first", "spline"): (0.1870, "99.30 %"),
}


def runs(scale: str) -> list[Run]:
    train = {"batch_size": 64, **({"epochs": 20} if scale == "thesis" else {})}
    return [Run(f"{algo}_{p}-{F}", {"algorithm": algo, "encoding": {"p": p, "F": F, "horizon": 5, "dt": 0.02},
                                    "selector": {"kind": "exponential", "alpha": 0.6}, "train": train},
                row={"Algorithm": algo, "Encoding (p, F)": f"{p}, {F}"})
            for algo, p, F in THESIS]


def figure(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.5))
    labels = [f"{r['Algorithm']}\n{r['Encoding (p, F)']}" for r in rows]
    ours = [r["_sp"] * 100 for r in rows]
    err = [[100 * (r["_sp"] - r["_ci"][0]) for r in rows], [100 * (r["_ci"][1] - r["_sp"]) for r in rows]]
    thesis = [float(r["thesis SP"].rstrip(" %")) for r in rows]
    x = range(len(rows))
    ax.bar([i - 0.2 for i in x], ours, 0.4, yerr=err, label="ours (95 % CI)")
    ax.bar([i + 0.2 for i in x], thesis, 0.4, label="thesis")
    ax.set_xticks(list(x), labels)
    ax.set_ylabel("SP [%]")
    ax.axhline(100, color="k", lw=0.8, ls="--")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    args = parse_args(__doc__, "table11_naive_vs_dagger")
    rs = [r for r in runs(args.scale) if args.only is None or r.name in args.only]
    trained = train_runs(rs, args)
    sp = batched_sp(trained, args)
    rows = []
    for r in rs:
        row = {**r.row, **summary_row(trained, sp, r.name)}
        key = (r.row["Algorithm"], *r.row["Encoding (p, F)"].split(", "))
        row["thesis MSE"], row["thesis SP"] = THESIS[key]
        row["_sp"], row["_ci"] = sp[r.name][-1]["sp"], sp[r.name][-1]["ci95"]
        rows.append(row)
    cols = ["Algorithm", "Encoding (p, F)", "MSE", "SP [95 % CI]", "survival", "thesis MSE", "thesis SP",
            "SP episodes", "test datapoints", "train datapoints", "epochs"]
    write_table(rows, cols, args.out / "table", f"Table 11, scale {args.scale}: naive IL vs DAgger (H = 5, dt = 0.02 s)")
    write_json({"rows": [{k: v for k, v in r.items() if not k.startswith("_")} for r in rows], "sp": sp},
               args.out / "results.json")
    figure(rows, args.out / "table11.png")
    write_config(args, rs, trained)
    print((args.out / "table.md").read_text())


if __name__ == "__main__":
    main()

"""Table 12 (thesis 7.2.3): DAgger mini-batch size 64 ... 1024, discrete-discrete, H = 5, dt = 0.02 s;
dataset size and epochs fixed, so a larger batch makes fewer gradient steps; 3 training seeds per row.

    python -m experiments.table12_batch_size --scale small
"""

from __future__ import annotations

import time
from pathlib import Path

from dls_quadruped.core.json_io import write_json
from dls_quadruped.eval.provenance import provenance
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

THESIS = {64: (0.2048, "98.53 %"), 128: (0.2534, "98.54 %"), 256: (0.2764, "97.79 %"), 512: (0.3444, "94.89 %"),
          1024: (0.4876, "89.60 %")}


def runs() -> list[Run]:
    return [Run(f"batch_{b}", {"algorithm": "dagger", "encoding": {"p": "discrete", "F": "discrete", "horizon": 5,
                                                                   "dt": 0.02}, "train": {"batch_size": b}},
                row={"batch": b}) for b in THESIS]


def figure(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(9, 3.5))
    x = [r["batch"] for r in rows]
    a.errorbar(x, [100 * r["_sp"] for r in rows], yerr=[[100 * (r["_sp"] - r["_ci"][0]) for r in rows],
                                                         [100 * (r["_ci"][1] - r["_sp"]) for r in rows]],
               fmt="o-", label="ours, 3 seeds (95 % CI)")
    a.plot(x, [float(THESIS[v][1].rstrip(" %")) for v in x], "s--", label="thesis")
    a.set_xscale("log", base=2)
    a.set_xlabel("mini-batch")
    a.set_ylabel("SP [%]")
    a.legend()
    b.errorbar(x, [r["_mse"] for r in rows], yerr=[[r["_mse"] - r["_mse_ci"][0] for r in rows],
                                                   [r["_mse_ci"][1] - r["_mse"] for r in rows]], fmt="o-", label="ours")
    b.plot(x, [THESIS[v][0] for v in x], "s--", label="thesis")
    b.set_xscale("log", base=2)
    b.set_xlabel("mini-batch")
    b.set_ylabel("test MSE")
    b.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    t0 = time.monotonic()
    args = parse_args(__doc__, "table12_batch_size")
    rs = select(runs(), args.only)
    trained = train_runs(rs, args)
    t_train = time.monotonic() - t0
    ev = evaluate(trained, args)
    rows = []
    for r in rs:
        row = {**r.row, **summary_row(trained, ev, r.name)}
        row["thesis MSE"], row["thesis SP"] = THESIS[r.row["batch"]]
        row["_sp"], row["_ci"] = ev["sp"][r.name][-1]["sp"], ev["sp"][r.name][-1]["ci95"]
        row["_mse"], row["_mse_ci"] = ev["mse"][r.name][-1]["mse"], ev["mse"][r.name][-1]["ci95"]
        rows.append(row)
    cols = ["batch", "gradient steps", "MSE [95 % CI]", "SP [95 % CI]", "SP per seed [%]", "MSE per seed", "survival",
            "thesis MSE", "thesis SP", "seeds", "SP episodes", "test windows", "train datapoints", "epochs"]
    write_table(rows, cols, args.out / "table", f"Table 12, scale {args.scale}: DAgger mini-batch size "
                "(discrete-discrete, H = 5, dt = 0.02 s)")
    write_json({"rows": [{k: v for k, v in r.items() if not k.startswith("_")} for r in rows], "sp": ev["sp"],
                "mse": ev["mse"], "returns": ev["returns"], "test_set": ev["test_set"], **provenance()},
               args.out / "results.json")
    figure(rows, args.out / "table12.png")
    write_config(args, rs, trained, {"seconds": {"total": time.monotonic() - t0, "training_part": t_train,
                                                 "evaluation": ev["seconds"]}})
    print((args.out / "table.md").read_text())


if __name__ == "__main__":
    main()

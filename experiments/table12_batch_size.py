"""Table 12 (thesis 7.2.3): DAgger mini-batch size 64 ... 1024, discrete-discrete, H = 5, dt = 0.02 s;
dataset size and epochs fixed, so a larger batch makes fewer gradient steps.

    python experiments/table12_batch_size.py --scale small
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
               fmt="o-", label="ours (95 % CI)")
    a.plot(x, [float(THESIS[v][1].rstrip(" %")) for v in x], "s--", label="thesis")
    a.set_xscale("log", base=2)
    a.set_xlabel("mini-batch")
    a.set_ylabel("SP [%]")
    a.legend()
    b.plot(x, [float(r["MSE"]) for r in rows], "o-", label="ours")
    b.plot(x, [THESIS[v][0] for v in x], "s--", label="thesis")
    b.set_xscale("log", base=2)
    b.set_xlabel("mini-batch")
    b.set_ylabel("test MSE")
    b.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    args = parse_args(__doc__, "table12_batch_size")
    rs = [r for r in runs() if args.only is None or r.name in args.only]
    trained = train_runs(rs, args)
    sp = batched_sp(trained, args)
    rows = []
    for r in rs:
        row = {**r.row, **summary_row(trained, sp, r.name)}
        row["gradient steps"] = sum(h["train"]["steps"] for h in trained[r.name]["history"])
        row["thesis MSE"], row["thesis SP"] = THESIS[r.row["batch"]]
        row["_sp"], row["_ci"] = sp[r.name][-1]["sp"], sp[r.name][-1]["ci95"]
        rows.append(row)
    cols = ["batch", "gradient steps", "MSE", "SP [95 % CI]", "survival", "thesis MSE", "thesis SP", "SP episodes",
            "test datapoints", "train datapoints", "epochs"]
    write_table(rows, cols, args.out / "table", f"Table 12, scale {args.scale}: DAgger mini-batch size "
                "(discrete-discrete, H = 5, dt = 0.02 s)")
    write_json({"rows": [{k: v for k, v in r.items() if not k.startswith("_")} for r in rows], "sp": sp},
               args.out / "results.json")
    figure(rows, args.out / "table12.png")
    write_config(args, rs, trained)
    print((args.out / "table.md").read_text())


if __name__ == "__main__":
    main()

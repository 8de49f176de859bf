"""Fig. 24 (thesis 7.2.3): DAgger policy selector, indicator vs exponential decay alpha^i with
alpha in {0.3, 0.6, 0.9}; SP (a) and test MSE (b) over the epochs. The thesis does not state the
encoding of this figure; we use discrete-discrete, H = 5, dt = 0.02 s as in Table 12. 3 training
seeds per selector; every epoch's students are evaluated on the same SP episodes and test states.

    python -m experiments.fig24_selector --scale small
"""

from __future__ import annotations

import time
from pathlib import Path

from dls_quadruped.core.json_io import write_json
from dls_quadruped.eval.provenance import provenance
from experiments.distill_common import (
    Run,
    mse_cell,
    parse_args,
    seeds_cell,
    select,
    sp_cell,
    train_runs,
    write_config,
)
from experiments.distill_eval import evaluate
from experiments.output import write_table

SELECTORS = [("indicator", {"kind": "indicator"}), ("alpha_0.3", {"kind": "exponential", "alpha": 0.3}),
             ("alpha_0.6", {"kind": "exponential", "alpha": 0.6}), ("alpha_0.9", {"kind": "exponential", "alpha": 0.9})]


def runs() -> list[Run]:
    return [Run(name, {"algorithm": "dagger", "selector": sel,
                       "encoding": {"p": "discrete", "F": "discrete", "horizon": 5, "dt": 0.02}},
                snapshots=True, row={"selector": name.replace("_", " = ")}) for name, sel in SELECTORS]


def figure(ev: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.8))
    sp, mse = ev["sp"], ev["mse"]
    for name, _ in SELECTORS:
        if name not in sp:
            continue
        e = [r["epoch"] for r in sp[name]]
        v = [100 * r["sp"] for r in sp[name]]
        line, = a.plot(e, v, "o-", label=name.replace("_", " = "))
        a.fill_between(e, [100 * r["ci95"][0] for r in sp[name]], [100 * r["ci95"][1] for r in sp[name]],
                       color=line.get_color(), alpha=0.15)
        m = mse[name]
        b.plot([r["epoch"] for r in m], [r["mse"] for r in m], "o-", color=line.get_color(),
               label=name.replace("_", " = "))
        b.fill_between([r["epoch"] for r in m], [r["ci95"][0] for r in m], [r["ci95"][1] for r in m],
                       color=line.get_color(), alpha=0.15)
    a.set_xlabel("epoch")
    a.set_ylabel("SP [%], 3 seeds (95 % CI shaded)")
    a.axhline(100, color="k", lw=0.8, ls="--")
    a.legend()
    b.set_xlabel("epoch")
    b.set_ylabel("test MSE")
    b.set_yscale("log")
    b.legend()
    fig.suptitle("Fig. 24: policy selector (DAgger, discrete-discrete, H = 5)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    t0 = time.monotonic()
    args = parse_args(__doc__, "fig24_selector")
    rs = select(runs(), args.only)
    trained = train_runs(rs, args)
    t_train = time.monotonic() - t0
    ev = evaluate(trained, args)
    rows = []
    for r in rs:
        for snap, m, h in zip(ev["sp"][r.name], ev["mse"][r.name], trained[r.name]["history"]):
            rows.append({**r.row, "epoch": snap["epoch"], "beta": f"{h['beta']:.3g}", "MSE [95 % CI]": mse_cell(m),
                         "SP [95 % CI]": sp_cell(snap),
                         "SP per seed [%]": seeds_cell([p["sp"] for p in snap["per_seed"]]),
                         "survival": f"{100 * snap['survival']['rate']:.1f} %", "seeds": snap["seeds"],
                         "SP episodes": snap["episodes"], "dataset": h["dataset_size"]})
    cols = ["selector", "epoch", "beta", "MSE [95 % CI]", "SP [95 % CI]", "SP per seed [%]", "survival", "seeds",
            "SP episodes", "dataset"]
    write_table(rows, cols, args.out / "table", f"Fig. 24, scale {args.scale}: policy selector over epochs")
    write_json({"rows": rows, "sp": ev["sp"], "mse": ev["mse"], "returns": ev["returns"], "test_set": ev["test_set"],
                **provenance()}, args.out / "results.json")
    figure(ev, args.out / "fig24.png")
    write_config(args, rs, trained, {"seconds": {"total": time.monotonic() - t0, "training_part": t_train,
                                                 "evaluation": ev["seconds"]}})
    print((args.out / "table.md").read_text())


if __name__ == "__main__":
    main()

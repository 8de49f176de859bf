"""Table 11 settled: where, if anywhere, does the thesis's naive-vs-DAgger gap appear?

The thesis (Table 11) reports SP 55.6 % for naive imitation against 99.3 % for DAgger (first-spline); our
Table 11 runs found the two close. This sweep varies what could make naive imitation fail, every cell with 3
training seeds on the same scheduled SP episodes:

* **data**: 15 k, 50 k, 100 k and 400 k datapoints in all (10 epochs of a tenth each; ``--sizes`` picks some);
* **collection**: ``today`` (the base task, a new velocity command every 10 s of the 15 s episodes) and
  ``narrow`` (one fixed command per episode: the expert's states cover less, so a student's drift finds states
  its data never showed);
* **evaluation**: the base task as collected (``plain``) and with the rough task's "high" observation noise and
  pushes added (``disturbed``: noise scale 1, a push of up to 0.5 m/s every 8-12 s), chosen before any run.

Encoding first-spline, H = 5, dt = 0.02 s, batch 64, beta = 0.6^i (Table 11's). The expert is the committed base
expert (``--expert``). Per (collection, data, evaluation): SP of naive and of DAgger with their intervals
(seeds and episodes, two-level bootstrap) and the difference naive - DAgger with its interval (episodes paired,
seeds resampled independently, ``distill_metrics.sp_difference``). The thesis's gap *appears* in a cell where
that interval lies wholly below 0.

    python -m experiments.table11_sweep --scale medium --sizes 15000 50000 100000
    python -m experiments.table11_sweep --scale medium          # all four sizes (the finished runs are kept)
"""

from __future__ import annotations

import time

from dls_quadruped.core.json_io import write_json
from dls_quadruped.eval.provenance import provenance
from dls_quadruped.learning.distill_metrics import sp_difference
from experiments.distill_common import (
    Run,
    parse_args,
    pct,
    select,
    sp_cell,
    train_runs,
    write_config,
)
from experiments.distill_eval import evaluate, untrained_returns
from experiments.output import write_table

SIZES = (15_000, 50_000, 100_000, 400_000)
EPOCHS = 10
COLLECTIONS = {
    "today": None,
    "narrow": {"commands": {"base_velocity": {"resampling_time_s": [1000.0, 1000.0]}}},
}
EVALUATIONS = {
    "plain": None,
    "disturbed": {"observations": {"policy": {"noise_scale": 1.0}},
                  "events": {"push": {"func": "push_robot", "mode": "interval", "interval_s": [8.0, 12.0],
                                      "params": {"velocity_range": [-0.5, 0.5]}}}},
}
THESIS = {"naive": "55.62 %", "dagger": "99.30 %"}  # Table 11, first-spline


def name(algo: str, collection: str, size: int) -> str:
    return f"{algo}_{collection}_{f'{size // 1000}k' if size % 1000 == 0 else size}"


def runs(sizes: tuple[int, ...]) -> list[Run]:
    enc = {"encoding": {"p": "first", "F": "spline", "horizon": 5, "dt": 0.02},
           "selector": {"kind": "exponential", "alpha": 0.6}}
    out = []
    for collection, over in COLLECTIONS.items():
        for size in sizes:
            for algo in ("naive", "dagger"):
                train = {"batch_size": 64, "epochs": EPOCHS, "datapoints_per_epoch": size // EPOCHS}
                out.append(Run(name(algo, collection, size), {"algorithm": algo, **enc, "train": train},
                               row={"collection": collection, "datapoints": size, "algorithm": algo},
                               collect=over))
    return out


def _sizes(p) -> None:
    p.add_argument("--sizes", type=int, nargs="+", default=list(SIZES), choices=list(SIZES), metavar="N",
                   help=f"total datapoints per run, of {', '.join(map(str, SIZES))} (default all)")


def main() -> None:
    t0 = time.monotonic()
    args = parse_args(__doc__, "table11_sweep", extra=_sizes)
    rs = select(runs(tuple(sorted(set(args.sizes)))), args.only)
    trained = train_runs(rs, args)
    t_train = time.monotonic() - t0
    evs = {ev: evaluate(trained, args, over) for ev, over in EVALUATIONS.items()}
    rows, diffs = [], {}
    for r in rs:
        row = {**r.row, "MSE (plain test set)": f"{evs['plain']['mse'][r.name][-1]['mse']:.3f}",
               "thesis SP": THESIS[r.row["algorithm"]]}
        for ev_name, ev in evs.items():
            sp = ev["sp"][r.name][-1]
            row[f"SP {ev_name}"] = sp_cell(sp)
            row[f"survival {ev_name}"] = pct(sp["survival"]["rate"])
            row[f"survival {ev_name} (expert)"] = pct(sp["survival_expert"]["rate"])
            if r.row["algorithm"] == "naive":
                dagger = name("dagger", r.row["collection"], r.row["datapoints"])
                if dagger in trained:
                    rets = ev["returns"]
                    r0 = untrained_returns(ev, trained[r.name]["config"])
                    d = sp_difference(rets[r.name][-1], rets[dagger][-1], rets["expert"], r0, r0)
                    diffs[f"{r.name} {ev_name}"] = d
                    row[f"SP naive - DAgger, {ev_name}"] = sp_cell({"sp": d["difference"], "ci95": d["ci95"]})
        rows.append(row)
    cols = ["collection", "datapoints", "algorithm", "SP plain", "SP naive - DAgger, plain", "SP disturbed",
            "SP naive - DAgger, disturbed", "survival plain", "survival plain (expert)", "survival disturbed",
            "survival disturbed (expert)", "MSE (plain test set)", "thesis SP"]
    write_table(rows, cols, args.out / "table", f"Table 11 sweep, scale {args.scale}: naive IL vs DAgger "
                f"(first-spline, H = 5, dt = 0.02 s, 3 seeds)")
    write_json({"rows": rows, "sp_difference_naive_minus_dagger": diffs, **provenance(),
                **{ev_name: {k: ev[k] for k in ("sp", "mse", "returns", "test_set", "seconds")}
                   for ev_name, ev in evs.items()}}, args.out / "results.json")
    write_config(args, rs, trained, {"collections": COLLECTIONS, "evaluations": EVALUATIONS,
                                     "seconds": {"total": time.monotonic() - t0, "training_part": t_train,
                                                 **{f"evaluation_{k}": ev["seconds"] for k, ev in evs.items()}}})
    print((args.out / "table.md").read_text())


if __name__ == "__main__":
    main()

"""The thesis-5.3 evaluation ([mpc_cost_plan.md](docs/experiments/mpc_cost_plan.md)): Table 14's protocol at the
matched height reference with the horizon-space PPO policies as warm starts.

Cells, all on the same scheduled test episodes (the simple task, first-spline, H = 10, dt = 0.02 s, M = 10 000,
the MPC optimising the forces only, every MPC and the initial-cost probe at ``--com-height``, 0.404 m):

* ``naive_warm_start``; ``rl_warm_start`` with the DAgger student (the start of every run); ``rl_warm_start`` with
  each run's selected policy (``<policies>/base_mpc_cost_<run>.pt2``, written by ``mpc_cost_select.py --export``;
  a run whose policy is missing is skipped with a note);
* alone: the DAgger student, each run's policy (``student``: the first action of its horizon) and
  ``base_recipe_actor.pt2`` (``rl_baseline``).

Runs of one weight are merged over their training seeds (``merge_training_seeds``: per episode each seed's mean over
its sampler seeds, intervals over episodes and seeds). Contrasts (paired on the episodes, 95 % interval by the
two-level bootstrap, 2 000 resamples): the primary (initial cost, W = -0.1 merged - naive), secondary 1 (5.3 policy
- DAgger student as warm starts), 2 (walking quality alone), 3 (each weight, and the dose contrasts against W = 0),
4 (by term). The manipulation check -- the policy's own trajectory cost c alone on the test episodes, 5.3 policy -
DAgger student -- is measured by ``mpc_cost_select.evaluate`` on the same commands (``manipulation.json``).

    python -m experiments.mpc_cost_eval --scale medium --runs w0.1_s0 w0.1_s1 \\
        --out docs/experiments/mpc_cost/eval_medium
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dls_quadruped.cli import run_cli
from dls_quadruped.core.json_io import write_json
from dls_quadruped.eval.metrics import paired_difference
from dls_quadruped.eval.provenance import provenance
from dls_quadruped.eval.scenario import EvalOptions
from dls_quadruped.mpc.cost import STATE_TERMS
from experiments.mpc_cost_select import STUDENT, evaluate
from experiments.output import pyplot, save, write_table
from experiments.warm_start_common import Cell, parse_args, run_cells
from experiments.warm_start_seeds import merge_training_seeds
from experiments.warm_start_tables import finish, med, survival

FIRST_SPLINE = {"encoding_p": "first", "encoding_F": "spline"}
POLICIES = Path("docs/policies")  # relative to the repository root, where the scripts run
WEIGHTS = {"w0.1": -0.1, "w0.05": -0.05, "w0": 0.0, "scratch_w0.1": -0.1}
"""Run-name prefix -> its trajectory-cost weight W (runs are ``<prefix>_s<seed>``; ``scratch_``: trained from
scratch, not from the student, exploratory)."""


def arm_label(prefix: str) -> str:
    """The table's W column: the weight, "scratch" beside it for a run trained from scratch."""
    return f"{WEIGHTS[prefix]:g}" + (" (scratch)" if prefix.startswith("scratch") else "")
PRIMARY = "w0.1"


def policy_file(policies: Path, run: str) -> Path:
    return policies / f"base_mpc_cost_{run}.pt2"


def cells(runs: list[str], policies: Path) -> list[Cell]:
    out = [Cell("naive_warm_start", "naive_warm_start", FIRST_SPLINE, row={"Controller": "naive_warm_start"}),
           Cell("rl_warm_start_student", "rl_warm_start", FIRST_SPLINE, student=str(STUDENT),
                row={"Controller": "rl_warm_start, DAgger student"})]
    out += [Cell(f"rl_warm_start_{r}", "rl_warm_start", FIRST_SPLINE, student=str(policy_file(policies, r)),
                 row={"Controller": f"rl_warm_start, 5.3 policy {r}"}) for r in runs]
    out += [Cell("alone_student", "student", FIRST_SPLINE, student=str(STUDENT),
                 row={"Controller": "DAgger student alone"}),
            Cell("alone_rl_baseline", "rl_baseline", policy=str(POLICIES / "base_recipe_actor.pt2"),
                 row={"Controller": "base_recipe_actor.pt2 alone"})]
    out += [Cell(f"alone_{r}", "student", FIRST_SPLINE, student=str(policy_file(policies, r)),
                 row={"Controller": f"5.3 policy {r} alone"}) for r in runs]
    return out


def weight_rows(results: dict, runs: list[str], prefix: str) -> None:
    """Add the merged rows ``<kind>_<prefix>`` (kind: rl_warm_start, alone) over the runs of one weight that ran."""
    for kind in ("rl_warm_start", "alone"):
        names = [f"{kind}_{r}" for r in runs if r.startswith(prefix + "_s")]
        done = [results[n] for n in names if n in results and "skipped" not in results[n]]
        if done:
            results[f"{kind}_{prefix}"] = merge_training_seeds(done) if len(done) > 1 else done[0]
            results[f"{kind}_{prefix}"]["merged_from"] = [n for n in names if n in results and
                                                          "skipped" not in results[n]]


def contrast(results: dict, a: str, b: str, key: str) -> dict | None:
    """Paired a - b of per-episode ``key``: mean, its 95 % interval, the median difference, episodes."""
    sa, sb = results.get(a) or {}, results.get(b) or {}
    if key not in sa.get("per_episode", {}) or key not in sb.get("per_episode", {}):
        return None
    same = sa.get("students") is not None and sa.get("students") == sb.get("students")
    d = paired_difference(np.array(sa["per_episode"][key], dtype=float), np.array(sb["per_episode"][key], dtype=float),
                          paired_seeds=same)
    return {"a": a, "b": b, "key": key, "mean": d["mean"], "ci95": d["ci95"], "median": d["median"],
            "median_ci95": d["median_ci95"], "episodes": d["episodes"]}


def contrasts(results: dict, weights: list[str]) -> list[dict]:
    out = []
    keys = ("initial_cost", "rollout_cost", "rl_reward", "survived")
    for w in weights:
        for a, b, what in ((f"rl_warm_start_{w}", "naive_warm_start", "5.3 warm start - naive"),
                           (f"rl_warm_start_{w}", "rl_warm_start_student", "5.3 warm start - student warm start"),
                           (f"alone_{w}", "alone_rl_baseline", "5.3 alone - base_recipe_actor alone"),
                           (f"alone_{w}", "alone_student", "5.3 alone - student alone")):
            for key in keys:
                if (c := contrast(results, a, b, key)) is not None:
                    out.append({"weight": WEIGHTS[w], "arm": w, "contrast": what, **c})
        dose = w not in ("w0", "scratch_w0.1")  # the scratch run has no W = 0 twin from scratch
        if dose and (c := contrast(results, f"rl_warm_start_{w}", "rl_warm_start_w0", "initial_cost")):
            out.append({"weight": WEIGHTS[w], "arm": w, "contrast": "dose: W - (W = 0), warm start", **c})
    for a, b, what in (("rl_warm_start_student", "naive_warm_start", "student warm start - naive"),):
        for key in keys:
            if (c := contrast(results, a, b, key)) is not None:
                out.append({"weight": None, "arm": None, "contrast": what, **c})
    for w in weights:  # by term, medians of the paired differences (cost_gap.md's statistic)
        for b in ("naive_warm_start", "rl_warm_start_student"):
            for prefix in ("initial_term_", "rollout_term_"):
                for t in STATE_TERMS:
                    if (c := contrast(results, f"rl_warm_start_{w}", b, prefix + t)) is not None:
                        out.append({"weight": WEIGHTS[w], "arm": w, "contrast": f"by term, 5.3 warm start - {b}",
                                    **c})
    return out


def manipulation(runs: list[str], policies: Path, args) -> dict:
    """The policy's own c alone on the test episodes (``mpc_cost_select.evaluate``, W = 0: the Table-4 reward),
    each 5.3 policy and the student; cached in ``<out>/manipulation/``."""
    import json

    from dls_quadruped.envs.config import load_task

    params = load_task("base_mpc_cost").data["rewards"]["mpc_trajectory_cost"]["params"]
    opts = EvalOptions(episodes=args.episodes, seed=args.seed, num_workers=0, episode_length_s=args.seconds)
    out = {}
    folder = args.out / "manipulation"
    folder.mkdir(parents=True, exist_ok=True)
    for name, path in [("student", STUDENT), *((r, policy_file(policies, r)) for r in runs)]:
        if not path.is_file():
            continue
        cached = folder / f"{name}.json"
        if cached.is_file():
            out[name] = json.loads(cached.read_text())
            continue
        out[name] = evaluate(path, 0.0, opts, params)
        write_json({**out[name], **provenance()}, cached, indent=1)
    return out


def manipulation_rows(man: dict, weights: list[str], runs: list[str]) -> list[dict]:
    rows = []
    if "student" not in man:
        return rows
    student = np.array(man["student"]["per_episode"]["c_mean"], dtype=float)
    for w in weights:
        mine = [np.array(man[r]["per_episode"]["c_mean"], dtype=float) for r in runs
                if r.startswith(w + "_s") and r in man]
        if not mine:
            continue
        d = paired_difference(np.stack(mine), student[None])
        rows.append({"weight": WEIGHTS[w], "arm": w, "policies": len(mine), "c (5.3 alone)": float(np.mean(mine)),
                     "c (student alone)": float(student.mean()), "5.3 - student": d["mean"], "ci95": d["ci95"]})
    return rows


def fmt(c: dict | None, digits: int = 1) -> str:
    if c is None:
        return "-"
    lo, hi = c["ci95"]
    return f"{c['mean']:+.{digits}f} [{lo:+.{digits}f}, {hi:+.{digits}f}]"


def figure(results: dict, path: Path) -> None:
    """Initial cost per cell (median, 95 % interval)."""
    plt = pyplot()
    names = [n for n in results if "per_episode" in results[n] and "initial_cost" in results[n]]
    fig, ax = plt.subplots(figsize=(10, 4))
    for i, n in enumerate(names):
        m = results[n]["initial_cost"]
        lo, hi = m.get("ci95", [m["q1"], m["q3"]])
        ax.errorbar(i, m["median"], yerr=[[m["median"] - lo], [hi - m["median"]]], fmt="o", capsize=3)
    ax.set_xticks(range(len(names)), names, rotation=30, ha="right", fontsize=7)
    ax.set_ylabel("initial cost (median, 95 % CI)")
    ax.set_title("Thesis 5.3: initial cost per cell", fontsize=9)
    save(fig, path)


def _flags(p) -> None:
    p.add_argument("--runs", nargs="*", default=[], help="run names <w0.1|w0.05|w0>_s<seed> whose policies to add")
    p.add_argument("--policies", type=Path, default=POLICIES, help="folder of base_mpc_cost_<run>.pt2")


def main() -> None:
    args = parse_args(__doc__, "mpc_cost_eval", _flags)
    bad = [r for r in args.runs if r.rsplit("_s", 1)[0] not in WEIGHTS]
    if bad:
        raise SystemExit(f"--runs: {bad} are not <w>_s<seed> with <w> in {sorted(WEIGHTS)}")
    todo = cells(args.runs, args.policies)
    results = run_cells(todo, args)
    weights = [w for w in WEIGHTS if any(r.startswith(w + "_s") for r in args.runs)]
    for w in weights:
        weight_rows(results, args.runs, w)
    rows = contrasts(results, weights)
    man = manipulation(args.runs, args.policies, args)
    man_rows = manipulation_rows(man, weights, args.runs)
    write_json({"contrasts": rows, "manipulation": man_rows, **provenance()}, args.out / "contrasts.json", indent=1)
    table = [{"W": "-" if r["arm"] is None else arm_label(r["arm"]), "contrast": r["contrast"], "quantity": r["key"],
              "mean [95 % CI]": fmt(r, 3 if r["key"] in ("rl_reward", "survived") else 1),
              "median of differences": f"{r['median']:+.2f}"} for r in rows]
    table += [{"W": arm_label(r["arm"]), "contrast": "manipulation: c alone, 5.3 - student", "quantity": "c",
               "mean [95 % CI]": fmt({"mean": r["5.3 - student"], "ci95": r["ci95"]}, 2),
               "median of differences": "-"} for r in man_rows]
    write_table(table, ["W", "contrast", "quantity", "mean [95 % CI]", "median of differences"],
                args.out / "contrasts", "Thesis 5.3: paired contrasts on the test episodes (two-level bootstrap)")
    cols = ["Controller", "RL reward", "Initial cost", "Rollout cost (state)", "Survival"]
    cell_rows = [{**c.row, "RL reward": med(results[c.name].get("rl_reward"), 3),
                  "Initial cost": med(results[c.name].get("initial_cost")),
                  "Rollout cost (state)": med(results[c.name].get("rollout_cost")),
                  "Survival": survival(results[c.name])} if "skipped" not in results[c.name] else
                 {**c.row, "RL reward": f"skipped: {results[c.name]['skipped']}"} for c in todo if c.name in results]
    finish(args, todo, results, cell_rows, cols, "Thesis 5.3 evaluation (first-spline, M = 10 000, H = 10, F only)",
           figure, "initial_cost.png")
    print((args.out / "contrasts.md").read_text())


if __name__ == "__main__":
    run_cli(main)

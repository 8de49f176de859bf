"""Seeds of the base expert, and what made the retrained base less robust (plan: docs/experiments/expert_seeds_plan.md).

    python -m experiments.expert_seeds eval --runs /work/seedruns --out docs/experiments/expert_seeds
    python -m experiments.expert_seeds report --out docs/experiments/expert_seeds

``eval`` chooses the checkpoint of each new default-recipe run on validation episodes (``eval.select --every 100
--episodes 64``, as seed 0's was) and evaluates every policy of the plan on its episode sets, one JSON per policy and
set under ``<out>/<policy>/<set>/``; a JSON already there is kept, so an interrupted ``eval`` continues. ``--only``
restricts it to some policies (a run still training is left for later). The policies (``--runs`` holds the training
runs, which are not committed):

- ``D<s>_sel``: the default recipe, seed s, the checkpoint chosen on validation (seed 0: ``base_recipe_actor.pt2``);
- ``D<s>_450``: the same run at iteration 450 (seed 0: ``base_recipe_s0_450``, the committed run continued from its
  iteration-380 resume point);
- ``T<s>_450``: Table 6's recipe (``--task base_thesis``), seed s, 450 iterations (its last checkpoint,
  ``model_449.pt``: the iterations are numbered from 0; one update fewer than ``model_450.pt`` of the D runs);
- ``base_actor``: the committed ``base_actor.pt`` (Table 6, seed 0, 450 iterations, older code).

``report`` reads those JSONs and writes ``results.json`` and ``table.md``: every policy's outcomes, and the plan's
contrasts (seed spread, budget, recipe, code, the drop's path at seed 0, the validation choice of the recipe, Fig. 17
per seed), each a paired difference over the same episodes with the plan's label. Pooled contrasts stack the three
seeds as rows of one (seeds x episodes) array and resample seeds and episodes together
(``eval.metrics.paired_difference(paired_seeds=True)``).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from dls_quadruped.cli import ArgumentParser, UserError, run_cli
from dls_quadruped.core.json_io import write_json
from dls_quadruped.eval.compare import per_episode_values
from dls_quadruped.eval.metrics import paired_difference
from dls_quadruped.eval.provenance import provenance
from experiments.gait_control import label

REPO = Path(__file__).resolve().parents[1]
POLICY_DIR = REPO / "docs" / "policies"
SEEDS = (0, 1, 2)
SETS = {"test_simple": ("simple", "test", 512), "test_sweep": ("survival_sweep", "test", 288),
        "val_simple": ("simple", "validation", 64), "val_sweep": ("survival_sweep", "validation", 96)}
"""Episode sets: name -> (scenario, split, episodes); seed 0 throughout (Fig. 17's and Fig. 18b's medium episodes)."""
OUTCOMES = {"reward": ("reward per step", "test_simple", 0.02, 3),
            "survived": ("survival (sweep)", "test_sweep", 0.10, 3)}
"""Test outcomes: key -> (label, episode set, margin, digits)."""
VALIDATION_MARGINS = {"reward": ("val_simple", 0.02), "survived": ("val_sweep", 0.05)}
"""Question 3 (the default recipe) on validation episodes: key -> (episode set, margin)."""
FIG17 = REPO / "docs" / "experiments" / "retrained" / "fig17_medium_recipe"
SELECT_EVERY, SELECT_EPISODES = 100, 64


def policy_names() -> list[str]:
    return [f"D{s}_sel" for s in SEEDS] + [f"D{s}_450" for s in SEEDS] + [f"T{s}_450" for s in SEEDS] + ["base_actor"]


def sets_of(name: str) -> list[str]:
    """The episode sets the plan evaluates ``name`` on: the test sets for all, validation for the 450 ones."""
    return list(SETS) if name.endswith("_450") else ["test_simple", "test_sweep"]


def selection_dir(out: Path, seed: int) -> Path:
    return out / "selection" / f"D{seed}"


def policy_file(name: str, runs: Path, out: Path) -> Path:
    """The file ``eval`` plays for ``name`` (a committed policy or a run's checkpoint)."""
    if name == "base_actor":
        return POLICY_DIR / "base_actor.pt"
    if name == "D0_sel":
        return POLICY_DIR / "base_recipe_actor.pt2"
    kind, seed, which = name[0], int(name[1]), name.split("_", 1)[1]
    if which == "450":
        if kind == "T":  # a 450-iteration run numbers its iterations 0-449: its last checkpoint, 450 updates
            return runs / f"base_thesis_s{seed}" / "model_449.pt"
        run = runs / ("base_recipe_s0_450" if name == "D0_450" else f"base_recipe_s{seed}")
        return run / "model_450.pt"
    selection = selection_dir(out, seed) / "selection.json"
    if not selection.is_file():
        raise UserError(f"{name}: no checkpoint chosen yet ({selection} missing; `eval` writes it)")
    chosen = json.loads(selection.read_text())["chosen"]
    return runs / f"base_recipe_s{seed}" / Path(chosen["checkpoint"]).name


def select(runs: Path, out: Path, seed: int, num_workers: int) -> dict:
    from dls_quadruped.eval import select as eval_select

    run = runs / f"base_recipe_s{seed}"
    if not any((run / f"model_{it}.pt").is_file() for it in (999, 1000)):  # 1 000 iterations, numbered from 0
        raise UserError(f"{run}: the run has not finished its 1 000 iterations (model_999.pt missing)")
    return eval_select.main([str(run), "--scenario", "simple", "--every", str(SELECT_EVERY), "--episodes",
                             str(SELECT_EPISODES), "--num-workers", str(num_workers), "--out",
                             str(selection_dir(out, seed))])


def evaluate(runs: Path, out: Path, only: list[str] | None, num_workers: int) -> None:
    from dls_quadruped.eval.__main__ import main as eval_main

    for name in only or policy_names():
        if name.endswith("_sel") and name != "D0_sel":
            select(runs, out, int(name[1]), num_workers)
        policy = policy_file(name, runs, out)
        if not policy.is_file():
            raise UserError(f"{name}: {policy} not found")
        for set_name in sets_of(name):
            scenario, split, episodes = SETS[set_name]
            dest = out / name / set_name
            if (dest / f"{scenario}.json").is_file():
                continue
            eval_main(["--policy", str(policy), "--scenario", scenario, "--split", split, "--episodes", str(episodes),
                       "--seed", "0", "--num-workers", str(num_workers), "--out", str(dest)])


def load(out: Path) -> dict[str, dict[str, dict]]:
    """{policy: {set: eval JSON}} for every JSON ``eval`` wrote."""
    res: dict[str, dict[str, dict]] = {}
    for name in policy_names():
        for set_name, (scenario, _, _) in SETS.items():
            f = out / name / set_name / f"{scenario}.json"
            if f.is_file():
                res.setdefault(name, {})[set_name] = json.loads(f.read_text())
    return res


def values(res: dict, name: str, key: str, set_name: str) -> np.ndarray | None:
    r = res.get(name, {}).get(set_name)
    return None if r is None else per_episode_values(r, key)


def contrast(res: dict, a: list[str], b: list[str], key: str, set_name: str, margin: float) -> dict | None:
    """mean over rows and episodes of a - b (rows: the policies of ``a`` and ``b`` pairwise, e.g. three seeds),
    rows and episodes resampled together; None where a policy lacks the set."""
    va = [values(res, n, key, set_name) for n in a]
    vb = [values(res, n, key, set_name) for n in b]
    if any(v is None for v in va + vb):
        return None
    d = paired_difference(np.stack(va), np.stack(vb), paired_seeds=True)
    return {"a": a, "b": b, "mean": d["mean"], "ci95": d["ci95"], "episodes": d["episodes"],
            "label": label(d["ci95"], margin)}


def contrasts(res: dict) -> list[dict]:
    """Every contrast of the plan on the test sets, one row per (contrast, outcome)."""
    plan: list[tuple[str, list[str], list[str]]] = []
    plan += [(f"seed spread: D{s} - D0, chosen", [f"D{s}_sel"], ["D0_sel"]) for s in SEEDS[1:]]
    plan += [("budget: chosen - 450, pooled", [f"D{s}_sel" for s in SEEDS], [f"D{s}_450" for s in SEEDS])]
    plan += [(f"budget, seed {s}", [f"D{s}_sel"], [f"D{s}_450"]) for s in SEEDS]
    plan += [("recipe: default - Table 6 at 450, pooled", [f"D{s}_450" for s in SEEDS], [f"T{s}_450" for s in SEEDS])]
    plan += [(f"recipe, seed {s}", [f"D{s}_450"], [f"T{s}_450"]) for s in SEEDS]
    plan += [("Table 6 seed spread at 450: T1 - T0", ["T1_450"], ["T0_450"]),
             ("Table 6 seed spread at 450: T2 - T0", ["T2_450"], ["T0_450"])]
    plan += [("code: T0 at 450 (today) - base_actor.pt", ["T0_450"], ["base_actor"]),
             ("the drop: base_recipe_actor.pt2 - base_actor.pt", ["D0_sel"], ["base_actor"])]
    rows = []
    for title, a, b in plan:
        for key, (outcome, set_name, margin, _) in OUTCOMES.items():
            c = contrast(res, a, b, key, set_name, margin)
            if c is not None:
                rows.append({"contrast": title, "outcome": outcome, **c})
    return rows


def recipe_choice(res: dict) -> dict | None:
    """Question 3: default - Table 6 at 450 on validation episodes, pooled, and the plan's decision."""
    a, b = [f"D{s}_450" for s in SEEDS], [f"T{s}_450" for s in SEEDS]
    parts = {key: contrast(res, a, b, key, set_name, margin) for key, (set_name, margin) in
             VALIDATION_MARGINS.items()}
    if any(c is None for c in parts.values()):
        return None
    return {**parts, "decision": decide({k: (c["ci95"], VALIDATION_MARGINS[k][1]) for k, c in parts.items()})}


def decide(intervals: dict[str, tuple[list[float], float]]) -> str:
    """The plan's rule on default - Table 6 intervals {outcome: (ci95, margin)}."""
    if all(ci[0] > -m for ci, m in intervals.values()):
        return "the default stays: not worse on either outcome beyond its margin"
    for k, (ci, _) in intervals.items():
        others = [c for o, (c, _) in intervals.items() if o != k]
        if ci[1] < 0 and all(c[0] <= 0 for c in others):
            return f"Table 6 becomes the default: better on {k}, the default not better on the other"
    return "the default stays; trade-off (each better on one outcome, or inconclusive), stated in docs/train.md"


def fig17_rows(res: dict, fig17: Path = FIG17) -> list[dict]:
    """Each base seed against the committed retrained rough, speed and climb on Fig. 17's episodes: base / X - 1."""
    rows = []
    for s in SEEDS:
        mine = res.get(f"D{s}_sel", {}).get("test_simple")
        if mine is None:
            continue
        for task in ("rough", "speed", "climb"):
            f = fig17 / task / "simple.json"
            if not f.is_file():
                continue
            other = json.loads(f.read_text())
            if other["per_episode"]["command"] != mine["per_episode"]["command"]:
                raise UserError(f"{f}: not Fig. 17's episodes of D{s}_sel (the commands differ)")
            d = paired_difference(per_episode_values(mine, "reward"), per_episode_values(other, "reward"))
            # base / X - 1 = relative of base - X against X; its interval from the same resamples
            rel_ci = d["relative_ci95"]
            rows.append({"seed": s, "versus": task, "base - X": d["mean"], "ci95": d["ci95"],
                         "relative": d["relative"], "relative_ci95": rel_ci,
                         "holds": bool(d["ci95"][0] > 0 and rel_ci[1] < 0.20)})
    return rows


def outcome_rows(res: dict) -> list[dict]:
    rows = []
    for name in policy_names():
        r = res.get(name, {})
        simple, sweep = r.get("test_simple"), r.get("test_sweep")
        row = {"policy": name}
        if simple is not None:
            rw = per_episode_values(simple, "reward")
            row["reward per step"] = float(np.nanmean(rw))
            for axis in ("v_x", "v_y", "omega_z"):
                row[f"slope {axis}"] = simple["axes"][axis]["slope"]
            row["simple survival"] = float(np.mean(per_episode_values(simple, "survived")))
        if sweep is not None:
            row["sweep survival"] = float(np.mean(per_episode_values(sweep, "survived")))
        for set_name in ("val_simple", "val_sweep"):
            if set_name in r:
                key = "reward" if set_name == "val_simple" else "survived"
                row[f"{set_name} {key}"] = float(np.nanmean(per_episode_values(r[set_name], key)))
        rows.append(row)
    return rows


def _fmt(v: object, digits: int = 3) -> str:
    return f"{v:.{digits}f}" if isinstance(v, float) else str(v)


def report(out: Path, fig17: Path = FIG17) -> dict:
    res = load(out)
    if not res:
        raise UserError(f"{out}: no evaluation yet (run `python -m experiments.expert_seeds eval` first)")
    summary = {"outcomes": outcome_rows(res), "contrasts": contrasts(res), "recipe_choice": recipe_choice(res),
               "fig17": fig17_rows(res, fig17),
               "policies": {n: {s: r[s].get("policy") for s in r} for n, r in res.items()},
               **provenance()}
    write_json(summary, out / "results.json", indent=1)
    lines = ["**Outcomes** (test episodes; simple: 512, survival sweep: 288)", ""]
    cols = ["policy", "reward per step", "slope v_x", "slope v_y", "slope omega_z", "sweep survival",
            "val_simple reward", "val_sweep survived"]
    lines += _md(cols, [[_fmt(r.get(c, "-")) for c in cols] for r in summary["outcomes"]])
    lines += ["", "**Contrasts** (mean over episodes [95 % CI]; label by the plan's margins)", ""]
    lines += _md(["contrast", "outcome", "mean [95 % CI]", "label"],
                 [[c["contrast"], c["outcome"], f"{c['mean']:+.3f} [{c['ci95'][0]:+.3f}, {c['ci95'][1]:+.3f}]",
                   c["label"]] for c in summary["contrasts"]])
    choice = summary["recipe_choice"]
    if choice is not None:
        lines += ["", "**The default recipe** (validation, default - Table 6 at 450, pooled): "
                  + "; ".join(f"{k} {c['mean']:+.3f} [{c['ci95'][0]:+.3f}, {c['ci95'][1]:+.3f}]"
                              for k, c in choice.items() if k != "decision") + f" -> {choice['decision']}"]
    if summary["fig17"]:
        lines += ["", "**Fig. 17 per seed** (base - X on Fig. 17's episodes)", ""]
        lines += _md(["seed", "versus", "base - X [95 % CI]", "base / X - 1 [95 % CI]", "first, < +20 %"],
                     [[str(r["seed"]), r["versus"], f"{r['base - X']:+.4f} [{r['ci95'][0]:+.4f}, {r['ci95'][1]:+.4f}]",
                       _pct(r["relative"], r["relative_ci95"]), "yes" if r["holds"] else "no"]
                      for r in summary["fig17"]])
    (out / "table.md").write_text("\n".join(lines) + "\n", encoding="utf-8")
    print("\n".join(lines))
    return summary


def _pct(v: float, ci: list[float]) -> str:
    return f"{100 * v:+.1f} % [{100 * ci[0]:+.1f}, {100 * ci[1]:+.1f}]"


def _md(cols: list[str], rows: list[list[str]]) -> list[str]:
    return ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)] + ["| " + " | ".join(r) + " |" for r in rows]


def main(argv: list[str] | None = None) -> dict | None:
    p = ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("command", choices=("eval", "report"))
    p.add_argument("--runs", type=Path, default=Path("runs/expert_seeds"),
                   help="the training runs: base_recipe_s1, base_recipe_s2, base_recipe_s0_450, base_thesis_s{0,1,2}")
    p.add_argument("--out", type=Path, default=Path("results/experiments/expert_seeds"))
    p.add_argument("--only", nargs="+", choices=policy_names(), default=None, metavar="POLICY",
                   help=f"evaluate only these ({', '.join(policy_names())})")
    p.add_argument("--num-workers", type=int, default=0, help="simulator worker processes per evaluation (0)")
    args = p.parse_args(argv)
    if args.command == "eval":
        evaluate(args.runs, args.out, args.only, args.num_workers)
        return None
    return report(args.out)


if __name__ == "__main__":
    run_cli(main)

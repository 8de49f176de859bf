"""PPO recipe ablation at one fixed budget: which change makes the exploration std fall (docs/train.md "Recipe").

    python -m experiments.recipe_ablation run  --variants thesis ent0 --seeds 0 1 --iterations 200 --num-envs 256
    python -m experiments.recipe_ablation eval --every 50 --episodes 64       # validation reward of the checkpoints
    python -m experiments.recipe_ablation report --iterations 200   # every run over its first 200 iterations

Variants are the task files in ``experiments/recipe_ablation/`` (each inherits ``tasks/base_thesis.yaml``, Table 6, and
changes one thing; ``ent0_std05`` and ``ent0_log05`` start from the default, no entropy bonus, and lower the
initial std). ``run`` trains every (variant, seed) in ``runs/recipe_ablation/<variant>_s<seed>``
one after the other and is resumable: a finished run is skipped, an interrupted one continues from its
newest checkpoint (``train --resume``). Start two ``run`` processes with disjoint variant lists to use two
cores. ``eval`` scores every ``--every``-th checkpoint on the **validation** episodes of the simple task
(``python -m dls_quadruped.eval.select``: ``eval --split validation``, disjoint from the test episodes every
report uses). ``report`` writes the
learning-curve CSVs, a summary table (JSON + Markdown) and one plot.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from dls_quadruped.cli import ArgumentParser

ROOT = Path(__file__).resolve().parents[1]
VARIANT_DIR = ROOT / "experiments" / "recipe_ablation"
RUNS = ROOT / "runs" / "recipe_ablation"


def variants() -> list[str]:
    return sorted(p.stem for p in VARIANT_DIR.glob("*.yaml"))


def run_dir(variant: str, seed: int) -> Path:
    return RUNS / f"{variant}_s{seed}"


def checkpoints(run: Path) -> dict[int, Path]:
    out = {}
    for p in run.glob("model_*.pt"):
        try:
            out[int(p.stem.split("_")[1])] = p
        except ValueError:
            continue
    return dict(sorted(out.items()))


def _python(args: list[str], threads: int) -> None:
    env = dict(os.environ, OMP_NUM_THREADS=str(threads), OMP_WAIT_POLICY="PASSIVE")
    print("+", " ".join(args), flush=True)
    subprocess.run([sys.executable, *args], cwd=ROOT, env=env, check=True)


def cmd_run(a: argparse.Namespace) -> None:
    jobs = [j.split(":") for j in a.jobs] if a.jobs else [(v, s) for s in a.seeds for v in a.variants]
    for variant, _ in jobs:
        if variant not in variants():
            raise SystemExit(f"unknown variant {variant!r}; allowed: {variants()}")
    for variant, seed in jobs:
        if True:
            run = run_dir(variant, int(seed))
            done = max(checkpoints(run), default=-1)
            if done >= a.iterations - 1:
                print(f"{run.name}: done ({done + 1} iterations)", flush=True)
                continue
            args = ["-m", "dls_quadruped.learning.train", "--task", str(VARIANT_DIR / f"{variant}.yaml"),
                    "--num-envs", str(a.num_envs), "--device", "cpu", "--seed", str(seed), "--num-workers", "0",
                    "--run-dir", str(run), "--save-interval", str(a.save_interval), "--update-threads", "0"]
            if done >= 0:
                args += ["--resume", "--iterations", str(a.iterations - 1 - done)]
            else:
                args += ["--iterations", str(a.iterations)]
            _python(args, a.threads)


def cmd_eval(a: argparse.Namespace) -> None:
    for run in sorted(RUNS.glob("*_s*")):
        if checkpoints(run):
            _python(["-m", "dls_quadruped.eval.select", str(run), "--scenario", "simple", "--every", str(a.every),
                     "--episodes", str(a.episodes), "--num-workers", "0"], a.threads)


def _curve(run: Path, csv: Path) -> dict[str, np.ndarray]:
    if not csv.is_file() or csv.stat().st_mtime < max(p.stat().st_mtime for p in run.glob("events.*")):
        png = run / "learning_curve.png"  # per-run plot beside the run; the report keeps one combined plot
        _python(["-m", "dls_quadruped.viz.learning_curve", str(run), "--csv", str(csv), "--png", str(png)], 1)
    rows = np.genfromtxt(csv, delimiter=",", names=True)
    return {name: rows[name] for name in rows.dtype.names}


def _evaluations(run: Path, upto: int | None = None) -> dict[int, dict]:
    """{iteration: ``eval.select``'s evaluation on the validation episodes}, at or before ``upto``, in order."""
    out = {}
    for res in (run / "selection" / "simple").glob("model_*.json"):
        it = int(res.stem.split("_")[1])
        if upto is None or it <= upto:
            out[it] = json.loads(res.read_text())
    return dict(sorted(out.items()))


def _validation(run: Path, upto: int | None = None) -> dict[int, float]:
    """{iteration: reward per step on the validation episodes}."""
    return {it: float(res["reward"]["per_step"]) for it, res in _evaluations(run, upto).items()}


def end_episodes(run: Path, upto: int) -> tuple[int, np.ndarray] | None:
    """The newest validated checkpoint at or before iteration ``upto``: (iteration, per-episode reward per step)."""
    evaluations = _evaluations(run, upto)
    if not evaluations:
        return None
    it = max(evaluations)
    return it, np.asarray(evaluations[it]["per_episode"]["reward"], dtype=float)


def paired_against(ends: dict[str, dict[int, np.ndarray]], baseline: str) -> list[dict]:
    """Each variant minus ``baseline`` on the same validation episodes, reward per step at the end of the budget.

    ``ends[variant][seed]`` is one run's per-episode values. The training seeds of a variant are its units (S, E);
    they are resampled independently of the baseline's (two runs with the same seed number share nothing but the
    seed), the episodes together (``eval.metrics.paired_difference``). Per seed as well: the difference on that
    seed's episodes alone (the seed's run against the baseline's run with the same seed)."""
    from dls_quadruped.eval.metrics import paired_difference

    base = ends.get(baseline, {})
    out = []
    for variant in sorted(ends):
        if variant == baseline or not ends[variant] or not base:
            continue
        seeds = sorted(ends[variant])
        a = np.stack([ends[variant][s] for s in seeds])
        b = np.stack([base[s] for s in sorted(base)])
        d = paired_difference(a, b)
        per_seed = {s: paired_difference(ends[variant][s], base[s]) for s in seeds if s in base}
        out.append({"variant": variant, "baseline": baseline, "seeds": seeds, "mean": d["mean"], "ci95": d["ci95"],
                    "per_seed": {s: {"mean": v["mean"], "ci95": v["ci95"]} for s, v in per_seed.items()}})
    return out


def cmd_report(a: argparse.Namespace) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    a.out.mkdir(parents=True, exist_ok=True)
    rows, curves, ends = [], {}, {}
    for run in sorted(RUNS.glob("*_s*")):
        if not list(run.glob("events.*")):
            continue
        c = _curve(run, a.out / f"{run.name}.csv")
        c = {k: v[: a.iterations] for k, v in c.items()}  # every run at the same budget, however long it went on
        curves[run.name] = c
        n = len(c["iteration"])
        last = slice(max(0, n - max(1, n // 4)), n)
        ret = c["mean_reward"]
        best = float(np.nanmax(ret))
        std_cols = {g: c.get(f"std_{g}") for g in ("f", "d", "p", "F")}
        rows.append({
            "run": run.name, "variant": run.name.rsplit("_s", 1)[0], "seed": int(run.name.rsplit("_s", 1)[1]),
            "iterations": n, "samples": int(c.get("samples", np.array([0]))[-1]) if "samples" in c else None,
            "return_best": best, "return_last_quarter": float(np.nanmean(ret[last])),
            "drop_below_best": float(1.0 - np.nanmin(ret[last]) / best) if best > 0 else None,
            "std_start": float(c["action_std"][0]), "std_end": float(c["action_std"][-1]),
            **{f"std_{g}_end": float(v[-1]) for g, v in std_cols.items() if v is not None},
            "lr_end": float(c["learning_rate"][-1]) if "learning_rate" in c else None,
            "kl_mean_last_quarter": float(np.nanmean(c["kl_mean"][last])) if "kl_mean" in c else None,
            "s_per_iteration": float(np.nanmedian(c["collection_s"] + c["learning_s"])),
            "validation": _validation(run, a.iterations),
        })
        end = end_episodes(run, a.iterations)
        if end is not None:
            ends.setdefault(rows[-1]["variant"], {})[rows[-1]["seed"]] = end[1]
    paired = paired_against(ends, a.baseline)
    (a.out / "summary.json").write_text(json.dumps(rows, indent=1) + "\n")
    (a.out / "paired.json").write_text(json.dumps(paired, indent=1) + "\n")
    lines = [("| run | it | return best | return last ¼ | std start → end | std f / d / p / F at end | lr end | "
             "validation reward/step (checkpoint: value) | s/it |"), "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        val = ", ".join(f"{k}: {v:.3f}" for k, v in r["validation"].items()) or "-"
        groups = " / ".join(f"{r.get(f'std_{g}_end', float('nan')):.2f}" for g in ("f", "d", "p", "F"))
        lines.append(f"| {r['run']} | {r['iterations']} | {r['return_best']:.2f} | {r['return_last_quarter']:.2f} | "
                     f"{r['std_start']:.2f} → {r['std_end']:.2f} | {groups} | "
                     f"{r['lr_end'] if r['lr_end'] is None else format(r['lr_end'], '.1e')} | {val} | "
                     f"{r['s_per_iteration']:.1f} |")
    lines += ["", (f"Validation reward per step at the last validated checkpoint <= {a.iterations}, variant - "
                   f"{a.baseline} on the same episodes (both seeds: seeds resampled; per seed: that seed's runs):"), "",
              "| variant | both seeds | " + " | ".join(f"seed {s}" for s in a.seeds) + " |",
              "|---|---|" + "---|" * len(a.seeds)]
    for d in paired:
        cell = lambda v: f"{v['mean']:+.3f} [{v['ci95'][0]:+.3f}, {v['ci95'][1]:+.3f}]"
        lines.append(f"| {d['variant']} | {cell(d)} | "
                     + " | ".join(cell(d["per_seed"][s]) if s in d["per_seed"] else "-" for s in a.seeds) + " |")
    (a.out / "summary.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))

    fig, axes = plt.subplots(1, 3, figsize=(15, 4))
    names = sorted({r["variant"] for r in rows})
    colours = {v: plt.cm.tab10(i) for i, v in enumerate(names)}
    for name, c in curves.items():
        variant, seed = name.rsplit("_s", 1)
        style = "-" if seed == "0" else "--"
        label = variant if seed == "0" else None
        axes[0].plot(c["iteration"], c["mean_reward"], style, color=colours[variant], label=label)
        axes[1].plot(c["iteration"], c["action_std"], style, color=colours[variant], label=label)
        if "learning_rate" in c:
            axes[2].semilogy(c["iteration"], c["learning_rate"], style, color=colours[variant], label=label)
    for ax, title in zip(axes, ("training return (mean episode reward)", "mean action std (raw units)",
                                "learning rate (adaptive schedule)")):
        ax.set_title(title)
        ax.set_xlabel("iteration")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle("base, 256 robots x 24 steps per iteration; solid: seed 0, dashed: seed 1")
    fig.tight_layout()
    fig.savefig(a.out / "recipe_ablation.png", dpi=110)


def main(argv: list[str] | None = None) -> None:
    p = ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("cmd", choices=("run", "eval", "report"), help="train the runs, score their checkpoints, or report")
    p.add_argument("--variants", nargs="+", default=None, help="run: variants (default: every file)")
    p.add_argument("--seeds", nargs="+", type=int, default=[0, 1], help="run: seeds")
    p.add_argument("--jobs", nargs="+", default=None, metavar="VARIANT:SEED", help="run: instead of variants x seeds")
    p.add_argument("--iterations", type=int, default=200,
                   help="run: PPO iterations per run; report: compare every run over its first N iterations")
    p.add_argument("--baseline", default="ent0", help="report: the variant every other is paired against")
    p.add_argument("--num-envs", type=int, default=256, help="run: robots")
    p.add_argument("--save-interval", type=int, default=25, help="run: checkpoint every K iterations")
    p.add_argument("--threads", type=int, default=1, help="torch threads per process")
    p.add_argument("--every", type=int, default=50, help="eval: score checkpoints whose iteration is a multiple")
    p.add_argument("--episodes", type=int, default=64, help="eval: validation episodes")
    p.add_argument("--out", type=Path, default=ROOT / "docs" / "train" / "recipe_ablation", help="report: folder")
    a = p.parse_args(argv)
    if a.baseline not in variants():
        p.error(f"argument --baseline: unknown variant {a.baseline!r}; allowed: {variants()}")
    if a.iterations < 1:
        p.error(f"argument --iterations: must be >= 1, got {a.iterations}")
    if a.cmd == "run":
        a.variants = a.variants or variants()
    {"run": cmd_run, "eval": cmd_eval, "report": cmd_report}[a.cmd](a)


if __name__ == "__main__":
    main()

"""Shared machinery of the RL-policy experiments (thesis 7.1: Figs. 17-23).

Every figure runs one evaluation scenario (``dls_quadruped.eval.scenarios``) for each of the four
experts, found by task name as ``docs/policies/<task>_actor.pt`` (``--policy-dir``; ``--variant recipe``:
the experts retrained with the default recipe, ``<task>_recipe_actor.pt2``); a missing policy is skipped
with a printed note. Per policy, the scenario's own JSON + PNG go to
``<out>/<task>/<scenario>.{json,png}`` (a result whose policy file has not changed, same sha256,
scale and seed, is not evaluated again); the script then writes ``results.json`` (every policy's
result without its per-episode lists), ``table.csv`` / ``table.md``, ``paired.md`` / ``paired.csv`` (each
expert minus base on the same scheduled episodes: survival, reward, episode length, CoT where the
scenario records them per episode, with 95 % intervals) (our numbers beside the
thesis's words), the comparison figure and ``config.json`` (scale, episodes, git commit,
uncommitted files, policy paths and sha256, what was skipped). Default ``--out``:
``results/experiments/<script>``; the small-scale files are copied to ``docs/experiments/<script>/``.

Scales (``--scale``): ``small`` is each scenario's default size (``Scenario.default_episodes``:
one policy in one to two minutes on two cores); ``medium`` three times as many (``MEDIUM_EPISODES``);
``thesis`` approaches the thesis's 50 000
trajectories per evaluation within one batched env (4096 episodes for simple and survival,
512 per condition for the sweeps, 128 per cell for omni: 3-6 M env steps per policy and
scenario); it was not run.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import resource
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from dls_quadruped.cli import ArgumentParser
from dls_quadruped.core.json_io import write_json
from dls_quadruped.eval.compare import paired_vs
from dls_quadruped.eval.provenance import provenance
from dls_quadruped.eval.scenario import EvalOptions
from dls_quadruped.eval.scenarios import SCENARIOS
from experiments.output import write_table

REPO = Path(__file__).resolve().parents[1]
TASKS = ("base", "rough", "speed", "climb")
"""The four RL experts of thesis 7.1, in the thesis's order."""
POLICY_DIR = REPO / "docs" / "policies"
VARIANTS = {"thesis": ("{task}_actor.pt", "{task}_student_first_spline_h10.pt"),
            "recipe": ("{task}_recipe_actor.pt2", "{task}_recipe_student_first_spline_h10.pt2")}
"""Which committed experts and students (docs/policies/README.md): ``thesis`` = trained with Table 6's PPO
settings (the files every experiment used first), ``recipe`` = retrained with the default recipe (docs/train.md)
and the students distilled from those."""


def expert_file(policy_dir: Path, task: str, variant: str = "thesis") -> Path:
    """The committed expert of ``task`` in ``variant`` (see ``VARIANTS``)."""
    return Path(policy_dir) / VARIANTS[variant][0].format(task=task)


def student_file(policy_dir: Path, task: str, variant: str = "thesis") -> Path:
    """The committed first-spline H = 10 student of ``task``'s expert in ``variant``."""
    return Path(policy_dir) / VARIANTS[variant][1].format(task=task)


@dataclass(frozen=True)
class Policies:
    """A folder of committed experts and students and the variant to take from it."""

    folder: Path
    variant: str = "thesis"

    def expert(self, task: str) -> Path:
        return expert_file(self.folder, task, self.variant)

    def student(self, task: str) -> Path:
        return student_file(self.folder, task, self.variant)
THESIS_EPISODES = {"simple": 4096, "survival": 4096, "survival_sweep": 4096, "stairs": 512, "speed": 512, "omni": 128,
                   "cot": 512, "gait": 512}
MEDIUM_EPISODES = {"simple": 512, "survival": 288, "survival_sweep": 288, "stairs": 36, "speed": 48, "omni": 9,
                   "cot": 24, "gait": 24}
"""Three times the small defaults (twice for simple): 1.5-3 min per policy and scenario at load ~3."""
SCALES: dict[str, dict] = {
    "small": {"episodes": {}, "episode_length_s": None},   # {}: each scenario's default_episodes
    "medium": {"episodes": MEDIUM_EPISODES, "episode_length_s": None},
    "thesis": {"episodes": THESIS_EPISODES, "episode_length_s": None},
}


def parse_args(description: str, name: str, tasks: tuple[str, ...] = TASKS, argv: list[str] | None = None):
    p = ArgumentParser(description=description, formatter_class=argparse.RawDescriptionHelpFormatter)  # one-line errors
    p.add_argument("--scale", choices=sorted(SCALES), default="small")
    p.add_argument("--out", type=Path, default=REPO / "results" / "experiments" / name)
    p.add_argument("--policy-dir", type=Path, default=POLICY_DIR, help="folder of <task>_actor.pt")
    p.add_argument("--variant", choices=sorted(VARIANTS), default="thesis",
                   help="thesis: the experts trained with Table 6 (<task>_actor.pt); recipe: those retrained with the "
                        "default recipe (<task>_recipe_actor.pt2)")
    p.add_argument("--tasks", nargs="*", default=list(tasks), choices=TASKS, help="policies to compare")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--num-workers", type=int, default=-1)
    return p.parse_args(argv)


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def cpu_seconds() -> float:
    """User + system CPU time of this process and of its waited-for children (simulator workers) [s]."""
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def episodes_of(scenario: str, scale: str) -> int:
    return SCALES[scale]["episodes"].get(scenario, SCENARIOS[scenario].default_episodes)


def evaluate_policies(scenario: str, args: argparse.Namespace) -> tuple[dict[str, dict], dict]:
    """Run ``scenario`` for every available policy of ``args.tasks``.

    Returns:
        ({task: the scenario's result}, {"policies": {task: {path, sha256}}, "skipped": {task: why}}).
    """
    sc = SCENARIOS[scenario]
    episodes = episodes_of(scenario, args.scale)
    length = SCALES[args.scale]["episode_length_s"]
    results, info = {}, {"policies": {}, "skipped": {}}
    for task in args.tasks:
        path = expert_file(args.policy_dir, task, getattr(args, "variant", "thesis"))
        if not path.is_file():
            note = f"{path} not found (not trained yet?): skipped"
            print(f"[{scenario}] {task}: {note}", flush=True)
            info["skipped"][task] = note
            continue
        digest = sha256(path)
        info["policies"][task] = {"path": str(path), "sha256": digest}
        out = args.out / task
        done = out / f"{scenario}.json"
        key = {"sha256": digest, "scale": args.scale, "episodes": episodes, "seed": args.seed,
               "episode_length_s": length, "protocol": PROTOCOL}
        if done.is_file():
            old = json.loads(done.read_text())
            if old.get("experiment_key") == key:
                print(f"[{scenario}] {task}: {done} is up to date, not evaluated again", flush=True)
                results[task] = old
                continue
        t0, cpu0 = time.perf_counter(), cpu_seconds()
        res = sc.evaluate(path, EvalOptions(episodes=episodes, seed=args.seed, num_workers=args.num_workers,
                                            episode_length_s=length))
        res["wall_s"] = round(time.perf_counter() - t0, 1)
        res["cpu_s"] = round(cpu_seconds() - cpu0, 1)  # this process + its finished simulator workers
        res["load_avg_1min_end"] = round(os.getloadavg()[0], 2)
        res["experiment_key"] = key
        res.update(provenance())  # of this evaluation (config.json's is of the table)
        out.mkdir(parents=True, exist_ok=True)
        write_json(res, done, indent=1)
        sc.plot(res, out / f"{scenario}.png")
        print(sc.summary(res) if sc.summary else f"[{scenario}] {task} done", flush=True)
        results[task] = json.loads(done.read_text())  # what was written (strict JSON: NaN -> null)
    return results, info


def without_episodes(res: dict) -> dict:
    """A result without its per-episode lists (for the small results.json)."""
    return {k: v for k, v in res.items() if k not in ("per_episode", "diagrams", "events")}


PROTOCOL = "episode-schedule-1+spawn-1"
"""Evaluation protocol of a cached result: results from before the episode schedule (envs/schedule.py),
whose pushes and noise after a fall depended on the other robots, and from before the reset placed every
foot above the terrain (events.spawn_height; it changed the rough-terrain scenarios' starts), are evaluated
again."""



def finish(name: str, scenario: str, args: argparse.Namespace, results: dict, info: dict, rows: list[dict],
           columns: list[str], title: str, figure: Callable[[dict, Path], None], figure_name: str) -> None:
    """Write table, results, figure and config of one experiment."""
    args.out.mkdir(parents=True, exist_ok=True)
    write_table(rows, columns, args.out / "table", title)
    paired = paired_vs(results)
    if paired:
        write_table(paired, list(paired[0]), args.out / "paired",
                    f"{title}: paired differences on the same episodes (mean over episodes [95 % CI])")
    write_json({"scenario": scenario, "rows": rows, "paired_vs_base": paired, **provenance(),
                "results": {t: without_episodes(r) for t, r in results.items()}}, args.out / "results.json")
    if results:
        figure(results, args.out / figure_name)
    write_json({"experiment": name, "scenario": scenario, "scale": args.scale, "scale_settings": SCALES[args.scale],
                "episodes_per_condition": episodes_of(scenario, args.scale), "seed": args.seed,
                **provenance(), **info}, args.out / "config.json")
    print(f"[{name}] wrote {args.out}/table.md, results.json, {figure_name}, config.json", flush=True)


def num(x, fmt: str = ".3f") -> str:
    """A number or '-' for a missing one (null in strict JSON)."""
    return "-" if x is None else format(x, fmt)


def rate_cell(b: dict) -> str:
    """'97.5 % [93.1, 99.2] (n = 128)' of a binomial result; '-' without episodes."""
    if not b or not b.get("n") or b.get("rate") is None:
        return "-"
    lo, hi = b["ci95"]
    return f"{100 * b['rate']:.1f} % [{100 * lo:.1f}, {100 * hi:.1f}] (n = {b['n']})"


def percent_band(cells: list[dict]):
    """(rate, low, high) [%] arrays of binomial results (missing values as 0) for a plot."""
    import numpy as np

    def pick(f):
        return np.array([100 * (f(c) or 0.0) for c in cells])

    return pick(lambda c: c["rate"]), pick(lambda c: c["ci95"][0]), pick(lambda c: c["ci95"][1])


def mean_cell(m: dict, fmt: str = ".3f") -> str:
    """'0.512 [0.498, 0.526] (n = 16)' of a mean_ci result."""
    if not m or not m.get("n") or m.get("mean") is None:
        return "-"
    lo, hi = m["ci95"]
    return f"{num(m['mean'], fmt)} [{num(lo, fmt)}, {num(hi, fmt)}] (n = {m['n']})"


def run(doc: str, name: str, scenario: str, rows_of: Callable[[dict], list[dict]], title: str,
        figure: Callable[[dict, Path], None], figure_name: str, argv: list[str] | None = None) -> None:
    """A figure script's whole main: parse the flags, evaluate every expert on ``scenario``, tabulate with
    ``rows_of`` and :func:`finish`; ``title`` may use ``{scale}``."""
    args = parse_args(doc, name, argv=argv)
    results, info = evaluate_policies(scenario, args)
    rows = rows_of(results)
    finish(name, scenario, args, results, info, rows, list(rows[0]) if rows else ["policy"],
           title.format(scale=args.scale), figure, figure_name)

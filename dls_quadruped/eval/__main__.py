"""Evaluate a policy on a standard scenario (thesis 7.1): JSON + plot.

    python -m dls_quadruped.eval --policy docs/policies/base_actor.pt --scenario simple [--episodes 256] [--out DIR]
    python -m dls_quadruped.eval --policy docs/policies/base_actor.pt --scenario speed --set env.episode_length_s=10
    make eval POLICY=docs/policies/base_actor.pt SCENARIO=simple

``--policy``: an exported actor (e.g. ``runs/base/<run>/exported/policy.pt2``, or a TorchScript one such as the
committed ``docs/policies/base_actor.pt``) or an
rsl-rl checkpoint (``runs/base/<run>/model_<it>.pt``). Writes ``<out>/<scenario>.json`` and
``<out>/<scenario>.png`` (default: :func:`default_out`, ``results/eval/<task>/<run>/<policy stem>`` for a file of a
training run, ``results/eval/<policy stem>`` for any other) and prints the headline figures
and the targets. ``--split validation`` plays disjoint episodes of the same scenario, for choosing checkpoints; reports
use the default ``test``. ``--episodes`` is per condition (speed, step height, grid cell); each scenario has a
small default. Scenarios: see ``dls_quadruped/eval/scenarios.py`` and docs/eval.md.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from dls_quadruped.cli import (
    ArgumentParser,
    add_set_argument,
    run_cli,
    set_overrides,
    torch_device,
)
from dls_quadruped.core.json_io import write_json
from dls_quadruped.core.progress import label
from dls_quadruped.eval.policy import check_policy_file
from dls_quadruped.eval.provenance import provenance
from dls_quadruped.eval.scenario import (
    SPLITS,
    VALIDATION_SEED_OFFSET,
    split_seed,
)
from dls_quadruped.eval.scenarios import SCENARIOS
from dls_quadruped.eval.velocity_tracking import (
    FIXED_SECTIONS,
    OVERRIDABLE_SECTIONS,
    TaskEvalOptions,
)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--policy", type=Path, required=True,
                   help="exported actor (.pt2 or TorchScript .pt) or model_<it>.pt checkpoint")
    p.add_argument("--scenario", default="simple", choices=sorted(SCENARIOS),
                   # argparse %-formats help strings: a literal "50 %" must be "50 %%"
                   help="; ".join(f"{s.name}: {s.description}" for s in SCENARIOS.values()).replace("%", "%%"))
    p.add_argument("--episodes", type=int, default=None,
                   help="episodes per condition (per speed, step height, grid cell; the whole set for simple, "
                        "forward, survival), all in parallel; default: the scenario's small size")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--split", default="test", choices=SPLITS,
                   help="episode set: test (what reports use) or validation (for choosing checkpoints; the same "
                        f"scenario with disjoint episodes, seed + {VALIDATION_SEED_OFFSET})")
    p.add_argument("--num-workers", type=int, default=-1, help="simulator worker processes (-1: one per core)")
    p.add_argument("--episode-length-s", type=float, default=None, help="override the task's episode length [s]")
    p.add_argument("--device", type=torch_device, default="cpu", help="cpu, cuda or cuda:<index>")
    p.add_argument("--out", type=Path, default=None,
                   help="output folder (default: results/eval/<task>/<run>/<policy stem> for a file of a training run "
                        "runs/<task>/<run>/, else results/eval/<policy stem>)")
    add_set_argument(p, f"of the base task every scenario starts from, in its sections "
                        f"{', '.join(OVERRIDABLE_SECTIONS)}: "
                        f"the scenario sets {', '.join(FIXED_SECTIONS)} itself, so a key there is refused; recorded "
                        "in the JSON as task_overrides")
    args = p.parse_args(argv)
    try:
        args.episode_seed = split_seed(args.seed, args.split)
    except ValueError as err:
        p.error(f"argument --seed: {err}")
    if args.episodes is not None and args.episodes < 1:
        p.error(f"argument --episodes: must be >= 1, got {args.episodes}")
    multiple = SCENARIOS[args.scenario].episodes_multiple
    if args.episodes is not None and args.episodes % multiple:
        p.error(f"argument --episodes: scenario {args.scenario} needs a multiple of {multiple} (every command has a "
                f"mirrored twin), got {args.episodes}")
    return args


def default_out(policy: Path, root: Path = Path("results/eval")) -> Path:
    """Where an evaluation of ``policy`` goes without ``--out``: ``root/<task>/<run>/<stem>`` for a file inside a
    training run (a folder holding the ``task.yaml`` train writes: ``runs/base/<run>/model_450.pt``,
    ``runs/base/<run>/exported/policy.pt2``), so two runs' ``policy.pt2`` never share a folder; ``root/<stem>``
    for any other file (``docs/policies/base_actor.pt`` -> ``results/eval/base_actor``)."""
    for run in list(policy.parents)[:2]:
        if (run / "task.yaml").is_file() and run.name and run.parent.name:
            return root / run.parent.name / run.name / policy.stem
    return root / policy.stem


def headline(res: dict) -> str:
    """A few lines of the main figures (scenarios with tracking metrics)."""
    lines = [f"[eval] {res['scenario']}: {res['policy']}, {res['episodes']} episodes of {res['episode_length_s']:g} s"]
    s = res["survival"]
    lines.append(f"  survival {100 * s['rate']:.1f} % (95 % CI {100 * s['ci95'][0]:.1f}-{100 * s['ci95'][1]:.1f})")
    for name, a in res.get("axes", {}).items():
        m = res.get("mirror", {}).get(name, {})
        lines.append(f"  {name:8s} slope {a['slope']:.3f}  mean error {a['mean_error']:+.3f}"
                     + (f"  mirror |diff| {m['mean_abs_diff']:.3f} (mean diff {m['mean_diff']:+.3f})" if m else ""))
    if "tracking" in res:
        t = res["tracking"]
        lines.append(f"  |v_xy - cmd| median {t['vxy_error']['median']:.3f} (IQR {t['vxy_error']['q1']:.3f}-"
                     f"{t['vxy_error']['q3']:.3f}) m/s; |omega_z - cmd| median {t['yaw_rate_error']['median']:.3f} "
                     f"(IQR {t['yaw_rate_error']['q1']:.3f}-{t['yaw_rate_error']['q3']:.3f}) rad/s")
    if "reward" in res:
        lines.append(f"  reward per step {res['reward']['per_step']:.3f} (thesis RL baseline "
                     f"{res['reward']['thesis_rl_baseline']})")
    if "targets" in res:
        missed = [k for k, v in res["targets"].items() if not v["met"]]
        lines.append(f"  targets met {len(res['targets']) - len(missed)}/{len(res['targets'])}"
                     + (f"; missed: {', '.join(missed)}" if missed else ""))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict:
    args = parse_args(argv)
    scenario = SCENARIOS[args.scenario]
    check_policy_file(args.policy)  # before the env is built
    overrides = set_overrides(args.set)
    opts = TaskEvalOptions(episodes=args.episodes or scenario.default_episodes, seed=args.episode_seed,
                           num_workers=args.num_workers, episode_length_s=args.episode_length_s, device=args.device,
                           task_overrides=overrides or None)
    t0 = time.perf_counter()
    with label(f"eval {scenario.name}"):  # every rollout's bar (a line every ~15 s in a log) says whose it is
        res = scenario.evaluate(args.policy, opts)
    res["split"] = args.split
    if overrides:
        res["task_overrides"] = overrides
    res["wall_s"] = round(time.perf_counter() - t0, 1)
    res.update(provenance())
    out = args.out or default_out(args.policy)
    out.mkdir(parents=True, exist_ok=True)
    write_json(res, out / f"{scenario.name}.json", indent=1)  # strict JSON: a NaN metric becomes null, listed
    scenario.plot(res, out / f"{scenario.name}.png")
    print((scenario.summary or headline)(res))
    print(f"[eval] wrote {out / (scenario.name + '.json')} and .png ({res['wall_s']} s)")
    return res


if __name__ == "__main__":
    run_cli(main)  # user errors (missing policy, bad flag) as one line, exit 2

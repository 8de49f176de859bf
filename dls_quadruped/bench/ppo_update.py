"""PPO iteration benchmark (``make bench-ppo``, part of ``make bench``).

For each robot count N, one env and one rsl-rl runner per variant, all from the same seed; the
variants take turns iteration by iteration (the order alternating), so a change of the machine's
load hits them alike and their ratios are measured side by side:

* ``stock``: rsl-rl-lib's PPO update as shipped, the trainer's thread count (``--threads``);
* ``fast_1_thread``: ``learning/fast_update.py``'s update, still on ``--threads`` threads;
* ``fast``: the same with ``--update-threads`` threads in the update (default every core), as
  ``make train`` runs;
* ``fast_no_diag``: ``fast`` without ``learning/diagnostics.py``'s hooks and the action manager's clip
  and stance masks (``make train`` always records them); ``fast`` / ``fast_no_diag`` is what the
  diagnostics cost an iteration (``fast`` reads them out every iteration, as the trainer does);
* ``fast_bf16`` (only with ``--variants``): ``fast`` with rsl-rl's ``use_mixed_precision`` (the
  update's forward passes and losses under ``torch.autocast`` in bfloat16; a task sets it with
  ``agent.algorithm.use_mixed_precision: true``). It changes the update's rounding, so it is not
  the default of any task; the bench measures what it would buy.

Every iteration is timed as ``OnPolicyRunner.learn`` splits it: collection (24 env steps + policy +
storage) and update (returns + 5 epochs x 4 mini-batches). The first iteration of each variant is
a warm-up and not counted. Reported per variant: median collection and update seconds, samples/s of
each part alone and end to end, the update's share of the iteration, and the ratios to ``stock``.
Writes ``results/bench/ppo_update.json`` (CPU model, cores, load averages, ``OMP_WAIT_POLICY``)
and prints a markdown table. Usage::

    python -m dls_quadruped.bench.ppo_update [--sizes 256 1024] [--iterations 3] [--quick]
"""

from __future__ import annotations

import json
import os
import statistics
import time
from pathlib import Path
from typing import Any

import torch

from dls_quadruped.bench.machine import cpu_model
from dls_quadruped.bench.rl_env import make_runner, ppo_iteration
from dls_quadruped.cli import ArgumentParser, non_negative_int, positive_int, run_cli
from dls_quadruped.envs.config import load_task
from dls_quadruped.envs.env import LocomotionEnv
from dls_quadruped.learning.diagnostics import TrainingDiagnostics
from dls_quadruped.learning.fast_update import (
    available_cores,
    default_update_threads,
    speed_up_update,
)

VARIANTS = ("stock", "fast_1_thread", "fast", "fast_no_diag")
"""The default variants; ``stock`` is always run (every ratio is to it)."""
ALL_VARIANTS = (*VARIANTS, "fast_bf16")


def summarise(iterations: list[dict[str, float]]) -> dict[str, float]:
    """Medians of the measured iterations and the samples/s they give."""
    collect = statistics.median(it["collection_s"] for it in iterations)
    update = statistics.median(it["learning_s"] for it in iterations)
    samples = iterations[0]["samples"]
    return {"collection_s": collect, "update_s": update, "total_s": collect + update,
            "collection_samples_per_s": samples / collect, "update_samples_per_s": samples / update,
            "samples_per_s": samples / (collect + update), "update_share": update / (collect + update)}


def bench_size(task: str, n: int, iterations: int, update_threads: int,
               variants: tuple[str, ...] = VARIANTS) -> dict[str, Any]:
    """The variants at N robots, interleaved; per-iteration timings and their summary."""
    unknown = [v for v in variants if v not in ALL_VARIANTS]
    if unknown or "stock" not in variants:
        raise ValueError(f"variants {list(variants)}: need 'stock' and only {list(ALL_VARIANTS)}")
    cfg = load_task(task)
    env = LocomotionEnv(cfg, num_envs=n, verbose=False)
    try:
        runners, diagnostics = {}, {}
        for name in variants:
            torch.manual_seed(0)  # the same initial networks for every variant
            runners[name] = make_runner(env, cfg.data)
            if name != "stock":
                speed_up_update(runners[name].alg, threads=0 if name == "fast_1_thread" else update_threads)
            if name == "fast_bf16":
                runners[name].alg.use_mixed_precision = True  # rsl-rl's flag, read by every update
            if name != "fast_no_diag":
                diagnostics[name] = TrainingDiagnostics.attach(runners[name])
        timings: dict[str, list[dict[str, float]]] = {name: [] for name in variants}
        for i in range(iterations + 1):
            order = variants if i % 2 == 0 else variants[::-1]
            for name in order:
                env.action_manager.record_diagnostics = name in diagnostics
                it = ppo_iteration(env, runners[name])
                if name in diagnostics:  # the trainer reads them out once per iteration, after the update
                    t0 = time.perf_counter()
                    diagnostics[name].scalars()
                    it["learning_s"] += time.perf_counter() - t0
                    it["total_s"] += time.perf_counter() - t0
                it["load_1min"] = os.getloadavg()[0]
                print(f"[bench.ppo_update] N={n} {name} iteration {i}{' (warm-up)' if i == 0 else ''}: "
                      f"collection {it['collection_s']:.2f} s, update {it['learning_s']:.2f} s "
                      f"(load {it['load_1min']:.1f})", flush=True)
                if i > 0:
                    timings[name].append(it)
    finally:
        env.close()
    summary = {name: summarise(timings[name]) for name in variants}
    stock = summary["stock"]
    for s in summary.values():
        s["end_to_end_vs_stock"] = s["samples_per_s"] / stock["samples_per_s"]
        s["update_vs_stock"] = stock["update_s"] / s["update_s"]
    if "fast" in summary and "fast_no_diag" in summary:  # what the diagnostics add to an iteration's wall time
        summary["fast"]["diagnostics_overhead"] = summary["fast"]["total_s"] / summary["fast_no_diag"]["total_s"] - 1.0
    return {"task": task, "num_envs": n, "iterations": timings, "summary": summary}


def markdown(result: dict[str, Any]) -> str:
    lines = [("| N | variant | collection [s] | update [s] | update share | collection samples/s | "
              "update samples/s | end to end samples/s | update speed-up | end to end speed-up |"),
             "|---|---|---|---|---|---|---|---|---|---|"]
    for size in result["sizes"]:
        for name, s in size["summary"].items():
            lines.append(f"| {size['num_envs']} | {name} | {s['collection_s']:.2f} | {s['update_s']:.2f} | "
                         f"{s['update_share']:.0%} | {s['collection_samples_per_s']:,.0f} | "
                         f"{s['update_samples_per_s']:,.0f} | {s['samples_per_s']:,.0f} | "
                         f"{s['update_vs_stock']:.2f}x | {s['end_to_end_vs_stock']:.2f}x |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="base")
    parser.add_argument("--sizes", type=positive_int, nargs="+", default=[256, 1024])
    parser.add_argument("--iterations", type=positive_int, default=3, help="measured iterations per variant")
    parser.add_argument("--threads", type=positive_int, default=1,
                        help="torch threads of the trainer (collection, and the stock update)")
    parser.add_argument("--update-threads", type=non_negative_int, default=None,
                        help="torch threads of the fast variant's update (default: every core)")
    parser.add_argument("--variants", nargs="+", choices=ALL_VARIANTS, default=list(VARIANTS),
                        help="variants to run side by side (stock always: the ratios are to it)")
    parser.add_argument("--quick", action="store_true", help="N = 64, 1 measured iteration (a smoke run)")
    parser.add_argument("--out", type=Path, default=Path("results/bench"))
    args = parser.parse_args(argv)
    if args.quick:
        args.sizes, args.iterations = [64], 1
    torch.set_num_threads(args.threads)
    update_threads = default_update_threads() if args.update_threads is None else args.update_threads
    variants = ["stock"] + [v for v in dict.fromkeys(args.variants) if v != "stock"]
    t0 = time.perf_counter()
    result: dict[str, Any] = {
        "machine": {"cpu": cpu_model(), "cores": os.cpu_count(), "available_cores": available_cores(),
                    "torch": torch.__version__, "omp_wait_policy": os.environ.get("OMP_WAIT_POLICY")},
        "threads": args.threads, "update_threads": update_threads, "load_avg_before": os.getloadavg(),
        "note": "shared machine: other processes may run alongside (see the load averages); compare "
                "the variants' ratios, measured interleaved, rather than absolute times",
        "args": {k: str(v) for k, v in vars(args).items()},
        "variants": variants,
        "sizes": [bench_size(args.task, n, args.iterations, update_threads, tuple(variants)) for n in args.sizes]}
    result["load_avg_after"] = os.getloadavg()
    result["wall_s"] = time.perf_counter() - t0
    args.out.mkdir(parents=True, exist_ok=True)
    tmp = args.out / "ppo_update.json.tmp"
    tmp.write_text(json.dumps(result, indent=2))
    tmp.replace(args.out / "ppo_update.json")
    print()
    print(f"{result['machine']['cpu']}, {result['machine']['cores']} cores, load {result['load_avg_before'][0]:.1f} "
          f"-> {result['load_avg_after'][0]:.1f}; update threads {update_threads} (OMP_WAIT_POLICY="
          f"{result['machine']['omp_wait_policy']})")
    print(markdown(result))
    return result


if __name__ == "__main__":
    run_cli(main)

"""The solve around the kernel, fused vs torch path: ``python -m dls_quadruped.bench.mpc_path``.

Also the last part of ``make bench-mpc``. Two SamplingMPCs with the same seed (so the same samples and winners),
one on the fused path (``SamplingMPC.fused``, :mod:`dls_quadruped.mpc.solve_glue`) and one on the torch path,
take turns solve by solve on 1 thread (so load from other jobs falls on both alike), the MPC solve time benchmark's
problem: B = 1, M = 10 000, N = 10, naive + external warm start 50/50. Per path: median wall time of
``SamplingMPC.solve`` alone, of the naive warm start built before it, of the kernel call inside the solve
(``SamplingMPC.kernel_seconds``), the thread's CPU time per solve (robust to other jobs taking the core), and
the ratios solve / kernel (target <= 1.2).

Writes results/bench/mpc_path.json; with ``--update-docs`` it also rewrites the "## MPC solve path" section of
docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from pathlib import Path

import torch

from dls_quadruped.bench.mpc_common import BUILDS_SECTION, section_span, solve_problem
from dls_quadruped.cli import ArgumentParser, run_cli
from dls_quadruped.core.machine import cpu_model
from dls_quadruped.mpc import SamplerConfig, SamplingMPC, warm_start

REPO = Path(__file__).resolve().parents[2]
SECTION = "## MPC solve path"
PATHS = ("fused", "torch")


def time_paths(num_samples: int = 10000, horizon: int = 10, solves: int = 200, warmup: int = 10) -> list[dict]:
    """Median times [ms] per path of :data:`PATHS`, taking turns solve by solve on the current torch threads."""
    state, refs, phase = solve_problem("cpu")
    cfg = SamplerConfig(num_samples=num_samples, horizon=horizon, kernel="cpp")
    default, external = warm_start.nominal_trot(1, cfg), warm_start.nominal_trot(1, cfg, freq=1.8)
    mpcs = {}
    for path in PATHS:
        mpcs[path] = SamplingMPC(cfg, seed=0)
        mpcs[path].fused = path == "fused"
    keys = ("solve", "warm_start", "kernel", "solve_cpu")
    times = {path: {k: [] for k in keys} for path in PATHS}
    same = True
    for i in range(warmup + solves):
        results = {}
        for path, mpc in mpcs.items():
            t0 = time.perf_counter()
            ws = mpc.naive_warm_start(default)
            c1, t1, k0 = time.thread_time(), time.perf_counter(), mpc.kernel_seconds
            results[path] = mpc.solve(state, refs, [ws, external], proportions=(0.5, 0.5), phase=phase)
            t2, c2 = time.perf_counter(), time.thread_time()
            if i >= warmup:
                for k, v in zip(keys, (t2 - t1, t1 - t0, mpc.kernel_seconds - k0, c2 - c1), strict=True):
                    times[path][k].append(1e3 * v)
        same = same and torch.equal(results["fused"].best_encoded, results["torch"].best_encoded) \
            and torch.equal(results["fused"].best_cost, results["torch"].best_cost)
    rows = []
    for path in PATHS:
        med = {f"{k}_median_ms": statistics.median(v) for k, v in times[path].items()}
        rows.append({"path": path, "M": num_samples, "N": horizon, "solves": solves,
                     "threads": torch.get_num_threads(), **med,
                     "solve_min_ms": min(times[path]["solve"]), "kernel_min_ms": min(times[path]["kernel"]),
                     "solve_over_kernel": med["solve_median_ms"] / med["kernel_median_ms"],
                     "solve_cpu_over_kernel": med["solve_cpu_median_ms"] / med["kernel_median_ms"],
                     "min_solve_over_min_kernel": min(times[path]["solve"]) / min(times[path]["kernel"]),
                     "solve_and_warm_start_over_kernel":
                         (med["solve_median_ms"] + med["warm_start_median_ms"]) / med["kernel_median_ms"],
                     "same_results": same})
    return rows


def table(rows: list[dict]) -> str:
    """Markdown rows per path."""
    lines = [("| path | solve [ms] | kernel call [ms] | solve / kernel | solve CPU time [ms] | solve CPU / kernel | "
              "solve, min [ms] | kernel, min [ms] | min / min | naive warm start [ms] | "
              "(warm start + solve) / kernel |"),
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['path']} | {r['solve_median_ms']:.3f} | {r['kernel_median_ms']:.3f} | "
                     f"**{r['solve_over_kernel']:.2f}x** | {r['solve_cpu_median_ms']:.3f} | "
                     f"{r['solve_cpu_over_kernel']:.2f}x | {r['solve_min_ms']:.3f} | {r['kernel_min_ms']:.3f} | "
                     f"{r['min_solve_over_min_kernel']:.2f}x | {r['warm_start_median_ms']:.3f} | "
                     f"{r['solve_and_warm_start_over_kernel']:.2f}x |")
    return "\n".join(lines)


def update_docs(rows: list[dict], info: dict, path: Path) -> None:
    """Replace (or append after '## MPC C++ kernel builds') the '## MPC solve path' section of ``path``."""
    r = rows[0]
    body = (
        f"{SECTION}\n\n"
        "`python -m dls_quadruped.bench.mpc_path` (also the last part of `make bench-mpc`): the fused "
        "solve (`SamplingMPC.fused`, `mpc/solve_glue.py`: input cleaning, kernel + argmin in one C++ call, the "
        "winner's decoding in C++ around torch's log/sqrt/cos/sin/matmul/sums) and the torch path, two SamplingMPCs "
        "with the same seed taking turns solve by solve, the problem of \"MPC solve time\" "
        f"(B = 1, M = {r['M']}, N = {r['N']}, two warm starts), {r['threads']} thread(s), medians over {r['solves']} "
        f"solves. Same winners and costs on both paths in this run: {r['same_results']}. `solve` is "
        "`SamplingMPC.solve` alone; the naive warm start is built before it (`warm_start.naive`, shared by both "
        "paths). Machine: "
        f"{info['cpu']}, {info['cpu_count']} cores, torch {info['torch']}; load average (1, 5, 15 min) at start "
        f"{info['load_avg_1_5_15']} and end {info['load_avg_end']}.\n\n"
        f"{table(rows)}\n\nRaw numbers: `results/bench/mpc_path.json`.\n\n"
    )
    text = path.read_text() if path.exists() else "# Benchmarks\n"
    if SECTION in text:
        start, end = section_span(text, SECTION)
        text = text[:start] + body + text[end:]
    elif BUILDS_SECTION in text:
        _, end = section_span(text, BUILDS_SECTION)
        text = text[:end].rstrip("\n") + "\n\n" + body + text[end:]
    else:
        text = text.rstrip("\n") + "\n\n" + body
    path.write_text(text)


def run(args: argparse.Namespace) -> list[dict]:
    """Time both paths on 1 thread; print, write JSON and (with ``--update-docs``, not ``--quick``) the docs."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    info = {"cpu": cpu_model(), "cpu_count": os.cpu_count(), "torch": torch.__version__,
            "load_avg_1_5_15": [round(x, 2) for x in os.getloadavg()]}
    try:
        m, n = (2000, 5) if args.quick else (10000, 10)
        rows = time_paths(m, n, solves=min(args.solves, 20) if args.quick else args.solves)
    finally:
        torch.set_num_threads(threads)
    info["load_avg_end"] = [round(x, 2) for x in os.getloadavg()]
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "mpc_path.json").write_text(json.dumps({"machine": info, "results": rows}, indent=2))
    print(f"MPC solve path, M = {m}, N = {n}, 1 thread, {info['cpu']}, load {info['load_avg_1_5_15']} -> "
          f"{info['load_avg_end']}")
    print(table(rows))
    if args.update_docs and not args.quick:
        update_docs(rows, info, args.docs)
    return rows


def main(argv: list[str] | None = None) -> None:
    parser = ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="M = 2000, N = 5, 20 solves, docs untouched")
    parser.add_argument("--solves", type=int, default=200, help="timed solves per path (default 200)")
    parser.add_argument("--out", type=Path, default=REPO / "results" / "bench")
    parser.add_argument("--docs", type=Path, default=REPO / "docs" / "benchmarks.md",
                        help="the page --update-docs rewrites (default docs/benchmarks.md)")
    parser.add_argument("--update-docs", action="store_true",
                        help="also rewrite the section of --docs (default: write only under --out)")
    run(parser.parse_args(argv))


if __name__ == "__main__":
    run_cli(main)  # a bad flag or a user error: one line, exit 2; Ctrl-C: one line, exit 130

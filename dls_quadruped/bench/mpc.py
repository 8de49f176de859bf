"""MPC solve-time benchmark: ``python -m dls_quadruped.bench.mpc [--quick]``.

Times one full :meth:`SamplingMPC.solve` (validation, sampling, rollouts, argmin, decoding the
winner) for M samples x N steps, B = 1 robot, two warm starts (naive + external, 50/50), every
variable optimised (sigma_f, sigma_d, sigma_p, sigma_F > 0, first-spline encoding), for the
``fast``, ``cpp`` (CPU only) and ``reference`` kernels, on the CPU with the threads torch has and on CUDA when
present. Median and p90 over ``--solves`` solves after warm-up (the first call compiles).

Writes results/bench/mpc.json (with machine info), results/bench/mpc_solve_time.png and prints a
markdown table; with ``--update-docs`` it also rewrites the "## MPC solve time" section of docs/benchmarks.md.

Then (or alone, ``--builds-only``) the C++ kernel built three ways is timed side by side at M = 10 000,
N = 10: for the host (``-march=native``), for ``x86-64-v3`` (AVX2 + FMA: a machine without
AVX-512) and without auto-vectorisation (``scalar``), taking turns solve by solve; full solve and kernel
call medians, speed-ups over ``scalar`` and the kernel's share of the machine's fp32 peak go to
results/bench/mpc_builds.json (and, with ``--update-docs``, the "## MPC C++ kernel builds" section of
docs/benchmarks.md): :mod:`dls_quadruped.bench.mpc_builds`.

Last, the fused solve vs the torch path side by side (:mod:`dls_quadruped.bench.mpc_path`).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from pathlib import Path

import torch

from dls_quadruped.bench.mpc_builds import run_builds
from dls_quadruped.bench.mpc_common import (
    SECTION,
    machine_info,
    section_span,
    solve_problem,
)
from dls_quadruped.cli import ArgumentParser, run_cli
from dls_quadruped.mpc import SamplerConfig, SamplingMPC, warm_start

REPO = Path(__file__).resolve().parents[2]


def time_solves(num_samples: int, horizon: int, kernel: str, device: str, solves: int, warmup: int = 3) -> dict:
    """Median / p90 wall time [ms] of ``solves`` solves after ``warmup`` (first one timed as compile)."""
    cfg = SamplerConfig(num_samples=num_samples, horizon=horizon, kernel=kernel)
    mpc = SamplingMPC(cfg, device=device, seed=0)
    state, refs, phase = solve_problem(device)
    default = warm_start.nominal_trot(1, cfg).to(device)
    external = warm_start.nominal_trot(1, cfg, freq=1.8).to(device)
    sync = torch.cuda.synchronize if device.startswith("cuda") else (lambda: None)

    def solve() -> None:
        mpc.solve(state, refs, [mpc.naive_warm_start(default), external], proportions=(0.5, 0.5), phase=phase)
        sync()

    t0 = time.perf_counter()
    solve()
    first = time.perf_counter() - t0
    for _ in range(warmup):
        solve()
    times = []
    for _ in range(solves):
        t0 = time.perf_counter()
        solve()
        times.append((time.perf_counter() - t0) * 1e3)
    times.sort()
    return {"M": num_samples, "N": horizon, "kernel": kernel, "device": device, "solves": solves,
            "median_ms": statistics.median(times), "p90_ms": times[int(0.9 * (len(times) - 1))],
            "min_ms": times[0], "first_call_s": first}


def markdown_table(results: list[dict]) -> str:
    """Rows (device, N, M) with fast / reference median and p90 and the speed-up."""
    keyed = {(r["device"], r["N"], r["M"], r["kernel"]): r for r in results}
    header = ("| device | N | M | fast median [ms] | fast p90 [ms] | fast min [ms] | cpp median [ms] | cpp p90 [ms] "
              "| cpp min [ms] | reference median [ms] | reference p90 [ms] | speed-up fast (medians) |")
    lines = [header, "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for dev, n, m in sorted({(r["device"], r["N"], r["M"]) for r in results}):
        fast, ref = keyed.get((dev, n, m, "fast")), keyed.get((dev, n, m, "reference"))
        cpp = keyed.get((dev, n, m, "cpp"))
        cell = lambda r, k: f"{r[k]:.2f}" if r else "-"
        speed = f"{ref['median_ms'] / fast['median_ms']:.1f}x" if fast and ref else "-"
        lines.append(f"| {dev} | {n} | {m} | {cell(fast, 'median_ms')} | {cell(fast, 'p90_ms')} | "
                     f"{cell(fast, 'min_ms')} | "
                     f"{cell(cpp, 'median_ms')} | {cell(cpp, 'p90_ms')} | {cell(cpp, 'min_ms')} | "
                     f"{cell(ref, 'median_ms')} | {cell(ref, 'p90_ms')} | {speed} |")
    return "\n".join(lines)


def plot(results: list[dict], path: Path) -> None:
    """Solve time vs samples, one line per (device, kernel, N)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for dev, kernel, n in sorted({(r["device"], r["kernel"], r["N"]) for r in results}):
        rows = sorted((r for r in results if (r["device"], r["kernel"], r["N"]) == (dev, kernel, n)),
                      key=lambda r: r["M"])
        ax.plot([r["M"] for r in rows], [r["median_ms"] for r in rows], marker="o",
                linestyle={"fast": "-", "cpp": "-."}.get(kernel, "--"), label=f"{kernel} {dev} N={n}")
    ax.axhline(4.0, color="grey", linewidth=0.8, linestyle=":", label="4 ms target (CPU)")
    ax.set(xscale="log", yscale="log", xlabel="samples M", ylabel="median solve time [ms]",
           title="Sampling MPC solve time (B = 1)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def update_docs(table: str, info: dict, results: list[dict], path: Path) -> None:
    """Replace (or append) the '## MPC solve time' section of docs/benchmarks.md."""
    ref10 = [r for r in results
             if r["kernel"] == "reference" and r["N"] == 10 and r["M"] == 10000 and r["device"] == "cpu"]
    fast10 = [r for r in results if r["kernel"] == "fast" and r["N"] == 10 and r["M"] == 10000 and r["device"] == "cpu"]
    cpp10 = [r for r in results if r["kernel"] == "cpp" and r["N"] == 10 and r["M"] == 10000 and r["device"] == "cpu"]
    headline = ""
    for name, rows in (("cpp", cpp10), ("fast", fast10)):
        if ref10 and rows:
            headline += (f"M = 10 000, N = 10 on the CPU: {name} {rows[0]['median_ms']:.2f} ms median "
                         f"(p90 {rows[0]['p90_ms']:.2f} ms) vs reference {ref10[0]['median_ms']:.1f} ms: "
                         f"speed-up {ref10[0]['median_ms'] / rows[0]['median_ms']:.1f}x (target <= 4 ms).\n\n")
    load = max(info["load_avg_1_5_15"][0], (info.get("load_avg_end") or [0.0])[0])
    load_note = ("the 2 cores were shared with other jobs, so medians and p90s are inflated and noisy"
                 if load > 1.5 else "the machine was otherwise idle")
    body = (
        f"{SECTION}\n\n"
        "`python -m dls_quadruped.bench.mpc`: one full `SamplingMPC.solve` for B = 1 robot, "
        "two warm starts (50/50), f, d, p and F all sampled, first-spline encoding, dt = 0.02 s; median and p90 "
        f"over {results[0]['solves']} solves after warm-up. `fast` = the torch.compile'd fused kernel, `cpp` = the "
        "hand-written C++/OpenMP kernel, "
        "`reference` = the straightforward eager kernel (the in-run reference). "
        f"Machine: {info['cpu']}, {info['cpu_count']} cores, {info['torch_threads']} torch threads, torch "
        f"{info['torch']}, load average (1, 5, 15 min) at start {info['load_avg_1_5_15']} and end "
        f"{info.get('load_avg_end')}: {load_note}; `min` is the best of the timed solves.\n\n"
        f"{headline}{table}\n\n"
        "Raw numbers: `results/bench/mpc.json`; plot: `results/bench/mpc_solve_time.png`.\n"
    )
    text = path.read_text() if path.exists() else "# Benchmarks\n"
    if SECTION in text:
        start, end = section_span(text, SECTION)
        text = text[:start] + body + text[end:]
    else:
        text = text.rstrip("\n") + "\n\n" + body
    path.write_text(text)


def main(argv: list[str] | None = None) -> None:
    parser = ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="reduced grid (M in 1000, 4000; N = 5; 10 solves)")
    parser.add_argument("--solves", type=int, default=50, help="timed solves per point (default 50)")
    parser.add_argument("--reference-all", action="store_true", help="reference kernel at every N (default N = 10)")
    parser.add_argument("--out", type=Path, default=REPO / "results" / "bench")
    parser.add_argument("--docs", type=Path, default=REPO / "docs" / "benchmarks.md",
                        help="the page --update-docs rewrites (default docs/benchmarks.md)")
    parser.add_argument("--update-docs", action="store_true",
                        help="also rewrite the MPC sections of --docs (default: write only under --out)")
    parser.add_argument("--threads", type=int, default=0, help="torch CPU threads (default: torch's choice)")
    parser.add_argument("--horizons", type=int, nargs="+", default=None, help="override the N grid")
    parser.add_argument("--samples", type=int, nargs="+", default=None, help="override the M grid")
    parser.add_argument("--builds-only", action="store_true",
                        help="only time the C++ kernel builds (native, x86-64-v3, scalar) side by side")
    parser.add_argument("--render", type=Path, default=None,
                        help="only re-render the table and plot (and with --update-docs the docs) from an existing "
                             "mpc.json")
    args = parser.parse_args(argv)
    if args.render is not None:
        data = json.loads(args.render.read_text())
        plot(data["results"], args.render.parent / "mpc_solve_time.png")
        table = markdown_table(data["results"])
        print(table)
        if args.update_docs:
            update_docs(table, data["machine"], data["results"], args.docs)
        return
    if args.threads > 0:
        torch.set_num_threads(args.threads)
    if args.builds_only:
        run_builds(args)
        return
    if args.quick:
        ms, ns, solves, ref_ns = (1000, 4000), (5,), min(args.solves, 10), (5,)
    else:
        ms, ns, solves = (1000, 4000, 10000, 25000), (5, 10, 15), args.solves
        ref_ns = ns if args.reference_all else (10,)
    ms, ns = tuple(args.samples or ms), tuple(args.horizons or ns)
    if args.horizons and not args.reference_all and not args.quick:
        ref_ns = tuple(n for n in ns if n == 10) or ns[:1]
    devices = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
    info = machine_info()
    results = []
    for device in devices:
        for n in ns:
            for m in ms:
                for kernel in ("fast", "cpp", "reference"):
                    if (kernel == "reference" and n not in ref_ns) or (kernel == "cpp" and device != "cpu"):
                        continue
                    r = time_solves(m, n, kernel, device, solves)
                    results.append(r)
                    print(f"{device} {kernel:9s} N={n:2d} M={m:6d}: median {r['median_ms']:8.2f} ms  "
                          f"p90 {r['p90_ms']:8.2f} ms  (first call {r['first_call_s']:.1f} s)", flush=True)
    info["load_avg_end"] = list(os.getloadavg()) if hasattr(os, "getloadavg") else None
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "mpc.json").write_text(json.dumps({"machine": info, "results": results}, indent=2))
    plot(results, args.out / "mpc_solve_time.png")
    table = markdown_table(results)
    print(table)
    if args.update_docs and not args.quick:
        update_docs(table, info, results, args.docs)
    run_builds(args)
    from dls_quadruped.bench import mpc_path

    mpc_path.run(argparse.Namespace(quick=args.quick, solves=200, out=args.out, docs=args.docs,
                                    update_docs=args.update_docs))


if __name__ == "__main__":
    run_cli(main)  # a bad flag or a user error: one line, exit 2; Ctrl-C: one line, exit 130

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
results/bench/mpc_builds.json (and, with ``--update-docs``, the "## MPC C++ kernel builds" section of docs/benchmarks.md).

Last, the fused solve vs the torch path side by side (:mod:`dls_quadruped.bench.mpc_path`).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import time
from pathlib import Path
from unittest import mock

import torch

from dls_quadruped.bench.mpc_common import BUILDS_SECTION, section_span, solve_problem
from dls_quadruped.cli import ArgumentParser, run_cli
from dls_quadruped.core.machine import cpu_model
from dls_quadruped.core.progress import progress
from dls_quadruped.mpc import SamplerConfig, SamplingMPC, cpp_kernel, warm_start

REPO = Path(__file__).resolve().parents[2]
SECTION = "## MPC solve time"
ROLLOUT_MFLOP = 30.0
"""fp32 work of one solve's kernel at M = 10 000, N = 10 (an estimate from the kernel's arithmetic), scaled by M N elsewhere."""
FLOP_PER_CYCLE = 32
"""fp32 FLOP per cycle and core with two 256-bit FMA pipes (2 x 8 lanes x 2): AMD Zen 2-4 (Zen 4 runs
AVX-512 on the same two 256-bit pipes), Intel cores since Haswell. Peak per core = clock x this."""
SIMD_FLAGS = ("sse4_2", "avx", "avx2", "fma", "avx512f", "avx512vl", "avx512bw", "avx512dq", "asimd", "sve")


def machine_info() -> dict:
    """CPU model, threads, torch version, CUDA device, load average."""
    info = {"cpu": cpu_model(), "cpu_count": os.cpu_count(), "torch_threads": torch.get_num_threads(),
            "torch": torch.__version__, "python": platform.python_version(),
            "load_avg_1_5_15": list(os.getloadavg()) if hasattr(os, "getloadavg") else None}
    if torch.cuda.is_available():
        info["cuda_device"] = torch.cuda.get_device_name(0)
    return info


def _cpuinfo_field(name: str) -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.split(":", 1)[0].strip() == name:
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return ""


def simd_flags() -> list[str]:
    """The vector-ISA flags of this CPU that matter to the kernel (x86 ``flags`` / ARM ``Features``)."""
    have = set((_cpuinfo_field("flags") or _cpuinfo_field("Features")).split())
    return [f for f in SIMD_FLAGS if f in have]


def peak_gflops_per_core() -> float | None:
    """fp32 peak of one core [GFLOP/s]: clock (/proc/cpuinfo 'cpu MHz') x :data:`FLOP_PER_CYCLE`."""
    mhz = _cpuinfo_field("cpu MHz")
    return float(mhz) * 1e-3 * FLOP_PER_CYCLE if mhz else None


def compiler_version() -> str:
    cxx = cpp_kernel.compiler()
    if cxx is None:
        return "none"
    out = subprocess.run([cxx, "--version"], capture_output=True, text=True, check=False).stdout
    return out.splitlines()[0] if out else cxx


def build_variants() -> list[str]:
    """The kernel builds this machine can run: x86-64-v3 needs an x86 CPU with AVX2 and FMA."""
    flags = simd_flags()
    can_v3 = platform.machine() in ("x86_64", "AMD64") and "avx2" in flags and "fma" in flags
    return [v for v in cpp_kernel.VARIANTS if v != "x86-64-v3" or can_v3]


def time_cpp_builds(num_samples: int, horizon: int, solves: int, threads: int, warmup: int = 3) -> list[dict]:
    """Full-solve and kernel-call times [ms] of the C++ kernel built as each of :func:`build_variants`, on
    ``threads`` torch / OpenMP threads.

    The builds take turns solve by solve (each its own SamplingMPC with the same seed, so the same work),
    so that load from other jobs falls on all of them alike. The solve goes through the normal path:
    ``cpp_kernel.load`` is patched to hand out the build under test; the kernel call inside the solve is
    ``SamplingMPC.kernel_seconds``' increment."""
    libs = {v: cpp_kernel.load(v) for v in build_variants()}
    libs = {v: lib for v, lib in libs.items() if lib is not None}
    state, refs, phase = solve_problem("cpu")
    runs = {}
    for v in libs:
        cfg = SamplerConfig(num_samples=num_samples, horizon=horizon, kernel="cpp")
        mpc = SamplingMPC(cfg, device="cpu", seed=0)
        runs[v] = (mpc, warm_start.nominal_trot(1, cfg), warm_start.nominal_trot(1, cfg, freq=1.8))
    solve_ms = {v: [] for v in libs}
    kernel_ms = {v: [] for v in libs}
    threads_before = torch.get_num_threads()
    torch.set_num_threads(threads)
    for i in progress(range(warmup + solves), desc=f"solves, {threads} threads", unit="solve", leave=False):
        for v, lib in libs.items():
            mpc, default, external = runs[v]
            with mock.patch.object(cpp_kernel, "load", lambda variant="native", lib=lib: lib):
                kernel_before = mpc.kernel_seconds
                t0 = time.perf_counter()
                mpc.solve(state, refs, [mpc.naive_warm_start(default), external], proportions=(0.5, 0.5),
                          phase=phase)
                elapsed = (time.perf_counter() - t0) * 1e3
            if i >= warmup:
                solve_ms[v].append(elapsed)
                kernel_ms[v].append((mpc.kernel_seconds - kernel_before) * 1e3)
    torch.set_num_threads(threads_before)
    rows = []
    for v, lib in libs.items():
        st, kt = sorted(solve_ms[v]), sorted(kernel_ms[v])
        rows.append({"variant": v, "flags": lib.build_flags, "threads": threads, "M": num_samples, "N": horizon,
                     "solves": solves,
                     "solve_median_ms": statistics.median(st), "solve_p90_ms": st[int(0.9 * (len(st) - 1))],
                     "kernel_median_ms": statistics.median(kt), "kernel_min_ms": kt[0]})
    return rows


def builds_table(rows: list[dict], peak_core: float | None) -> str:
    """Markdown rows per (threads, build): solve and kernel medians, time relative to the ``scalar`` build on
    as many threads, kernel GFLOP/s and its share of the fp32 peak of the cores it ran on."""
    header = ("| threads | build | flags | solve median [ms] | solve p90 [ms] | kernel median [ms] | kernel min [ms] "
              "| solve time / scalar | kernel time / scalar | kernel GFLOP/s | % of fp32 peak |")
    lines = [header, "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        scalar = next((s for s in rows if s["variant"] == "scalar" and s["threads"] == r["threads"]), None)
        gflops = ROLLOUT_MFLOP * r["M"] * r["N"] / 1e5 / r["kernel_median_ms"]  # MFLOP / ms = GFLOP/s
        rel = [f"{r[k] / scalar[k]:.2f}x" if scalar else "-" for k in ("solve_median_ms", "kernel_median_ms")]
        share = f"{100 * gflops / (peak_core * r['threads']):.1f} %" if peak_core else "-"
        lines.append(f"| {r['threads']} | {r['variant']} | `{r['flags']}` | {r['solve_median_ms']:.2f} | "
                     f"{r['solve_p90_ms']:.2f} | {r['kernel_median_ms']:.2f} | {r['kernel_min_ms']:.2f} | {rel[0]} | "
                     f"{rel[1]} | {gflops:.1f} | {share} |")
    return "\n".join(lines)


def build_notes(rows: list[dict]) -> list[str]:
    """One line per (threads, non-scalar build): solve and kernel-call time relative to the scalar build."""
    notes = []
    for r in rows:
        scalar = next((s for s in rows if s["variant"] == "scalar" and s["threads"] == r["threads"]), None)
        if scalar is None or r is scalar:
            continue
        notes.append(f"{r['threads']} thread(s), {r['variant']}: solve {r['solve_median_ms']:.2f} ms = "
                     f"{r['solve_median_ms'] / scalar['solve_median_ms']:.2f}x the scalar build's "
                     f"{scalar['solve_median_ms']:.2f} ms; kernel call {r['kernel_median_ms']:.2f} ms = "
                     f"{r['kernel_median_ms'] / scalar['kernel_median_ms']:.2f}x the scalar "
                     f"{scalar['kernel_median_ms']:.2f} ms (speed-up {scalar['kernel_median_ms'] / r['kernel_median_ms']:.1f}x)")
    return notes


def update_builds_docs(rows: list[dict], info: dict, path: Path) -> None:
    """Replace the '## MPC C++ kernel builds' section of ``path`` (new: right after '## MPC solve time')."""
    peak = info.get("peak_gflops_per_core")
    m, n = rows[0]["M"], rows[0]["N"]
    load = max(info["load_avg_1_5_15"][0], (info.get("load_avg_end") or [0.0])[0])
    load_note = (f"the {info['cpu_count']} cores were shared with other jobs (load above 1.5), which hits the "
                 "multi-threaded rows hardest (OpenMP waits for a descheduled thread): compare builds within a "
                 "thread count, the 1-thread rows are the steadiest" if load > 1.5 else "the machine was otherwise idle")
    peak_note = (f"fp32 peak per core {peak:.0f} GFLOP/s = {info['cpu_mhz']:.0f} MHz x {FLOP_PER_CYCLE} FLOP/cycle "
                 "(two 256-bit FMA pipes), times the threads used" if peak else "fp32 peak unknown (no clock)")
    body = (
        f"{BUILDS_SECTION}\n\n"
        "`python -m dls_quadruped.bench.mpc --builds-only` (also the last part of `make bench-mpc`): the "
        "`cpp` kernel built for this CPU (`native`), for `x86-64-v3` (AVX2 + FMA: how it runs on a machine without "
        "AVX-512) and without auto-vectorisation (`scalar`), timed side by side in one process, the builds taking "
        f"turns solve by solve; the solve of the table above at M = {m}, N = {n}, medians over "
        f"{rows[0]['solves']} solves; every build also has `{info.get('common_flags', '')}`. "
        "`solve` includes building the naive warm start; `kernel` is the C++ call alone inside the solve "
        "(`SamplingMPC.kernel_seconds`: the kernel and the argmin; the rest is validation, input cleaning and "
        "decoding the winner, see \"MPC solve path\"). "
        f"Machine: {info['cpu']}, {info['cpu_count']} cores at {info.get('cpu_mhz') or '?'} MHz, SIMD flags "
        f"{', '.join(info['simd_flags']) or '-'}, {info['compiler']}, torch {info['torch']}; load average "
        f"(1, 5, 15 min) at start {info['load_avg_1_5_15']} and end {info.get('load_avg_end')}: {load_note}.\n\n"
        + "".join(f"* {note}\n" for note in build_notes(rows)) + "\n"
        f"{builds_table(rows, peak)}\n\n"
        f"GFLOP/s take the kernel's work as {ROLLOUT_MFLOP:.0f} MFLOP per solve at M = 10 000, N = 10 (scaled by "
        f"M N); {peak_note}. Raw numbers: `results/bench/mpc_builds.json`.\n\n"
    )
    text = path.read_text() if path.exists() else "# Benchmarks\n"
    if BUILDS_SECTION in text:
        start, end = section_span(text, BUILDS_SECTION)
        text = text[:start] + body + text[end:]
    elif SECTION in text:
        _, end = section_span(text, SECTION)
        text = text[:end].rstrip("\n") + "\n\n" + body + text[end:]
    else:
        text = text.rstrip("\n") + "\n\n" + body
    path.write_text(text)


def run_builds(args: argparse.Namespace) -> None:
    """Time the C++ kernel builds side by side on 1 and on torch's threads; print, write JSON (and the docs page with
    ``--update-docs``)."""
    m, n = (4000, 5) if args.quick else (10000, 10)
    info = machine_info()
    mhz = _cpuinfo_field("cpu MHz")
    info.update(simd_flags=simd_flags(), cpu_mhz=float(mhz) if mhz else None,
                peak_gflops_per_core=peak_gflops_per_core(), compiler=compiler_version(),
                common_flags=" ".join([*cpp_kernel.COMMON_FLAGS, *cpp_kernel.extra_flags(cpp_kernel.compiler() or "")]))
    solves = min(args.solves, 10) if args.quick else args.solves
    rows = [row for threads in sorted({1, torch.get_num_threads()})
            for row in time_cpp_builds(m, n, solves, threads)]
    info["load_avg_end"] = list(os.getloadavg()) if hasattr(os, "getloadavg") else None
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "mpc_builds.json").write_text(json.dumps({"machine": info, "results": rows}, indent=2))
    print(f"C++ kernel builds, M = {m}, N = {n}, {info['cpu']} ({', '.join(info['simd_flags'])}), "
          f"load {info['load_avg_1_5_15']} -> {info['load_avg_end']}")
    print("\n".join(build_notes(rows)))
    print(builds_table(rows, info["peak_gflops_per_core"]))
    if args.update_docs and not args.quick:
        update_builds_docs(rows, info, args.docs)


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
        lines.append(f"| {dev} | {n} | {m} | {cell(fast, 'median_ms')} | {cell(fast, 'p90_ms')} | {cell(fast, 'min_ms')} | "
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
        rows = sorted((r for r in results if (r["device"], r["kernel"], r["N"]) == (dev, kernel, n)), key=lambda r: r["M"])
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
    ref10 = [r for r in results if r["kernel"] == "reference" and r["N"] == 10 and r["M"] == 10000 and r["device"] == "cpu"]
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
                        help="only re-render the table and plot (and with --update-docs the docs) from an existing mpc.json")
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

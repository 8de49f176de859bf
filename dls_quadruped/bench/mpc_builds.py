"""The MPC's C++ kernel built three ways and timed side by side (``python -m dls_quadruped.bench.mpc --builds-only``).

At M = 10 000, N = 10 the ``cpp`` kernel is built for the host (``-march=native``), for ``x86-64-v3`` (AVX2 +
FMA: a machine without AVX-512) and without auto-vectorisation (``scalar``); the builds take turns solve by
solve. Full solve and kernel call medians, speed-ups over ``scalar`` and the kernel's share of the machine's
fp32 peak go to results/bench/mpc_builds.json (and, with ``--update-docs``, the "## MPC C++ kernel builds"
section of docs/benchmarks.md).
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

from dls_quadruped.bench.mpc_common import (
    BUILDS_SECTION,
    SECTION,
    machine_info,
    section_span,
    solve_problem,
)
from dls_quadruped.core.progress import progress
from dls_quadruped.mpc import SamplerConfig, SamplingMPC, cpp_kernel, warm_start

ROLLOUT_MFLOP = 30.0
"""fp32 work of one solve's kernel at M = 10 000, N = 10 (an estimate from the kernel's arithmetic), scaled by M N
elsewhere."""
FLOP_PER_CYCLE = 32
"""fp32 FLOP per cycle and core with two 256-bit FMA pipes (2 x 8 lanes x 2): AMD Zen 2-4 (Zen 4 runs
AVX-512 on the same two 256-bit pipes), Intel cores since Haswell. Peak per core = clock x this."""
SIMD_FLAGS = ("sse4_2", "avx", "avx2", "fma", "avx512f", "avx512vl", "avx512bw", "avx512dq", "asimd", "sve")


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
                     f"{scalar['kernel_median_ms']:.2f} ms "
                     f"(speed-up {scalar['kernel_median_ms'] / r['kernel_median_ms']:.1f}x)")
    return notes


def update_builds_docs(rows: list[dict], info: dict, path: Path) -> None:
    """Replace the '## MPC C++ kernel builds' section of ``path`` (new: right after '## MPC solve time')."""
    peak = info.get("peak_gflops_per_core")
    m, n = rows[0]["M"], rows[0]["N"]
    load = max(info["load_avg_1_5_15"][0], (info.get("load_avg_end") or [0.0])[0])
    load_note = (f"the {info['cpu_count']} cores were shared with other jobs (load above 1.5), which hits the "
                 "multi-threaded rows hardest (OpenMP waits for a descheduled thread): compare builds within a "
                 "thread count, the 1-thread rows are the steadiest"
                 if load > 1.5 else "the machine was otherwise idle")
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

"""The sampling MPC's cost against work: ``python -m dls_quadruped.bench.mpc_scaling [--device cuda] [--out DIR]``.

One full :meth:`SamplingMPC.solve` (B robots x M samples, N = 10, first-spline, every variable sampled, two warm
starts 50/50: the naive one, whose shift is timed with the solve, and a 1.8 Hz trot) over the grid
M = 10^3 ... 10^6 x B = 1 ... 4 096, for one kernel on one device: on the CPU the ``cpp`` kernel (the CPU default)
once per ``--threads`` count (default 1 and 2), on CUDA the ``warp`` kernel. The problem, the per-point timing
and the skips are :mod:`dls_quadruped.bench.mpc_warp`'s (:func:`~dls_quadruped.bench.mpc_warp.sweep`): two warm-up
solves, then at most ``--solves`` solves or ``--point-s`` seconds (at least 3); points in order of work B M.

Per point: the median and quartiles of the solve time (the CPU: wall time of each solve; CUDA: CUDA-event time of
back-to-back solves, :func:`~dls_quadruped.bench.mpc_warp.per_call_ms`), the time per sample rollout (median / (B M),
ns), the calls per solve counted on one more solve (:func:`count_launches`), the 1-minute load average when the point
ended and the thread count. A point with B M > ``--max-work`` (the CPU default 5 x 10^7: one solve of 4 x 10^7 sample
rollouts takes ~7 s on one core of the 2-core VM, and the next grid size, 2.6 x 10^8, ~45 s a solve, 4-5 min a point
with its warm-up, per thread count) or whose predicted time exceeds what is left of ``--budget-s`` is a row with
``skipped`` = why. Writes ``DIR/mpc_scaling_<cpu|cuda>.json`` after every point and a plot
``DIR/mpc_scaling_<...>.png`` (solve time against M, a line per B; time per sample rollout against B M), and prints a
markdown table. ``--render F.json [G.json ...]`` only redraws the plot and the table from saved runs (several: the CPU
and the GPU run in one plot).
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path

import torch

from dls_quadruped.bench.gpu_probes import count_torch_ops
from dls_quadruped.bench.mpc_common import machine_info
from dls_quadruped.bench.mpc_warp import ArgumentParser, bench_device, run_cli, srbd_model, sweep
from dls_quadruped.core.json_io import write_json
from dls_quadruped.mpc import SamplingMPC

SAMPLES = (1000, 10000, 100000, 1000000)
ROBOTS = (1, 16, 256, 4096)
MAX_WORK = {"cpu": 5e7, "cuda": 4.2e9}
"""Largest B M timed by default: on the CPU (module doc); on CUDA the costs' 4 B M bytes (16 GiB at 4 096 x 10^6)."""
KERNEL_FUNCTIONS = ("mpc_solve", "mpc_costs")
"""The C++ rollout kernel's entry points (``mpc/rollout_kernel.cpp``): rollouts + costs (+ argmin)."""
GLUE_FUNCTIONS = ("clean_inputs", "winner_noise_args", "winner_sample", "winner_forces", "winner_decode",
                  "all_finite", "rotation_from_cos_sin")
"""The fused solve's other C++ entry points (``mpc/solve_glue.cpp``)."""
WARP_LAUNCHERS = ("launch", "launch_tiled", "capture_launch")


def count_launches(mpc: SamplingMPC, solve: Callable[[], object]) -> dict:
    """Calls made by one ``solve()`` of ``mpc`` (after its warm-up: libraries built, graphs captured).

    Returns ``{"launches": {...}}`` with ``kernel_calls`` (calls of the C++ rollout kernel, :data:`KERNEL_FUNCTIONS`),
    ``cpp_calls`` (every C++ call, the kernel's included; ``cpp_by_function``: per entry point), ``warp_launches``
    (``wp.launch``, ``wp.launch_tiled`` and ``wp.capture_launch`` calls: a graph replay counts one), ``graph_kernels``
    (the kernels in the device solve's graph; None without one) and ``torch_ops`` (operators dispatched from Python,
    views included, counted by the torch profiler: :func:`~dls_quadruped.bench.gpu_probes.count_torch_ops`).
    """
    counts: Counter = Counter()
    by_function: Counter = Counter()
    restore: list[tuple[object, str, object]] = []

    def counted(owner: object, name: str, kinds: tuple[str, ...]) -> None:
        original = getattr(owner, name)

        def wrapper(*a, **k):
            counts.update(kinds)
            if "cpp_calls" in kinds:
                by_function[name] += 1
            return original(*a, **k)

        restore.append((owner, name, original))
        setattr(owner, name, wrapper)

    fused = mpc.fused_solve
    for lib, names, kinds in ((fused.kernel_lib, KERNEL_FUNCTIONS, ("kernel_calls", "cpp_calls")),
                              (fused.lib, GLUE_FUNCTIONS, ("cpp_calls",))):
        for name in names if lib is not None else ():
            counted(lib, name, kinds)
    if importlib.util.find_spec("warp") is not None:
        import warp as wp

        for name in WARP_LAUNCHERS:
            counted(wp, name, ("warp_launches",))
    from torch.profiler import ProfilerActivity, profile

    try:
        with profile(activities=[ProfilerActivity.CPU]) as prof:
            solve()
            if mpc.device.type == "cuda":
                torch.cuda.synchronize(mpc.device)
    finally:
        for owner, name, original in reversed(restore):
            setattr(owner, name, original)
    work = mpc.last_device_solve
    launches = {k: counts[k] for k in ("kernel_calls", "cpp_calls", "warp_launches")}
    launches["graph_kernels"] = None if work is None else 3 + len(work.argmin.widths)
    launches["torch_ops"] = count_torch_ops(prof.events())[0]
    launches["cpp_by_function"] = dict(by_function)
    return {"launches": launches}


def probe(mpc: SamplingMPC, solve: Callable[[], object]) -> dict:
    """A timed point's extra entries: :func:`count_launches` and the 1-minute load average when its timing ended."""
    return {**count_launches(mpc, solve), "load_1min": os.getloadavg()[0] if hasattr(os, "getloadavg") else None}


def with_derived(row: dict, threads: int) -> dict:
    """``row`` with the thread count and the time per sample rollout [ns]."""
    row = {**row, "threads": threads}
    if "solve_ms" in row:
        row["ns_per_rollout"] = row["solve_ms"] * 1e6 / (row["B"] * row["M"])
    return row


def run(args: argparse.Namespace) -> dict:
    """The sweep(s) of the module doc; returns (and writes to ``args.out``) ``{"machine", "results"}``."""
    device = torch.device(args.device)
    kernel = args.kernel or ("warp" if device.type == "cuda" else "cpp")
    threads = args.threads if device.type == "cpu" else [torch.get_num_threads()]
    model, source = srbd_model()
    info = {**machine_info(), "device": str(device), "kernel": kernel, "srbd_model": source,
            "max_work": args.max_work, "budget_s_per_sweep": args.budget_s,
            "skip_rule": f"B M > {args.max_work:.3g} (--max-work), or the point's predicted time over what is left of "
                         f"{args.budget_s:.0f} s per thread count (--budget-s)"}
    if importlib.util.find_spec("warp") is not None:
        import warp as wp

        info["warp"] = wp.__version__
    out = args.out / f"mpc_scaling_{device.type}.json"
    args.out.mkdir(parents=True, exist_ok=True)
    done: list[dict] = []
    start, saved_threads = time.perf_counter(), torch.get_num_threads()

    def save(rows: list[dict]) -> dict:
        info["wall_s"] = time.perf_counter() - start
        info["load_avg_end"] = list(os.getloadavg()) if hasattr(os, "getloadavg") else None
        data = {"machine": info, "results": done + [with_derived(r, torch.get_num_threads()) for r in rows]}
        write_json(data, out)  # after every point: a crash keeps the rest
        return data

    try:
        for t in threads:
            torch.set_num_threads(t)
            rows = sweep(args, args.robots, args.samples, [kernel], device, model, probe=probe,
                         on_row=save, tag=f"mpc_scaling {t} thread{'s' if t > 1 else ''}")
            done += [with_derived(r, t) for r in rows]
    finally:
        torch.set_num_threads(saved_threads)
    data = save([])
    print(f"\n{info['cpu']}{', ' + info['cuda_device'] if 'cuda_device' in info else ''}, torch {info['torch']}\n\n"
          f"{table(data['results'])}\n\nwrote {out}")
    plot([data], out.with_suffix(".png"))
    return data


def config(row: dict) -> str:
    """The row's (device, kernel, threads) as a label."""
    threads = f", {row['threads']} thread{'s' if row['threads'] > 1 else ''}" if row["device"] == "cpu" else ""
    return f"{row['kernel']} {row['device']}{threads}"


def table(rows: list[dict]) -> str:
    """Markdown: a line per (B, M), per configuration (:func:`config`) the median [ms], the interquartile range and
    the time per sample rollout (a skipped point: "skipped"), then the calls per solve of the first timed row."""
    configs = list(dict.fromkeys(config(r) for r in rows))
    keyed = {(config(r), r["B"], r["M"]): r for r in rows}
    head = "| B | M | " + " | ".join(f"{c}: median [ms] | IQR [ms] | ns / rollout" for c in configs) + " | calls |"
    lines = [head, "|---|---|" + "---|---|---|" * len(configs) + "---|"]
    for b, m in sorted({(r["B"], r["M"]) for r in rows}):
        cells, calls = [], "-"
        for c in configs:
            r = keyed.get((c, b, m))
            if r is None or "skipped" in r:
                cells.append("skipped | | " if r is not None else "- | | ")
                continue
            cells.append(f"{r['solve_ms']:.4g} | {r['solve_q3_ms'] - r['solve_q1_ms']:.2g} | {r['ns_per_rollout']:.3g}")
            if calls == "-" and r.get("launches"):
                n = r["launches"]
                calls = (f"{n['kernel_calls']} kernel, {n['cpp_calls']} C++, " if n["kernel_calls"] else "") + (
                    f"{n['warp_launches']} Warp ({n['graph_kernels']} kernels), " if n["warp_launches"] else "") + (
                    f"{n['torch_ops']} torch ops")
        lines.append(f"| {b} | {m} | " + " | ".join(cells) + f" | {calls} |")
    return "\n".join(lines)


def plot(runs: list[dict], path: Path) -> None:
    """Two log-log panels from ``runs`` (saved JSONs): median solve time against M, a line per (configuration, B);
    time per sample rollout against B M, a line per configuration. Skipped points are not drawn."""
    try:
        import matplotlib
    except ImportError:
        print(f"matplotlib missing: no plot at {path}")
        return
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [r for data in runs for r in data["results"] if "solve_ms" in r]
    configs = list(dict.fromkeys(config(r) for r in rows))
    styles = ["-", "--", ":", "-."]
    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(12, 4.8))
    for i, c in enumerate(configs):
        mine = [r for r in rows if config(r) == c]
        for j, b in enumerate(sorted({r["B"] for r in mine})):
            line = sorted((r for r in mine if r["B"] == b), key=lambda r: r["M"])
            ax0.plot([r["M"] for r in line], [r["solve_ms"] for r in line], marker="o", color=f"C{j}",
                     linestyle=styles[i % len(styles)], label=f"B = {b}, {c}")
        line = sorted(mine, key=lambda r: (r["B"] * r["M"], r["B"]))
        ax1.plot([r["B"] * r["M"] for r in line], [r["ns_per_rollout"] for r in line], marker="o",
                 linestyle=styles[i % len(styles)], color=f"C{i}", label=c)
    ax0.set(xscale="log", yscale="log", xlabel="samples per robot M", ylabel="median solve time [ms]",
            title="One solve (N = 10), naive warm start included")
    ax1.set(xscale="log", yscale="log", xlabel="sample rollouts per solve B M", ylabel="time per rollout [ns]",
            title="Time per sample rollout")
    for ax in (ax0, ax1):
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    print(f"wrote {path}")


def main(argv: list[str] | None = None) -> int:
    p = ArgumentParser(prog="dls_quadruped.bench.mpc_scaling", description=__doc__.split("\n\n")[0])
    p.add_argument("--device", default="cpu", help="cpu (default) or cuda[:k]")
    p.add_argument("--kernel", default=None, help="cost kernel (default: cpp on the CPU, warp on CUDA)")
    p.add_argument("--samples", type=int, nargs="+", default=list(SAMPLES), help="M grid (default 10^3 ... 10^6)")
    p.add_argument("--robots", type=int, nargs="+", default=list(ROBOTS), help="B grid (default 1 16 256 4096)")
    p.add_argument("--threads", type=int, nargs="+", default=[1, 2], help="CPU thread counts, a sweep each")
    p.add_argument("--horizon", type=int, default=10)
    p.add_argument("--solves", type=int, default=30, help="timed solves per point at most (default 30)")
    p.add_argument("--point-s", type=float, default=3.0, help="seconds of timed solves per point at most")
    p.add_argument("--budget-s", type=float, default=400.0, help="seconds per sweep: then the rest is skipped")
    p.add_argument("--max-work", type=float, default=None, help="largest B M timed (default: 5e7 CPU, 4.2e9 CUDA)")
    p.add_argument("--out", type=Path, default=Path(os.environ.get("OUT", "results/bench")), help="output folder")
    p.add_argument("--render", type=Path, nargs="+", default=None, help="only redraw plot and table from JSONs")
    args = p.parse_args(argv)
    if args.render is not None:
        runs = [json.loads(f.read_text()) for f in args.render]
        print(table([r for data in runs for r in data["results"]]))
        plot(runs, args.out / "mpc_scaling.png")
        return 0
    device = bench_device(p, args.device)
    if min(args.solves, args.horizon, *args.threads, *args.samples, *args.robots) < 1 or args.budget_s <= 0:
        p.error("--solves, --horizon, --threads, --samples and --robots must be >= 1 and --budget-s > 0")
    if args.max_work is None:
        args.max_work = MAX_WORK[device.type]
    run(args)
    return 0


if __name__ == "__main__":
    if run_cli is not None:
        run_cli(main)  # a bad flag or a user error: one line, exit 2; Ctrl-C: one line, exit 130
    else:
        main()

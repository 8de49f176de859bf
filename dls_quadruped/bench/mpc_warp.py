"""The ``warp`` MPC kernel's cost against work: ``python -m dls_quadruped.bench.mpc_warp [--device cuda] [--out F]``.

One :meth:`SamplingMPC.solve` (the device solve, ``mpc/warp_solve.py``) for B robots x M samples, N = 10,
first-spline, every variable sampled, two warm starts 50/50 (the naive one and a 1.8 Hz trot), over a grid of
(B, M) taken in order of work B M until ``--budget-s`` is spent (the rest recorded as skipped). Per point, after a
launched and a captured warm-up solve:

* ``solve_ms``: back-to-back solves, on CUDA the CUDA-event time of a run divided by its solves (what one solve
  costs in a loop that never waits for it; the median of five runs, ``solve_q1_ms`` and ``solve_q3_ms`` their
  quartiles), on the CPU the median wall time (and its quartiles);
* ``graph_ms``: the captured graph's replay alone (clean, rollout, argmin, decode; inputs already staged), same
  timing: the kernels' time;
* ``latency_ms``: on CUDA, one solve then a synchronisation, median wall time (what a caller that reads the action
  at once waits).

On the CPU (Warp's CPU device) the ``cpp`` kernel's fused solve is timed on the same problems, side by side. First,
unless ``--no-check``, the kernel's costs against the eager ``reference`` kernel on the same device and a captured
device solve against a launched one, and on CUDA three solves under ``torch.cuda.set_sync_debug_mode("error")``
(:func:`check`, recorded in the JSON's ``machine.check``).
Writes JSON (``--out``, atomically) and prints a table. Imports neither MuJoCo nor YAML: the SRBD model comes from
the MJCF when MuJoCo is installed, else :data:`ALIENGO_SRBD` (the same model, computed once from the MJCF), so the
command runs on a GPU node that has only torch, numpy and Warp.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import torch

from dls_quadruped.core.json_io import write_json
from dls_quadruped.mpc import SamplerConfig, SamplingMPC, warm_start
from dls_quadruped.mpc.cost import Refs
from dls_quadruped.mpc.srbd import SRBDModel, SRBDState

try:  # the package's command-line conventions; cli.py imports YAML, which a bare GPU node may lack
    from dls_quadruped.cli import ArgumentParser, run_cli
except ImportError:
    run_cli = None

    class ArgumentParser(argparse.ArgumentParser):  # type: ignore[no-redef]
        """cli.ArgumentParser's one-line usage errors, without YAML."""

        def error(self, message: str):
            self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


GPU_SAMPLES = (1000, 10000, 100000, 1000000)
GPU_ROBOTS = (1, 64, 1024, 4096)
CPU_SAMPLES = (1000, 10000)
CPU_ROBOTS = (1, 16)
ALIENGO_SRBD = SRBDModel(
    mass=24.638,
    inertia_b=((0.22148251092161403, -0.0006191474556409126, -0.02082519721224049),
               (-0.0006191474556409126, 0.8879052933889475, -0.0006588704975292615),
               (-0.02082519721224049, -0.0006588704975292615, 0.9231738820701274)),
    com_offset_b=(-0.0033721799572436458, 0.0021439310820683495, -0.013543417141719805), gravity=9.81)
"""``srbd.robot_srbd_model()`` as computed from the MJCF's home keyframe: the model when MuJoCo is missing."""


def srbd_model() -> tuple[SRBDModel, str]:
    """(the SRBD model, where it came from)."""
    try:
        from dls_quadruped.mpc.srbd import robot_srbd_model

        return robot_srbd_model(), "MJCF"
    except ImportError:
        return ALIENGO_SRBD, "ALIENGO_SRBD (no MuJoCo)"


def problem(b: int, device: torch.device) -> tuple[SRBDState, Refs, torch.Tensor]:
    """B robots at 0.32 m, 0.3 m/s forward with a little roll, pitch and roll rate (bench/mpc_common.solve_problem's
    robot, each with its own yaw and gait phase), asked for 0.5 m/s at 0.33 m."""
    gen = torch.Generator().manual_seed(0)
    feet = torch.tensor([[0.24, 0.134, 0.0265], [0.24, -0.134, 0.0265], [-0.24, 0.134, 0.0265],
                         [-0.24, -0.134, 0.0265]]).expand(b, 4, 3).clone()
    euler = torch.tensor([[0.02, -0.01, 0.0]]).repeat(b, 1)
    euler[:, 2] = 0.3 * torch.randn(b, generator=gen)
    state = SRBDState(torch.tensor([[0.0, 0.0, 0.32]]).repeat(b, 1), torch.tensor([[0.3, 0.0, 0.0]]).repeat(b, 1),
                      euler, torch.tensor([[0.1, 0.0, 0.0]]).repeat(b, 1), feet).to(device)
    refs = Refs(torch.full((b,), 0.33), torch.tensor([[0.5, 0.0]]).repeat(b, 1), torch.zeros(b),
                feet.clone()).to(device)
    phase = (torch.tensor([[0.1, 0.6, 0.6, 0.1]]) + torch.rand(b, 1, generator=gen)) % 1.0
    return state, refs, phase.to(device)


def predict_s(timed: list[dict], work: int) -> float:
    """Seconds a point of B M = ``work`` will take (~8 solves: 2 warm-up, >= 3 timed, >= 3 replays), from the last two
    timed points (in order of work) as a fixed cost plus a cost per sample; 0 before any."""
    if not timed:
        return 0.0
    last = timed[-1]
    w1, t1 = last["B"] * last["M"], last["solve_ms"]
    rate = 0.0
    if len(timed) > 1:
        w0, t0 = timed[-2]["B"] * timed[-2]["M"], timed[-2]["solve_ms"]
        rate = max(0.0, (t1 - t0) / (w1 - w0)) if w1 > w0 else 0.0
    return 8e-3 * (t1 + rate * max(0, work - w1))


def time_point(b: int, m: int, n: int, kernel: str, device: torch.device, model: SRBDModel, solves: int,
               point_s: float, probe: Callable[[SamplingMPC, Callable], dict] | None = None) -> dict:
    """One grid point (module doc); at most ~``point_s`` seconds of timed solves after the warm-up. ``probe(mpc,
    solve)``, when given, runs after the timing and its entries join the row (e.g. launch counts)."""
    cfg = SamplerConfig(num_samples=m, horizon=n, kernel=kernel)
    mpc = SamplingMPC(cfg, model=model, device=device, seed=0)
    state, refs, phase = problem(b, device)
    default = warm_start.nominal_trot(b, cfg).to(device)
    trot = warm_start.nominal_trot(b, cfg, freq=1.8).to(device)
    cuda = device.type == "cuda"
    sync = (lambda: torch.cuda.synchronize(device)) if cuda else (lambda: None)

    def solve():
        return mpc.solve(state, refs, [mpc.naive_warm_start(default), trot], proportions=(0.5, 0.5), phase=phase)

    tic = time.perf_counter()
    solve()
    sync()
    first_s = time.perf_counter() - tic
    tic = time.perf_counter()
    solve()  # the device solve captures its graph here
    sync()
    second_s = time.perf_counter() - tic
    count = max(3, min(solves, int(point_s / max(second_s, 1e-6))))
    row = {"B": b, "M": m, "N": n, "kernel": kernel, "device": str(device), "solves": count,
           "first_call_s": first_s, "second_call_s": second_s}
    work = mpc.last_device_solve
    graph = None if work is None else work.execute
    row["solve_ms"], row["solve_q1_ms"], row["solve_q3_ms"] = per_call_ms(solve, count, device)
    row["graph_ms"] = per_call_ms(graph, count, device)[0] if graph is not None else None
    if cuda and b * m <= 1e8:  # big points: the back-to-back time is the latency already
        lat = []
        for _ in range(count):
            tic = time.perf_counter()
            solve()
            sync()
            lat.append((time.perf_counter() - tic) * 1e3)
        row["latency_ms"] = statistics.median(lat)
    row["launches_per_solve"] = None if work is None else 3 + len(work.argmin.widths)
    row["captured"] = None if work is None else bool(work.graph.graph is not None)
    if probe is not None:
        row.update(probe(mpc, solve))
    return row


def per_call_ms(fn: Callable[[], object], count: int, device: torch.device) -> tuple[float, float, float]:
    """(median, first quartile, third quartile) [ms] of one of ``count`` calls of ``fn``: on CUDA over five runs
    of back-to-back calls (one run when ``count`` < 5), each its CUDA-event time / its calls; on the CPU over the
    calls' wall times."""
    times = []
    if device.type == "cuda":
        runs = 5 if count >= 5 else 1
        start, end = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
        torch.cuda.synchronize(device)
        for _ in range(runs):
            start.record()
            for _ in range(count // runs):
                fn()
            end.record()
            end.synchronize()
            times.append(start.elapsed_time(end) / (count // runs))
    else:
        for _ in range(count):
            tic = time.perf_counter()
            fn()
            times.append((time.perf_counter() - tic) * 1e3)
    if len(times) < 2:
        return times[0], times[0], times[0]
    q1, median, q3 = statistics.quantiles(times, n=4, method="inclusive")
    return median, q1, q3


def check(device: torch.device, model: SRBDModel) -> dict:
    """The kernel against the eager ``reference`` kernel on ``device`` (B = 8, M = 512, N = 10, two warm-start groups)
    and a captured device solve against a launched one; on CUDA, whether torch counts a synchronising op in three
    captured solves: a few seconds, before any timing."""
    from dls_quadruped.mpc.kernel import KernelInputs, reference_costs
    from dls_quadruped.mpc.samples import group_layout
    from dls_quadruped.mpc.warp_argmin import warp_argmin
    from dls_quadruped.mpc.warp_kernel import warp_costs

    cfg = SamplerConfig(num_samples=512, horizon=10)
    b = 8
    state, refs, phase = problem(b, device)
    ws0 = warm_start.nominal_trot(b, cfg).to(device)
    group, perturb, _ = group_layout(cfg.num_samples, (0.5, 0.5))
    inp = KernelInputs(torch.tensor(77, device=device), torch.stack([ws0, warm_start.nominal_trot(
        b, cfg, freq=1.8).to(device)], dim=1), group.to(device), perturb.to(device), state.as_vector(), phase,
        0.1 * torch.ones(b, 2, device=device), state.euler[:, 2].contiguous(), torch.zeros(b, 4, device=device), refs)
    costs, ref = warp_costs(inp, cfg, model), reference_costs(inp, cfg, model)
    rel = ((costs - ref).abs() / ref.abs().clamp_min(1.0)).flatten()
    _, index = warp_argmin(costs)
    out = {"max_rel_vs_reference": float(rel.max()), "median_rel_vs_reference": float(rel.median()),
           "argmin_same_as_reference": float((index == ref.min(dim=1).indices).float().mean())}
    results, mpcs = [], []
    for capture in (True, False):
        mpc = SamplingMPC(SamplerConfig(num_samples=512, horizon=10, kernel="warp"), model=model, device=device)
        mpc.capture = capture
        for _ in range(3):
            r = mpc.solve(state, refs, [mpc.naive_warm_start(ws0)], phase=phase)
        results.append(r)
        mpcs.append(mpc)
    out["captured_equals_launched"] = bool(torch.equal(results[0].best_encoded, results[1].best_encoded)
                                           and torch.equal(results[0].best_index, results[1].best_index))
    if device.type == "cuda":  # torch's own count of synchronising ops in 3 solves (naive warm start included)
        mpc = mpcs[0]  # the captured one
        torch.cuda.set_sync_debug_mode("error")
        try:
            for _ in range(3):
                mpc.solve(state, refs, [mpc.naive_warm_start(ws0)], phase=phase)
            out["torch_sync_in_solve"] = "none"
        except RuntimeError as err:
            out["torch_sync_in_solve"] = str(err).splitlines()[0][:300]
        finally:
            torch.cuda.set_sync_debug_mode("default")
    return out


def sweep(args: argparse.Namespace, robots: Sequence[int], samples: Sequence[int], kernels: Sequence[str],
          device: torch.device, model: SRBDModel, probe: Callable[[SamplingMPC, Callable], dict] | None = None,
          on_row: Callable[[list[dict]], None] | None = None, tag: str = "mpc_warp") -> list[dict]:
    """Rows of :func:`time_point` over ``robots`` x ``samples`` x ``kernels``, in order of work B M; ``args`` holds
    ``horizon``, ``solves``, ``point_s``, ``budget_s`` and ``max_work``. A point with B M > ``max_work``, or one
    whose predicted time (:func:`predict_s`) exceeds what is left of ``budget_s`` seconds (the first point always
    runs), or out of memory, is a row with ``skipped`` = why. ``on_row(rows)`` after every row (e.g. write the
    JSON); progress lines on stdout start with ``[tag]``."""
    points = sorted(((b, m) for b in robots for m in samples), key=lambda bm: (bm[0] * bm[1], bm[1]))
    rows: list[dict] = []
    start = time.perf_counter()
    for b, m in points:
        for kernel in kernels:
            base = {"B": b, "M": m, "N": args.horizon, "kernel": kernel, "device": str(device)}
            timed = [r for r in rows if "solve_ms" in r and r["kernel"] == kernel]
            left = args.budget_s - (time.perf_counter() - start)
            predicted = predict_s(timed, b * m)
            if b * m > args.max_work:
                rows.append({**base, "skipped": f"B M = {b * m:.3g} > --max-work {args.max_work:.3g}"})
            elif any("solve_ms" in r for r in rows) and (left <= 0 or predicted > left):
                rows.append({**base, "skipped": "over --budget-s" if left <= 0 else
                             f"predicted {predicted:.0f} s > the {left:.0f} s left of --budget-s"})
            else:
                try:
                    rows.append(time_point(b, m, args.horizon, kernel, device, model, args.solves, args.point_s,
                                           probe))
                except torch.cuda.OutOfMemoryError:
                    rows.append({**base, "skipped": "out of memory"})
                r = rows[-1]
                graph = f", graph {r['graph_ms']:.3f} ms" if r.get("graph_ms") is not None else ""
                print(f"[{tag}] {kernel} {device} B={b} M={m}: " + (r.get("skipped") or
                      f"solve {r['solve_ms']:.3f} ms{graph}"), flush=True)
            if on_row is not None:
                on_row(rows)
            if device.type == "cuda":
                torch.cuda.empty_cache()
    return rows


def bench_device(p: argparse.ArgumentParser, text: str) -> torch.device:
    """``--device`` as a torch device: the CPU or an available CUDA device, else a one-line usage error."""
    try:
        device = torch.device(text)
    except RuntimeError as err:
        p.error(f"--device: {err}")
    if device.type not in ("cpu", "cuda") or (device.type == "cuda" and not torch.cuda.is_available()):
        p.error(f"--device must be cpu or an available cuda device, got {text!r}")
    return device


def table(rows: list[dict]) -> str:
    """Markdown: one line per (device, kernel, B, M)."""
    lines = ["| device | kernel | B | M | solve [ms] | graph [ms] | latency [ms] | samples/s | first call [s] |",
             "|---|---|---|---|---|---|---|---|---|"]
    cell = lambda v, f: "-" if v is None else format(v, f)
    for r in rows:
        if "skipped" in r:
            lines.append(f"| {r['device']} | {r['kernel']} | {r['B']} | {r['M']} | {r['skipped']} | | | | |")
            continue
        rate = r["B"] * r["M"] / (r["solve_ms"] * 1e-3)
        lines.append(f"| {r['device']} | {r['kernel']} | {r['B']} | {r['M']} | {r['solve_ms']:.3f} | "
                     f"{cell(r['graph_ms'], '.3f')} | {cell(r.get('latency_ms'), '.3f')} | {rate:.3g} | "
                     f"{r['first_call_s']:.1f} |")
    return "\n".join(lines)


def machine(device: torch.device) -> dict:
    import warp as wp

    info = {"cpu": platform.processor() or platform.machine(), "cpu_count": os.cpu_count(), "torch": torch.__version__,
            "warp": wp.__version__, "python": platform.python_version(), "torch_threads": torch.get_num_threads(),
            "load_avg_1_5_15": list(os.getloadavg()) if hasattr(os, "getloadavg") else None}
    try:
        from dls_quadruped.core.machine import cpu_model

        info["cpu"] = cpu_model()
    except ImportError:
        pass
    if device.type == "cuda":
        info["gpu"] = torch.cuda.get_device_name(device)
    return info


def main(argv: list[str] | None = None) -> int:
    p = ArgumentParser(prog="dls_quadruped.bench.mpc_warp", description=__doc__.split("\n\n")[0])
    p.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu", help="cpu or cuda[:k]")
    p.add_argument("--samples", type=int, nargs="+", default=None, help="M grid (default: 10^3 ... 10^6 on CUDA)")
    p.add_argument("--robots", type=int, nargs="+", default=None, help="B grid (default: 1 64 1024 4096 on CUDA)")
    p.add_argument("--horizon", type=int, default=10)
    p.add_argument("--solves", type=int, default=50, help="timed solves per point at most (default 50)")
    p.add_argument("--point-s", type=float, default=2.0, help="seconds of timed solves per point at most")
    p.add_argument("--budget-s", type=float, default=120.0,
                   help="seconds for the run: once spent, the remaining points are skipped (the first always runs)")
    p.add_argument("--max-work", type=float, default=4.2e9, help="largest B M timed (costs: 4 B M bytes)")
    p.add_argument("--no-cpp", action="store_true", help="on the CPU, skip the cpp kernel's rows")
    p.add_argument("--no-check", action="store_true", help="skip the check against the reference kernel")
    p.add_argument("--threads", type=int, default=0, help="torch CPU threads (default: torch's choice)")
    p.add_argument("--out", type=Path, default=Path(os.environ.get("OUT", "results/bench")) / "mpc_warp.json")
    args = p.parse_args(argv)
    device = bench_device(p, args.device)
    if min(args.solves, args.horizon) < 1 or args.budget_s <= 0:
        p.error("--solves and --horizon must be >= 1 and --budget-s > 0")
    if args.threads > 0:
        torch.set_num_threads(args.threads)
    cuda = device.type == "cuda"
    ms = args.samples or (GPU_SAMPLES if cuda else CPU_SAMPLES)
    bs = args.robots or (GPU_ROBOTS if cuda else CPU_ROBOTS)
    kernels = ["warp"] + ([] if cuda or args.no_cpp else ["cpp"])
    model, source = srbd_model()
    info = {**machine(device), "srbd_model": source}
    if not args.no_check:
        tic = time.perf_counter()
        info["check"] = check(device, model)
        print(f"[mpc_warp] check ({time.perf_counter() - tic:.1f} s, Warp compiles included): {info['check']}",
              flush=True)
    start = time.perf_counter()
    args.out.parent.mkdir(parents=True, exist_ok=True)

    def save(rows: list[dict]) -> None:
        info["wall_s"] = time.perf_counter() - start
        write_json({"machine": info, "results": rows}, args.out)  # after every point: a crash keeps the rest

    rows = sweep(args, bs, ms, kernels, device, model, on_row=save)
    print(f"\n{info.get('gpu', info['cpu'])}, torch {info['torch']}, warp {info['warp']}\n\n{table(rows)}\n\n"
          f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    if run_cli is not None:
        run_cli(main)  # a bad flag or a user error: one line, exit 2; Ctrl-C: one line, exit 130
    else:
        sys.exit(main())

"""Closed-loop throughput: ``python -m dls_quadruped.bench.closed_loop``.

Runs the student-warm-started MPC (``rl_warm_start``) and the naive MPC on the simple task for B robots
in one env, M = 10 000, N = 10, one batched solve of B x M samples per MPC step (100 Hz), and reports
simulated robot-seconds per wall-second with the wall time split into the MPC cost kernel, the rest
of the solves (warm starts, validation, decoding the winner), the policy queries, the initial-cost
metric, and the env + simulator (physics, low-level control, observations, rewards). In the same
process it times the kernel alone for one robot (M = 10 000, N = 10), so the throughput can be read
against the machine's kernel speed (our machines differ by 3-5x there).

With ``--paths fused torch`` (``make bench-closed-loop``: B = 16 and 64) each row runs on the fused solve
(``SamplingMPC.fused``) and on the torch path around the kernel, back to back in the same process: the kernel's share of
the wall time, the robot-seconds per second of the two and their ratio, and robot-seconds per CPU-second of the process
(what other jobs on shared cores do not inflate).

With ``--students 1 2`` each ``rl_warm_start`` row runs with one student and with the same student twice (two
sample groups sharing the M samples of one batched solve): a multi-policy solve should cost
what a single one does at equal M.

Writes results/bench/closed_loop.json and prints a markdown table.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

import torch

from dls_quadruped.cli import ArgumentParser, run_cli
from dls_quadruped.closed_loop.controllers import ControllerConfig, make_controller
from dls_quadruped.closed_loop.episodes import (
    DEFAULT_POLICY,
    DEFAULT_STUDENT,
    commands,
    make_env,
)
from dls_quadruped.closed_loop.loop import run_closed_loop
from dls_quadruped.core.json_io import write_json
from dls_quadruped.core.machine import cpu_model
from dls_quadruped.core.progress import progress
from dls_quadruped.mpc.config import SamplerConfig


def kernel_alone(samples: int, horizon: int, solves: int = 30) -> float:
    """Median [s] of the cost kernel alone for one robot (forces only, first-spline), after warm-up."""
    from dls_quadruped.mpc import warm_start
    from dls_quadruped.mpc.cost import Refs
    from dls_quadruped.mpc.sampler import SamplingMPC
    from dls_quadruped.mpc.srbd import SRBDState

    cfg = SamplerConfig(num_samples=samples, horizon=horizon, sigma_f=0.0, sigma_d=0.0, sigma_p=0.0)
    mpc = SamplingMPC(cfg)
    feet = torch.tensor([[[0.24, 0.13, 0.02], [0.24, -0.13, 0.02], [-0.24, 0.13, 0.02], [-0.24, -0.13, 0.02]]])
    state = SRBDState(torch.tensor([[0.0, 0.0, 0.32]]), torch.zeros(1, 3), torch.zeros(1, 3), torch.zeros(1, 3), feet)
    refs = Refs(torch.tensor([0.32]), torch.tensor([[0.5, 0.0]]), torch.zeros(1), feet.clone())
    ws = warm_start.nominal_trot(1, cfg)
    times = []
    for k in range(solves + 3):
        before = mpc.kernel_seconds
        mpc.solve(state, refs, [ws], phase=torch.zeros(1, 4))
        if k >= 3:
            times.append(mpc.kernel_seconds - before)
    return statistics.median(times)


def run(controller: str, robots: int, seconds: float, samples: int, horizon: int, num_workers: int,
        path: str = "fused", students: int = 1) -> dict:
    """One closed loop of ``robots`` robots for ``seconds``; ``path``: "fused" or "torch" (SamplingMPC.fused);
    ``students``: rl_warm_start with the student this many times (one sample group each)."""
    env = make_env(commands(robots, 0, None), seconds, seed=0, num_workers=num_workers)
    try:
        student = DEFAULT_STUDENT if students == 1 or controller != "rl_warm_start" else (DEFAULT_STUDENT,) * students
        cfg = ControllerConfig(controller, policy=DEFAULT_POLICY, student=student,
                               sampler=SamplerConfig(num_samples=samples, horizon=horizon))
        ctrl = make_controller(cfg, env)
        ctrl.mpc.fused = path == "fused"
        run_closed_loop(env, ctrl, num_steps=5)  # warm-up: kernel build, layouts, worker start
        ctrl.mpc.kernel_seconds, ctrl.solve_seconds = 0.0, 0.0
        cpu0 = time.process_time()
        tr = run_closed_loop(env, ctrl, num_steps=round(seconds / env.step_dt))
        cpu = time.process_time() - cpu0  # this process's CPU time: what other jobs on the cores do not inflate
    finally:
        env.close()
    t = tr.timing
    wall = t["wall"]
    return {"controller": controller, "path": path, "students": students, "robots": robots, "seconds": seconds,
            "samples": samples, "horizon": horizon,
            "num_workers": num_workers, "robot_seconds_per_second": t["robot_seconds_per_second"],
            "robot_seconds_per_cpu_second": robots * seconds / cpu, "cpu_s": cpu,
            "wall_s": wall, "share": {k: t[k] / wall for k in ("kernel", "policy", "probe", "env_and_sim")}
            | {"solve_without_kernel": (t["solve"] - t["kernel"]) / wall},
            "kernel_ms_per_solve": 1e3 * t["kernel"] / (2 * round(seconds / 0.02)),
            "survived": int((~tr.fell).sum())}


def main(argv: list[str] | None = None) -> dict:
    p = ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--robots", type=int, nargs="+", default=[4, 16])
    p.add_argument("--controllers", nargs="+", default=["rl_warm_start", "naive_warm_start"])
    p.add_argument("--seconds", type=float, default=3.0, help="simulated seconds per measurement")
    p.add_argument("--samples", type=int, default=10000)
    p.add_argument("--horizon", type=int, default=10)
    p.add_argument("--threads", type=int, nargs="+", default=[1], help="torch / kernel threads to measure")
    p.add_argument("--num-workers", type=int, nargs="+", default=[0], help="simulator processes (0: in-process)")
    p.add_argument("--paths", nargs="+", default=["fused"], choices=["fused", "torch"],
                   help="solve paths around the kernel, run back to back per row (SamplingMPC.fused)")
    p.add_argument("--students", type=int, nargs="+", default=[1],
                   help="rl_warm_start: run with the student this many times (sample groups), e.g. 1 2")
    p.add_argument("--out", type=Path, default=Path("results/bench"))
    args = p.parse_args(argv)
    rows = []
    load_start = os.getloadavg()
    bar = progress(total=len(args.threads) * len(args.num_workers) * len(args.robots) * len(args.controllers)
                   * len(args.paths) * len(args.students),
                   desc="configurations", unit="config")
    for threads in args.threads:
        torch.set_num_threads(threads)
        kernel = kernel_alone(args.samples, args.horizon)
        for workers in args.num_workers:
            for robots in args.robots:
                for ctrl, path, n in ((c, q, n) for c in args.controllers for q in args.paths for n in args.students):
                    if n > 1 and ctrl != "rl_warm_start":
                        continue
                    r = run(ctrl, robots, args.seconds, args.samples, args.horizon, workers, path, n)
                    r.update({"threads": threads, "kernel_alone_ms_B1": 1e3 * kernel})
                    rows.append(r)
                    print(f"[bench.closed_loop] {ctrl} ({path}, {n} student group(s)) B={robots} threads={threads} "
                          f"workers={workers}: "
                          f"{r['robot_seconds_per_second']:.2f} robot-s/s, kernel {100 * r['share']['kernel']:.0f} %, "
                          f"kernel alone (B=1) {1e3 * kernel:.2f} ms", flush=True)
                    bar.update(1)
    bar.close()
    res = {"cpu": cpu_model(), "load_avg_at_start": load_start, "load_avg_at_end": os.getloadavg(),
           "torch": torch.__version__, "rows": rows}
    args.out.mkdir(parents=True, exist_ok=True)
    write_json(res, args.out / "closed_loop.json", indent=1)
    print(f"{res['cpu']}, load average {[round(x, 2) for x in load_start]} -> "
          f"{[round(x, 2) for x in res['load_avg_at_end']]}")
    print("| controller | path | groups | B | threads | sim workers | robot-s/s | vs torch path | robot-s per CPU-s | "
          "vs torch path "
          "| kernel | rest of solve | policy | probe | env+sim | kernel alone B=1 [ms] |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    key = lambda r: (r["controller"], r["students"], r["robots"], r["threads"], r["num_workers"])
    torch_rows = {key(r): r for r in rows if r["path"] == "torch"}
    for r in rows:
        s, ref = r["share"], torch_rows.get(key(r))
        speed, speed_cpu = (f"{r[k] / ref[k]:.2f}x" if ref else "-"
                            for k in ("robot_seconds_per_second", "robot_seconds_per_cpu_second"))
        print(f"| {r['controller']} | {r['path']} | {r['students']} | {r['robots']} | {r['threads']} | "
              f"{r['num_workers']} | {r['robot_seconds_per_second']:.2f} | {speed} | "
              f"{r['robot_seconds_per_cpu_second']:.2f} | {speed_cpu} | "
              f"{100 * s['kernel']:.0f} % | "
              f"{100 * s['solve_without_kernel']:.0f} % | {100 * s['policy']:.0f} % | {100 * s['probe']:.0f} % | "
              f"{100 * s['env_and_sim']:.0f} % | {r['kernel_alone_ms_B1']:.2f} |")
    return res


if __name__ == "__main__":
    tic = time.perf_counter()
    run_cli(main)  # a bad flag or a user error: one line, exit 2; Ctrl-C: one line, exit 130
    print(f"[bench.closed_loop] {time.perf_counter() - tic:.0f} s")

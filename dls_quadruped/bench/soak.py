"""Soak: does a long training run keep its memory and open files flat? ``python -m dls_quadruped.bench.soak``.

    python -m dls_quadruped.bench.soak --minutes 60 --out results/bench        # base, 64 robots, 1 worker
    python -m dls_quadruped.bench.soak --minutes 5 -- python -m dls_quadruped.learning.train --task rough ...

Starts the command (default: :data:`DEFAULT_TRAIN`, a base training run with one simulator worker process, long
enough to be stopped by its own ``--time-limit`` = ``--minutes``) as a child process and, every ``--every-s``
seconds, reads from ``/proc`` the resident memory (``VmRSS``) and the open file descriptors of the child and of
all its descendants (the simulator workers), summed. After the warm-up (the first ``--warmup-frac`` of the samples:
imports, the env's build, the first allocations) it fits a line to each series over time. The run is **flat** when
the memory grows by less than ``--max-rss-mib-per-h`` and the descriptors stay within ``--max-fd-change`` of their
first post-warm-up value. Writes ``DIR/soak.json`` (the samples, the fits and the verdict; rewritten after every
sample, so a run cut short keeps what it measured) and prints the verdict; Linux only (``/proc``).

The judged window is the run itself, not its end: the default command's ``--time-limit`` lies
:data:`CLOSE_SLACK_S` past ``--minutes``, so it is still training when the window ends. The soak then sends SIGTERM
(the trainer finishes its iteration, saves and exports) and keeps sampling until the child exits, into
``closing`` (its own samples, reported beside the verdict, not fitted), killing it :data:`CLOSE_WAIT_S` later.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from dls_quadruped.bench.mpc_common import machine_info
from dls_quadruped.cli import ArgumentParser, UserError, run_cli
from dls_quadruped.core.json_io import write_json

DEFAULT_TRAIN = ("-m", "dls_quadruped.learning.train", "--task", "base", "--num-envs", "64", "--iterations", "1000000",
                 "--num-workers", "1", "--update-threads", "1", "--save-interval", "50")
"""The default soaked command (after the interpreter): base, 64 robots, one worker, checkpoints every 50 iterations."""
CLOSE_SLACK_S = 600.0
"""Seconds the default command's ``--time-limit`` lies past the window, so it does not start closing inside it."""
CLOSE_WAIT_S = 120.0
"""Seconds the closing (after SIGTERM) is sampled before the child is killed."""


def descendants(pid: int) -> list[int]:
    """``pid`` and every process below it (``/proc/<pid>/task/<tid>/children``), parents first."""
    out, todo = [], [pid]
    while todo:
        p = todo.pop(0)
        out.append(p)
        try:
            for task in os.listdir(f"/proc/{p}/task"):
                with open(f"/proc/{p}/task/{task}/children") as fh:
                    todo += [int(c) for c in fh.read().split()]
        except (FileNotFoundError, ProcessLookupError, PermissionError):
            continue  # it ended between the reads
    return out


def usage(pid: int) -> dict:
    """Resident memory [MiB] and open file descriptors of ``pid`` and its descendants, summed, and how many."""
    rss_kib, fds, procs = 0, 0, 0
    for p in descendants(pid):
        try:
            with open(f"/proc/{p}/status") as fh:
                rss_kib += next((int(line.split()[1]) for line in fh if line.startswith("VmRSS:")), 0)
            fds += len(os.listdir(f"/proc/{p}/fd"))
            procs += 1
        except (FileNotFoundError, ProcessLookupError):
            continue
    return {"rss_mib": rss_kib / 1024.0, "fds": fds, "processes": procs}


def flatness(samples: list[dict], warmup_frac: float, max_rss_mib_per_h: float, max_fd_change: int) -> dict:
    """Fits and verdict over the samples after the warm-up: memory slope [MiB/h] (least squares over time), the
    descriptors' range against their first post-warm-up value, and ``flat``; ``flat`` is None with fewer than 3
    samples after the warm-up."""
    rest = samples[int(len(samples) * warmup_frac):]
    if len(rest) < 3:
        return {"samples_fitted": len(rest), "flat": None}
    t = np.array([s["t_s"] for s in rest]) / 3600.0
    rss = np.array([s["rss_mib"] for s in rest])
    fds = np.array([s["fds"] for s in rest])
    slope = float(np.polyfit(t, rss, 1)[0]) if np.ptp(t) > 0 else 0.0
    change = int(max(abs(fds.max() - fds[0]), abs(fds.min() - fds[0])))
    return {"samples_fitted": len(rest), "window_s": float(3600.0 * np.ptp(t)), "rss_mib_first": float(rss[0]),
            "rss_mib_last": float(rss[-1]), "rss_mib_per_h": slope, "fds_first": int(fds[0]),
            "fds_min": int(fds.min()), "fds_max": int(fds.max()), "fd_change": change,
            "flat": bool(slope < max_rss_mib_per_h and change <= max_fd_change)}


def soak(command: list[str], minutes: float, every_s: float, out: Path, limits: dict,
         close_wait_s: float = CLOSE_WAIT_S) -> dict:
    """Run ``command`` for at most ``minutes``, sampling it; then SIGTERM, sampling its closing into ``closing``
    until it exits (killed ``close_wait_s`` later). The verdict fits the samples before SIGTERM only."""
    out.mkdir(parents=True, exist_ok=True)
    res = {"command": command, "minutes": minutes, "every_s": every_s, **limits, "machine": machine_info(),
           "samples": [], "closing": []}
    child = subprocess.Popen(command, stdout=subprocess.DEVNULL)  # stderr: the run's own errors stay visible
    t0 = time.monotonic()
    try:
        while child.poll() is None and time.monotonic() - t0 < 60.0 * minutes:
            res["samples"].append({"t_s": round(time.monotonic() - t0, 2), **usage(child.pid)})
            res.update(flatness(res["samples"], **limits))
            write_json(res, out / "soak.json")
            time.sleep(every_s)
        res["ended_by"] = "itself" if child.poll() is not None else "SIGTERM"
        if child.poll() is None:
            child.terminate()
            t_term = time.monotonic()
            while child.poll() is None and time.monotonic() - t_term < close_wait_s:
                res["closing"].append({"t_s": round(time.monotonic() - t0, 2), **usage(child.pid)})
                time.sleep(min(every_s, 1.0))
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    res["returncode"] = child.returncode
    res.update(flatness(res["samples"], **limits))
    live = [c for c in res["closing"] if c["processes"]]
    res["closing_fds_max"] = max((c["fds"] for c in live), default=None)
    res["closing_rss_mib_max"] = max((c["rss_mib"] for c in live), default=None)
    write_json(res, out / "soak.json")
    return res


def main(argv: list[str] | None = None) -> dict:
    p = ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--minutes", type=float, default=60.0, help="how long to run it (default: 60)")
    p.add_argument("--every-s", type=float, default=10.0, help="seconds between samples (default: 10)")
    p.add_argument("--warmup-frac", type=float, default=0.2, help="share of the samples left out of the fits (0.2)")
    p.add_argument("--max-rss-mib-per-h", type=float, default=20.0, help="memory growth still flat (20 MiB/h)")
    p.add_argument("--max-fd-change", type=int, default=2, help="descriptor change still flat (2)")
    p.add_argument("--out", type=Path, default=Path("results/bench"), help="writes OUT/soak.json")
    p.add_argument("command", nargs="*", help="after --: the command to soak (default: a base training run)")
    args = p.parse_args(argv)
    if not os.path.isdir("/proc/self/fd"):
        raise UserError("the soak reads /proc: Linux only")
    if args.minutes <= 0 or args.every_s <= 0 or not 0 <= args.warmup_frac < 1:
        raise UserError("--minutes and --every-s must be > 0 and --warmup-frac in [0, 1)")
    command = args.command or [sys.executable, *DEFAULT_TRAIN, "--time-limit", str(60.0 * args.minutes + CLOSE_SLACK_S),
                               "--log-root", str(args.out / "soak_runs")]
    limits = {"warmup_frac": args.warmup_frac, "max_rss_mib_per_h": args.max_rss_mib_per_h,
              "max_fd_change": args.max_fd_change}
    res = soak(command, args.minutes, args.every_s, args.out / "soak", limits)
    verdict = {None: "too short to judge", True: "flat", False: "NOT flat"}[res["flat"]]
    print(f"[soak] {len(res['samples'])} samples over {res['samples'][-1]['t_s'] if res['samples'] else 0:.0f} s: "
          f"memory {res.get('rss_mib_per_h', float('nan')):+.1f} MiB/h, descriptors "
          f"{res.get('fds_min', '-')}-{res.get('fds_max', '-')}: {verdict}; closing (after {res['ended_by']}, "
          f"{len(res['closing'])} samples, not judged): descriptors <= {res['closing_fds_max']}, exit status "
          f"{res['returncode']} -> {args.out / 'soak' / 'soak.json'}")
    return res


if __name__ == "__main__":
    run_cli(main)

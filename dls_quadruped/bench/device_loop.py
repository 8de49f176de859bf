"""The closed loop's host and device paths on the same episodes: ``python -m dls_quadruped.bench.device_loop``.

Each MPC controller plays the same scheduled episodes (commands, starting states; ``closed_loop.episodes``) three
times:

* ``cpu``: the host path, the ``cpu`` backend (MuJoCo) and the ``cpp`` kernel, MPC seed ``--seed``;
* ``cpu_next_seed``: the same with MPC seed ``--seed`` + 1: how much two sampler noise streams alone move an episode's
  values (the noise the device path is judged against);
* ``warp_cpu``: the device path on Warp's CPU device, the ``warp-cpu`` backend (MuJoCo Warp, float32) and the ``warp``
  kernel (``mpc/warp_solve.py``: its noise from the device counter), MPC seed ``--seed``; everything the loop keeps
  stays on the device and is read back once per episode (``envs/recorder.py``).

The two paths cannot agree bit for bit (two simulators, two noise streams), so the comparison is per episode:
the episode's median RL reward per step and median MPC initial cost (the state cost at each solve), and the paired
differences ``warp_cpu - cpu`` and ``cpu_next_seed - cpu`` (mean over episodes with a 95 % bootstrap interval,
``eval.metrics.paired_difference``). The device path agrees "within noise" when its difference is of the size of
the seed-to-seed one. Writes ``<out>/device_loop.json`` and prints a markdown table.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dls_quadruped.cli import ArgumentParser, positive_float, positive_int, run_cli
from dls_quadruped.closed_loop.controllers import ControllerConfig
from dls_quadruped.closed_loop.episodes import DEFAULT_STUDENT, commands, run_controllers, summarize_all
from dls_quadruped.core.json_io import write_json
from dls_quadruped.core.machine import cpu_model
from dls_quadruped.eval.metrics import paired_difference
from dls_quadruped.mpc.config import SamplerConfig

PATHS = {"cpu": ("cpu", "cpp", 0), "cpu_next_seed": ("cpu", "cpp", 1), "warp_cpu": ("warp-cpu", "warp", 0)}
"""Run name -> (backend, kernel, MPC seed offset)."""
METRICS = ("rl_reward", "mpc_initial_cost")
"""Per-episode medians compared (``closed_loop.metrics.summarize``'s ``per_episode``)."""


def compare(controllers: tuple[str, ...], episodes: int, seconds: float, samples: int, seed: int = 0,
            student: Path = DEFAULT_STUDENT) -> dict:
    """Every controller on every path of ``PATHS`` (module docstring); per controller and path the per-episode
    values of ``METRICS``, survival and timing, and the paired differences of each other path to ``cpu``."""
    cmds = commands(episodes, seed, None)
    out = {}
    for name in controllers:
        runs = {}
        for run, (backend, kernel, offset) in PATHS.items():
            cfg = ControllerConfig(name, student=student, seed=seed + offset,
                                   sampler=SamplerConfig(num_samples=samples, kernel=kernel))
            traces = run_controllers([cfg], cmds, seconds, seed, 0, backend=backend)
            summary = summarize_all(traces)[0][name]
            runs[run] = {"per_episode": {k: summary["per_episode"][k][0] for k in METRICS},
                         "survival": summary["survival"]["rate"], "mpc_fallbacks": summary["mpc_fallbacks"],
                         "robot_seconds_per_second": summary["timing"]["robot_seconds_per_second"]}
        base = runs["cpu"]["per_episode"]
        paired = {}
        for run in ("warp_cpu", "cpu_next_seed"):
            paired[f"{run} - cpu"] = {k: paired_difference(np.array([runs[run]["per_episode"][k]]),
                                                            np.array([base[k]])) for k in METRICS}
        out[name] = {"runs": runs, "paired": paired}
    return out


def table(result: dict) -> str:
    """A markdown table: per controller and metric, each path's median over episodes and the paired differences."""
    lines = ["| controller | metric | cpu | warp-cpu | warp-cpu - cpu [95 % CI] | cpu, seed + 1 - cpu [95 % CI] |",
             "|---|---|---|---|---|---|"]
    for name, r in result["controllers"].items():
        for k in METRICS:
            med = {run: float(np.median(r["runs"][run]["per_episode"][k])) for run in ("cpu", "warp_cpu")}
            d, s = r["paired"]["warp_cpu - cpu"][k], r["paired"]["cpu_next_seed - cpu"][k]
            fmt = (lambda v: f"{v:+.3f}") if k == "rl_reward" else (lambda v: f"{v:+.2f}")
            lines.append(f"| {name} | {k} | {med['cpu']:.3f} | {med['warp_cpu']:.3f} | {fmt(d['mean'])} "
                         f"[{fmt(d['ci95'][0])}, {fmt(d['ci95'][1])}] | {fmt(s['mean'])} "
                         f"[{fmt(s['ci95'][0])}, {fmt(s['ci95'][1])}] |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict:
    p = ArgumentParser(description=__doc__)
    p.add_argument("--controllers", nargs="+", default=["rl_warm_start", "naive_warm_start"],
                   choices=["rl_warm_start", "naive_warm_start"])
    p.add_argument("--episodes", type=positive_int, default=8, help="episodes (robots in parallel); even")
    p.add_argument("--seconds", type=positive_float, default=3.0, help="episode length [s]")
    p.add_argument("--samples", type=positive_int, default=1000, help="M, samples per robot")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, default=Path("results/bench"))
    args = p.parse_args(argv)
    if args.episodes % 2:
        p.error(f"argument --episodes: the simple task pairs every command with its mirror image, got {args.episodes}")
    settings = {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()}
    paths = {k: {"backend": b, "kernel": kernel, "seed_offset": o} for k, (b, kernel, o) in PATHS.items()}
    result = {"settings": {**settings, "cpu": cpu_model(), "paths": paths},
              "controllers": compare(tuple(args.controllers), args.episodes, args.seconds, args.samples, args.seed)}
    args.out.mkdir(parents=True, exist_ok=True)
    write_json(result, args.out / "device_loop.json", indent=1)
    print(table(result))
    print(f"[device_loop] wrote {args.out / 'device_loop.json'}")
    return result


if __name__ == "__main__":
    run_cli(main)

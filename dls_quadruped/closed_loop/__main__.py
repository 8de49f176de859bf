"""Closed-loop comparison of controllers on the simple task (thesis 7.3): summary.json + plot (+ video).

    python -m dls_quadruped.closed_loop --controllers rl_warm_start,naive_warm_start,rl_baseline \\
        --episodes 8 --seconds 15 [--sampler-seeds 3] [--samples 10000] [--vx 0.5] [--optimise F,f] [--out DIR]
    python -m dls_quadruped.closed_loop --controllers rl_warm_start --students base,speed [--shares 0.5,0.5] \\
        [--switching-cost 50] [--group-cost-smoothing 0.9]
    python -m dls_quadruped.closed_loop --scenario stairs --ground terrain --episodes 4 [--heights 0.05,0.1,0.15,0.2]
    python -m dls_quadruped.closed_loop --controllers rl_baseline --set terminations.bad_orientation.params.limit_deg=60

Every controller gets a fresh env with the same seed and the same scheduled episodes (commands,
starting states, and any event or noise, ``envs/schedule.py``), so differences between controllers
are paired per episode. An MPC controller runs each episode with ``--sampler-seeds`` independent
sampler noise streams at once (E x S robots in one batched env, robot s E + e playing episode e);
a policy controller is deterministic and runs each episode once. Summaries are per episode first,
then across episodes and seeds with 95 % intervals; ``paired`` holds every pair of controllers'
differences on the same episodes (two-level bootstrap over episodes and seeds).
``--vx`` replaces the simple task's random commands by a fixed forward speed (Table 17).
``--scenario stairs`` runs the eval suite's staircase test (``eval/stairs.py``, thesis Fig. 19): one
``stairs_up`` row per step height of ``--heights``, ``--episodes`` per height (height-major), commands
v_x ~ U[0.3, 0.5] m/s; the summary adds per height survival, success (the base reached the top level)
and the climbed fraction of the flight, computed as the eval suite does.
``--students`` warm-starts one MPC with several students (thesis 7.4): each seeds its own group of
samples (``--shares``, equal by default) in the same batched solve; a name ``X`` is the committed
``docs/policies/X_student_<p>_<F>_h<H>.pt``, anything else a path. ``--switching-cost`` and
``--group-cost-smoothing`` arbitrate between the groups for a coherent winner (``mpc.arbitration``).
Writes ``<out>/summary.json`` (per controller: medians and quartiles of the RL reward, initial
cost, rollout cost, cost per horizon step, velocity error, CoT; survival with a Wilson interval;
which warm start won; the timing profile), ``<out>/closed_loop.png`` and, with ``--video``,
``<out>/closed_loop.gif`` (robot 0 of each controller side by side).
"""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")  # before mujoco is imported (offscreen video)

import argparse
import time
from pathlib import Path

import numpy as np
import torch

from dls_quadruped.cli import (
    ArgumentParser,
    UserError,
    add_set_argument,
    non_negative_int,
    positive_float,
    positive_int,
    run_cli,
    set_overrides,
)
from dls_quadruped.closed_loop.controller_config import NEEDS_POLICY, NEEDS_STUDENT
from dls_quadruped.closed_loop.controllers import CONTROLLERS, ControllerConfig
from dls_quadruped.closed_loop.episodes import (
    DEFAULT_POLICY,
    DEFAULT_STUDENT,
    SCENARIOS,
    STAIRS_HEIGHTS,
    commands,
    plot,
    run_controllers,
    summarize_all,
)
from dls_quadruped.core.json_io import write_json
from dls_quadruped.core.machine import cpu_model
from dls_quadruped.eval.velocity_tracking import FIXED_SECTIONS, OVERRIDABLE_SECTIONS
from dls_quadruped.mpc.baseline import OPTIMISABLE
from dls_quadruped.mpc.config import ENCODING_KINDS, SamplerConfig
from dls_quadruped.mpc.inputs import GROUNDS

THESIS_TABLE14_FIRST_SPLINE = {
    "rl_warm_start": {"rl_reward": 2.347, "initial_cost": 30.72, "rollout_cost": 291.8},
    "naive_warm_start": {"rl_reward": 2.259, "initial_cost": 31.43, "rollout_cost": 211.7},
    "rl_baseline": {"rl_reward": 2.365, "initial_cost": 86.45},
}
"""Thesis Table 14, first-spline rows (medians over 100 episodes), printed beside ours."""


def _names(text: str, allowed: tuple[str, ...], what: str) -> tuple[str, ...]:
    names = tuple(t.strip() for t in text.split(",") if t.strip())
    bad = [n for n in names if n not in allowed]
    if bad or not names or len(set(names)) != len(names):
        raise argparse.ArgumentTypeError(f"{what} must be distinct names from {list(allowed)} separated by commas, "
                                         f"got {text!r}")
    return names


def _list(text: str) -> tuple[str, ...]:
    names = tuple(t.strip() for t in text.split(",") if t.strip())
    if not names:
        raise argparse.ArgumentTypeError(f"expected comma-separated names or paths, got {text!r}")
    return names


def _shares(text: str) -> tuple[float, ...]:
    try:
        return tuple(float(t) for t in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None


def student_paths(names: tuple[str, ...], encoding: str, horizon: int, dt: float,
                  policies: Path = Path("docs/policies")) -> tuple[Path, ...]:
    """``--students`` entries as files: an existing path as is, a bare name as the committed student
    ``<policies>/<name>_student_<p>_<F>_h<H>.pt`` of the MPC's encoding and horizon (dt = 0.02 s)."""
    p_kind, f_kind = encoding.split("-")
    out = []
    for name in names:
        path = Path(name)
        if path.is_file():
            out.append(path)
            continue
        committed = policies / f"{name}_student_{p_kind}_{f_kind}_h{horizon}.pt"
        if "/" not in name and not name.endswith(".pt") and committed.is_file() and abs(dt - 0.02) < 1e-9:
            out.append(committed)
            continue
        have = sorted(q.name.split("_student_")[0] for q in policies.glob(f"*_student_{p_kind}_{f_kind}_h{horizon}.pt"))
        raise UserError(f"--students: {name!r} is neither a file nor a committed student "
                        f"({committed}, dt 0.02 s); committed for {encoding}, H = {horizon}: {have}")
    return tuple(out)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--controllers", type=lambda t: _names(t, CONTROLLERS, "--controllers"),
                   default=("rl_warm_start", "naive_warm_start", "rl_baseline"),
                   help=f"comma-separated from {list(CONTROLLERS)}")
    p.add_argument("--policy", type=Path, default=DEFAULT_POLICY, help="RL expert (rl_baseline)")
    p.add_argument("--student", type=Path, default=DEFAULT_STUDENT, help="distilled student (rl_warm_start, student)")
    p.add_argument("--students", type=_list, default=None,
                   help="rl_warm_start with several students, comma-separated names (docs/policies/<name>_student_"
                        "<p>_<F>_h<H>.pt) or paths; replaces --student")
    p.add_argument("--shares", type=_shares, default=None,
                   help="--students' shares of the samples, comma-separated, positive, summing to 1 (default: equal)")
    p.add_argument("--switching-cost", type=float, default=0.0,
                   help="several warm starts: cost (units of eq. 3.2.1) added to every sample outside the previous "
                        "winner's group, >= 0 (default 0: off)")
    p.add_argument("--group-cost-smoothing", type=float, default=0.0,
                   help="several warm starts: groups compete by a running average of their best cost, "
                        "A <- (1 - beta) J + beta A; beta in [0, 1) (default 0: off)")
    p.add_argument("--episodes", type=positive_int, default=8,
                   help="episodes (robots in parallel); even for the simple task")
    p.add_argument("--seconds", type=positive_float, default=15.0, help="episode length [s]")
    p.add_argument("--vx", type=float, default=None, help="fixed forward command [m/s] instead of the simple task")
    p.add_argument("--scenario", choices=SCENARIOS, default="simple",
                   help="simple (flat, no disturbance), pushes (simple with pushes of --push-speed) or the eval "
                        "suite's survival / survival_sweep (terrain, pushes, "
                        "friction, wrench, noise) or stairs (one stairs_up row per --heights, no disturbance); the MPC "
                        "is terrain-blind unless --ground terrain")
    p.add_argument("--push-speed", type=positive_float, default=None,
                   help="pushes: the largest velocity change of a push [m/s] per horizontal axis (every 4-6 s)")
    p.add_argument("--heights", type=_heights, default=None,
                   help="stairs: step heights [m], comma-separated, positive, ascending and evenly spaced (one "
                        f"terrain row each; default {','.join(f'{h:g}' for h in STAIRS_HEIGHTS)}); --episodes is then "
                        "per height")
    p.add_argument("--ground", choices=("auto", *GROUNDS), default="auto",
                   help="ground the MPC plans on: auto = flat for simple, stance_feet (flat at its feet's height) "
                        "else; terrain = the terrain map (CoM reference above the terrain under the base, "
                        "touch-downs at the terrain height under the reference footholds)")
    p.add_argument("--samples", type=positive_int, default=10000, help="M, samples per robot")
    p.add_argument("--sampler-seeds", type=positive_int, default=1,
                   help="independent sampler noise streams per episode for the MPC controllers (robots in parallel)")
    p.add_argument("--horizon", type=positive_int, default=10, help="N")
    p.add_argument("--dt", type=positive_float, default=0.02, help="MPC step [s]")
    p.add_argument("--encoding", default="first-spline", help=f"p-F, each from {list(ENCODING_KINDS)}")
    p.add_argument("--optimise", type=lambda t: _names(t, OPTIMISABLE, "--optimise"), default=("F",),
                   help=f"variables the MPC samples, from {list(OPTIMISABLE)}")
    p.add_argument("--naive-share", type=float, default=0.0,
                   help="rl_warm_start: share of samples around the naive warm start")
    p.add_argument("--naive-gait", type=float, nargs=2, metavar=("FREQ", "DUTY"), default=None,
                   help="naive_warm_start: its trot's frequency [Hz] in (0, 3] and duty cycle in (0, 1) "
                        "(default 1.5 0.6, mpc.baseline.BaselineConfig)")
    p.add_argument("--com-height", type=float, default=None,
                   help="CoM height reference above the ground [m] in [0.1, 0.6] of the MPC controllers and of every "
                        "controller's initial cost (default ~0.324, mpc.srbd.com_height_reference)")
    p.add_argument("--kernel", default="cpp", choices=("cpp", "fast", "reference", "warp"),
                   help="the MPC's cost kernel (cpp on a CUDA device runs warp: mpc.sampler.resolved_kernel)")
    p.add_argument("--device", default="cpu", help="the env's torch device (cuda with --backend cuda)")
    p.add_argument("--backend", default="cpu", choices=("cpu", "warp-cpu", "cuda"),
                   help="the simulator (sim/registry.py): cpu (MuJoCo), warp-cpu (MuJoCo Warp on Warp's CPU "
                        "device, the GPU code path), cuda (MuJoCo Warp on the GPU)")
    p.add_argument("--threads", type=positive_int, default=1, help="torch / MPC kernel threads")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--num-workers", type=int, default=0,
                   help="simulator worker processes (0, default: in-process: the MPC keeps the cores busy, so separate "
                        "simulator processes only add IPC; measured in docs/benchmarks.md 'Closed loop'; -1: one per "
                        "core)")
    p.add_argument("--video", action="store_true", help="render robot 0 of each controller side by side (GIF)")
    p.add_argument("--video-seconds", type=positive_float, default=4.0)
    p.add_argument("--record-robots", type=non_negative_int, default=1)
    p.add_argument("--out", type=Path, default=Path("results/closed_loop"))
    add_set_argument(p, "of the base task every scenario starts from, in its sections "
                        f"{', '.join(OVERRIDABLE_SECTIONS)}: "
                        f"the scenario sets {', '.join(FIXED_SECTIONS)} itself, so a key there is refused; recorded "
                        "in summary.json's settings")
    args = p.parse_args(argv)
    parts = args.encoding.split("-")
    if len(parts) != 2 or any(k not in ENCODING_KINDS for k in parts):
        p.error(f"argument --encoding: must be p-F with each of {list(ENCODING_KINDS)}, e.g. first-spline; "
                f"got {args.encoding!r}")
    if args.scenario == "stairs":
        if args.vx is not None:
            p.error(f"argument --vx: the stairs scenario draws its own forward commands (v_x ~ U[0.3, 0.5] m/s); "
                    f"drop --vx {args.vx:g}")
        args.heights = args.heights or STAIRS_HEIGHTS
    elif args.heights is not None:
        p.error(f"argument --heights: only for --scenario stairs, got --scenario {args.scenario}")
    elif args.vx is None and args.episodes % 2:
        p.error(f"argument --episodes: the simple task pairs every command with its mirror image, so it must be even; "
                f"got {args.episodes}")
    if (args.push_speed is None) == (args.scenario == "pushes"):
        p.error("argument --push-speed: needed by --scenario pushes and only by it; "
                f"got --scenario {args.scenario} and --push-speed {args.push_speed}")
    if not 0.0 <= args.naive_share < 1.0:
        p.error(f"argument --naive-share: must be in [0, 1), got {args.naive_share}")
    return args


def _heights(text: str) -> tuple[float, ...]:
    try:
        h = tuple(float(t) for t in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated step heights [m], got {text!r}") from None
    d = np.diff(h)
    if not all(x > 0 for x in h) or (d <= 0).any() or (len(h) > 2 and not np.allclose(d, d[0])):
        raise argparse.ArgumentTypeError(f"step heights must be positive, ascending and evenly spaced (rows "
                                         f"interpolate linearly), got {text!r}")
    return h


def _metric(s: dict, key: str, thesis: dict) -> str:
    """'median [95 % CI] (thesis x)' of one metric of a controller's summary (median over episodes of
    each episode's median)."""
    if key not in s:
        return "-"
    m = s[key]
    digits = 3 if key == "rl_reward" else 1
    text = f"{m['median']:.{digits}f} [{m['ci95'][0]:.{digits}f}, {m['ci95'][1]:.{digits}f}]"
    return text + (f" (thesis {thesis[key]})" if key in thesis else "")


def _difference(d: dict, digits: int) -> str:
    return f"{d['mean']:+.{digits}f} [{d['ci95'][0]:+.{digits}f}, {d['ci95'][1]:+.{digits}f}]"


def headline(summary: dict) -> str:
    lines = []
    for name, s in summary["controllers"].items():
        thesis = THESIS_TABLE14_FIRST_SPLINE.get(name, {})
        sv = s["survival"]
        tm = s["timing"]
        seeds = f" x {s['replicas']} sampler seeds" if s.get("replicas", 1) > 1 else ""
        lines.append(f"[closed_loop] {name}: {s['episodes']} episodes{seeds}, survival {100 * sv['rate']:.0f} % "
                     f"(95 % CI {100 * sv['ci95'][0]:.0f}-{100 * sv['ci95'][1]:.0f})")
        lines.append(f"  medians over episodes [95 % CI]: RL reward {_metric(s, 'rl_reward', thesis)}; "
                     f"initial cost {_metric(s, 'initial_cost', thesis)}; state-only rollout cost "
                     f"{_metric(s, 'rollout_cost', thesis)}; full J {_metric(s, 'rollout_cost_full', {})}")
        lines.append(f"  |v_xy - cmd| median {s['vel_error']['median']:.3f} m/s; "
                     f"CoT median {s['cost_of_transport']['median']:.2f}; "
                     f"{tm['robot_seconds_per_second']:.2f} robot-s/s, kernel {100 * tm['kernel_share']:.0f} % of "
                     f"{tm['wall']:.1f} s wall")
        for r in s.get("stairs", {}).get("per_height", []):
            top, sv, c = r["success"], r["survival"], r["climbed_fraction"]
            lines.append(f"  stairs h {100 * r['step_height']:4.1f} cm ({r['episodes']:g} episodes): top "
                         f"{100 * top['rate']:.0f} % [{100 * top['ci95_episodes'][0]:.0f}, "
                         f"{100 * top['ci95_episodes'][1]:.0f}], "
                         f"survival {100 * sv['rate']:.0f} %, climbed {100 * c['mean']:.0f} % of the flight")
    for pair, diffs in summary.get("paired", {}).items():
        fine = ("rl_reward", "vel_error", "survived", "reached_top", "climbed_fraction")  # 3 digits, the rest 1
        parts = [f"{k} {_difference(diffs[k], 3 if k in fine else 1)}"
                 for k in ("rl_reward", "initial_cost", "rollout_cost", "survived", "reached_top", "climbed_fraction")
                 if k in diffs]
        lines.append(f"[closed_loop] paired, {pair} (mean over episodes [95 % CI]): " + "; ".join(parts))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict:
    args = parse_args(argv)
    torch.set_num_threads(args.threads)
    students = student_paths(args.students, args.encoding, args.horizon, args.dt) if args.students else None
    if students is not None and (set(args.controllers) & set(NEEDS_STUDENT)) != {"rl_warm_start"}:
        raise UserError(f"--students applies to the rl_warm_start controller alone, got --controllers "
                        f"{','.join(args.controllers)}")
    if args.shares is not None and students is None:
        raise UserError("--shares needs --students")
    for name in args.controllers:
        path = args.student if name in NEEDS_STUDENT else args.policy if name in NEEDS_POLICY else None
        if path is not None and students is None and not path.is_file():
            flag = "--student" if name in NEEDS_STUDENT else "--policy"
            raise UserError(f"{flag} {path} not found (controller {name} needs it)")
    p_kind, f_kind = args.encoding.split("-")
    auto_ground = "flat" if args.scenario in ("simple", "pushes") else "stance_feet"
    ground = args.ground if args.ground != "auto" else auto_ground
    try:
        sampler = SamplerConfig(num_samples=args.samples, horizon=args.horizon, dt=args.dt, encoding_p=p_kind,
                                encoding_F=f_kind, kernel=args.kernel, switching_cost=args.switching_cost,
                                group_cost_smoothing=args.group_cost_smoothing)
        configs = [ControllerConfig(name, policy=args.policy, student=students or args.student, sampler=sampler,
                                    optimise=args.optimise,
                                    naive_share=args.naive_share if name == "rl_warm_start" else 0.0,
                                    shares=args.shares if name == "rl_warm_start" else None, ground=ground,
                                    seed=args.seed,
                                    naive_gait=tuple(args.naive_gait) if args.naive_gait and name == "naive_warm_start"
                                    else None, com_height=args.com_height) for name in args.controllers]
    except ValueError as err:
        raise UserError(str(err)) from None
    heights = args.heights or STAIRS_HEIGHTS
    cmds = commands(args.episodes, args.seed, args.vx, args.scenario, heights)
    overrides = set_overrides(args.set)
    t0 = time.perf_counter()
    try:
        traces = run_controllers(configs, cmds, args.seconds, args.seed, args.num_workers, args.record_robots,
                                 args.sampler_seeds, args.scenario, heights, overrides or None, args.push_speed,
                                 device=args.device, backend=args.backend)
    except (ValueError, FileNotFoundError) as err:  # student/MPC mismatch, wrong observation size, bad file
        raise UserError(str(err)) from None
    summaries, paired = summarize_all(traces)
    summary = {
        "settings": {"controllers": list(args.controllers), "episodes": len(cmds), "seconds": args.seconds,
                     "command": ("stairs: v_x ~ U[0.3, 0.5] m/s" if args.scenario == "stairs" else
                                 "simple task" if args.vx is None else f"forward {args.vx} m/s"),
                     "scenario": args.scenario, "ground": ground,
                     "stairs_heights": list(heights) if args.scenario == "stairs" else None,
                     "push_speed": args.push_speed,
                     "samples": args.samples, "horizon": args.horizon, "dt": args.dt, "encoding": args.encoding,
                     "optimise": list(args.optimise), "naive_share": args.naive_share, "kernel": args.kernel,
                     "device": args.device, "backend": args.backend,
                     "naive_gait": args.naive_gait, "com_height": args.com_height,
                     "sampler_seeds": args.sampler_seeds,
                     "threads": args.threads, "seed": args.seed, "policy": str(args.policy),
                     "student": [str(x) for x in students] if students else str(args.student),
                     "shares": list(args.shares) if args.shares else None,
                     "switching_cost": args.switching_cost, "group_cost_smoothing": args.group_cost_smoothing,
                     "task_overrides": overrides or None, "cpu": cpu_model()},
        "controllers": summaries,
        "paired": paired,
        "thesis_table14_first_spline": THESIS_TABLE14_FIRST_SPLINE,
        "wall_s": round(time.perf_counter() - t0, 1),
    }
    args.out.mkdir(parents=True, exist_ok=True)
    write_json(summary, args.out / "summary.json", indent=1)
    plot(traces, args.out / "closed_loop.png")
    if args.video:
        from dls_quadruped.viz.video import render_gif_row

        print(render_gif_row(list(traces.values()), args.out / "closed_loop.gif", seconds=args.video_seconds,
                             labels=list(traces), size=(240, 320)))
    print(headline(summary))
    print(f"[closed_loop] wrote {args.out / 'summary.json'} and {args.out / 'closed_loop.png'}")
    return summary


if __name__ == "__main__":
    run_cli(main)

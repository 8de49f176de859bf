"""Shared machinery of the chapter-7.3 experiments (Tables 14-17, Fig. 28): closed-loop cells.

A *cell* is one controller (``rl_warm_start``, ``naive_warm_start``, ``rl_baseline``) with one MPC
setting, run for a batch of episodes in parallel (``dls_quadruped.closed_loop``) on the thesis's simple
task or a fixed forward speed, and summarised as the thesis does (medians with first and third
quartiles, 7.3.1; survival with a Wilson interval). Every cell is cached in
``<out>/cells/<name>.json``: an interrupted script continues with the cells it has not finished.

Scales (episodes x seconds per cell): ``small`` 4 x 5 s (minutes on 2 cores; a pipeline check more
than a measurement), ``medium`` 16 x 15 s, ``thesis`` 100 x 15 s (7.3.1: 100 trajectories per
configuration). Every MPC cell plays each episode with ``--sampler-seeds`` (default 3) independent
sampler noise streams side by side in one batched env; the RL baseline is deterministic and plays
each episode once. Every cell of a script sees the same scheduled episodes (same seed, commands and
starts, ``envs/schedule.py``), so cells are compared by paired differences per episode. Statistics
are per episode first (``closed_loop/metrics.py``): medians across episodes and seeds with a 95 %
interval of the median; the rollout cost is the state-only one (``rollout_cost``), the full J the
sampler minimised beside it (``rollout_cost_full``).

Students: ``rl_warm_start`` needs a student distilled for the cell's encoding, horizon and dt: the
committed ``docs/policies/base_student_first_spline_h10.pt`` for first-spline, H = 10, dt = 0.02 s,
otherwise ``<students>/<p>-<F>_H<H>_dt<dt>/exported/student.pt2`` (``--students``, default
``results/experiments/students``), made by ``experiments/make_students.sh`` (``make distill`` per
encoding). A cell whose student is missing is skipped with a note in the table (never silently
replaced by another).
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import torch

from dls_quadruped.cli import ArgumentParser
from dls_quadruped.closed_loop.controller_config import NEEDS_STUDENT, ControllerConfig
from dls_quadruped.closed_loop.episodes import commands, run_controllers
from dls_quadruped.closed_loop.metrics import summarize
from dls_quadruped.core.json_io import write_json
from dls_quadruped.core.progress import progress
from dls_quadruped.eval.provenance import provenance
from dls_quadruped.mpc.config import SamplerConfig
from dls_quadruped.mpc.inputs import GROUNDS
from experiments.rl_common import VARIANTS, expert_file, student_file

REPO = Path(__file__).resolve().parents[1]

SCALES = {"small": {"episodes": 4, "seconds": 5.0}, "medium": {"episodes": 16, "seconds": 15.0},
          "thesis": {"episodes": 100, "seconds": 15.0}}
POLICY = REPO / "docs" / "policies" / "base_actor.pt"
COMMITTED_STUDENT = REPO / "docs" / "policies" / "base_student_first_spline_h10.pt"


@dataclass(frozen=True)
class Cell:
    """One table cell: a controller and its MPC settings on one command set."""

    name: str
    controller: str
    sampler: dict = field(default_factory=dict)   # SamplerConfig overrides (num_samples, horizon, dt, encoding_*)
    optimise: tuple[str, ...] = ("F",)
    vx: float | None = None                      # fixed forward speed, else the simple task
    naive_share: float = 0.0                      # rl_warm_start: share of samples around the previous solution
    row: dict = field(default_factory=dict)       # table columns
    student: str | None = None                    # rl_warm_start: this student export (else found by encoding)
    students: tuple[str, ...] = ()                # rl_warm_start: several student exports, one sample group each
    shares: tuple[float, ...] | None = None       # their shares (None: equal)
    policy: str | None = None                     # rl_baseline: this expert (else --policy)
    scenario: str = "simple"                      # closed_loop scenario (simple, survival, survival_sweep, stairs;
                                                  # stairs: --episodes per step height, closed_loop.STAIRS_HEIGHTS)
    ground: str | None = None                     # ground the MPC plans on (mpc.inputs.GROUNDS); None: flat on
                                                  # the simple scenario, stance_feet (blind) on the others
    seconds: float | None = None                  # episode length [s] of this cell unless --seconds is given
    push_speed: float | None = None               # the pushes scenario's push speed [m/s]
                                                  # (None: the scale's)
    naive_gait: tuple[float, float] | None = None  # naive_warm_start: (frequency [Hz], duty) of its trot
                                                  # (None: BaselineConfig's 1.5 Hz, 0.6)
    com_height: float | None = None               # MPC controllers: CoM height reference [m] (None: ~0.324)

    def __post_init__(self) -> None:
        if self.ground is not None and self.ground not in GROUNDS:
            raise ValueError(f"cell {self.name!r}: ground must be one of {list(GROUNDS)} or None, got {self.ground!r}")

    def plan_ground(self) -> str:
        """The ground the cell's MPC plans on (``ground``, or the scenario's default)."""
        if self.ground is not None:
            return self.ground
        return "flat" if self.scenario in ("simple", "pushes") else "stance_feet"


def parse_args(description: str, name: str, extra=None) -> argparse.Namespace:
    """The scripts' common flags; ``extra(parser)`` adds a script's own."""
    p = ArgumentParser(description=description, formatter_class=argparse.RawDescriptionHelpFormatter)  # one-line errors
    p.add_argument("--scale", choices=sorted(SCALES), default="small")
    p.add_argument("--out", type=Path, default=REPO / "results" / "experiments" / name)
    p.add_argument("--students", type=Path, default=None,
                   help="folder of students <p>-<F>_H<H>_dt<dt>/exported/student.pt2 (default: "
                        "results/experiments/students); first-spline H = 10, dt = 0.02 s is the committed student "
                        "unless this folder is given and holds one")
    p.add_argument("--policy", type=Path, default=None,
                   help=f"the expert of the rl_baseline cells (default: the variant's base expert, {POLICY.name})")
    p.add_argument("--variant", choices=sorted(VARIANTS), default="thesis",
                   help="thesis: the experts trained with Table 6 and their committed students (base_actor.pt, "
                        "<expert>_student_first_spline_h10.pt); recipe: those retrained with the default recipe "
                        "(base_recipe_actor.pt2, <expert>_recipe_student_first_spline_h10.pt2; "
                        "docs/policies/README.md)")
    p.add_argument("--com-height", type=float, default=None,
                   help="the CoM height reference [m] of every cell without its own: the MPC's, and every controller's "
                        "initial-cost metric (default ~0.324, mpc.srbd.com_height_reference; "
                        "experiments/walking_height.py measures an expert's)")
    p.add_argument("--episodes", type=int, default=None, help="override the scale's episodes per cell (even)")
    p.add_argument("--seconds", type=float, default=None, help="override the scale's episode length [s]")
    p.add_argument("--threads", type=int, default=1, help="torch / MPC kernel threads")
    p.add_argument("--num-workers", type=int, default=0,
                   help="simulator processes (0: in-process, the closed loop's fastest)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--sampler-seeds", type=int, default=3,
                   help="sampler noise streams per episode for the MPC cells (robots in parallel)")
    p.add_argument("--only", nargs="*", default=None, help="run only these cells")
    p.add_argument("--shard", type=shard_arg, default=None, metavar="K/N",
                   help="run only cells K, K + N, K + 2N, ... of the script's list into the cache and stop (no "
                        "table): start N processes side by side (K = 0 .. N-1, the same --out), then run once "
                        "without --shard to write the table from the cache")
    if extra is not None:
        extra(p)
    args = p.parse_args()
    args.seconds_given = args.seconds is not None  # an explicit --seconds overrides a cell's own length too
    args.students_given = args.students is not None  # an explicit folder's first-spline student beats the committed
    args.students = args.students or REPO / "results" / "experiments" / "students"
    args.episodes = args.episodes or SCALES[args.scale]["episodes"]
    args.seconds = args.seconds or SCALES[args.scale]["seconds"]
    if args.com_height is not None and not 0.1 <= args.com_height <= 0.6:
        p.error(f"--com-height must be in [0.1, 0.6] m, got {args.com_height:g}")
    args.policy = args.policy or expert_file(POLICY.parent, "base", args.variant)
    args.committed_student = student_file(POLICY.parent, "base", args.variant)
    return args


def shard_arg(text: str) -> tuple[int, int]:
    """``"K/N"`` -> (K, N) with 0 <= K < N (argparse type: a bad value is a one-line usage error)."""
    try:
        k, n = (int(x) for x in text.split("/"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected K/N such as 0/2, got {text!r}") from None
    if not 0 <= k < n:
        raise argparse.ArgumentTypeError(f"K/N needs 0 <= K < N, got {text!r}")
    return k, n


def cell_com_height(cell: Cell, args: argparse.Namespace) -> float | None:
    """The CoM height reference of a cell: its own, else ``--com-height`` (None: the default,
    ``mpc.srbd.com_height_reference``). It is the MPC's reference and every controller's initial-cost reference,
    so the cells of one run are scored against one height."""
    return cell.com_height if cell.com_height is not None else getattr(args, "com_height", None)


def student_path(students: Path, p: str, F: str, horizon: int, dt: float,
                 committed: Path = COMMITTED_STUDENT, prefer_folder: bool = False) -> Path | None:
    """The student for an encoding, or None. The thesis's default configuration (first-spline, H = 10,
    dt = 0.02 s) uses the committed student (``docs/policies``, the demo's; ``committed``: the variant's), so
    every table shares it; with ``prefer_folder`` (``--students`` given) the folder's own student of that
    configuration replaces it where there is one."""
    exported = students / f"{p}-{F}_H{horizon}_dt{dt:g}" / "exported"
    # student.pt: an older distillation run's TorchScript export
    own = next((path for path in (exported / "student.pt2", exported / "student.pt") if path.is_file()), None)
    if (p, F, horizon, dt) == ("first", "spline", 10, 0.02) and committed.is_file() and not (prefer_folder and own):
        return committed
    return own


def run_cells(cells: list[Cell], args: argparse.Namespace) -> dict[str, dict]:
    """Run (or load from the cache) every cell; {name: summary or {"skipped": why}}. With ``args.shard`` = (K, N)
    only cells K, K + N, ... (positions in ``cells``) and exit after them: the table is written by a run without."""
    torch.set_num_threads(args.threads)
    out: dict[str, dict] = {}
    (args.out / "cells").mkdir(parents=True, exist_ok=True)
    shard = getattr(args, "shard", None)
    mine = {c.name for i, c in enumerate(cells) if shard is None or i % shard[1] == shard[0]}
    todo = [c for c in cells if (not args.only or c.name in args.only) and c.name in mine]
    bar = progress(total=len(todo), desc=args.out.name, unit="cell")
    for k, cell in enumerate(cells):
        if (args.only and cell.name not in args.only) or cell.name not in mine:
            continue
        bar.update(1)
        bar.set_postfix_str(cell.name, refresh=False)
        path = args.out / "cells" / f"{cell.name}.json"
        com_height = cell_com_height(cell, args)
        if path.is_file():
            cached = json.loads(path.read_text())
            if cached.get("com_height") != com_height and "skipped" not in cached:
                raise SystemExit(f"{path} was run with the MPC's CoM height reference {cached.get('com_height')} "
                                 f"(None: the default), this run asks for {com_height}: use another --out")
            out[cell.name] = cached
            continue
        sampler = SamplerConfig(**cell.sampler)
        student = None
        if cell.controller == "rl_warm_start" and cell.students:
            missing = [x for x in cell.students if not Path(x).is_file()]
            student = None if missing else tuple(Path(x) for x in cell.students)
            why = f"no student {missing[0]}" if missing else ""
            if student is None:
                out[cell.name] = {"skipped": why}
                print(f"[{args.out.name}] {cell.name}: skipped ({why})", flush=True)
                continue
        elif cell.controller in NEEDS_STUDENT:
            if cell.student:
                student = Path(cell.student) if Path(cell.student).is_file() else None
                why = f"no student {cell.student}"
            else:
                student = student_path(args.students, sampler.encoding_p, sampler.encoding_F, sampler.horizon,
                                       sampler.dt, getattr(args, "committed_student", COMMITTED_STUDENT),
                                       getattr(args, "students_given", False))
                why = (f"no student {sampler.encoding_p}-{sampler.encoding_F}_H{sampler.horizon}_dt{sampler.dt:g} "
                       f"under {args.students}")
            if student is None:
                out[cell.name] = {"skipped": why}
                print(f"[{args.out.name}] {cell.name}: skipped ({out[cell.name]['skipped']})", flush=True)
                continue
        policy = Path(cell.policy) if cell.policy else args.policy
        if cell.controller == "rl_baseline" and not policy.is_file():
            out[cell.name] = {"skipped": f"no policy {policy}"}
            print(f"[{args.out.name}] {cell.name}: skipped (no policy {policy})", flush=True)
            continue
        cfg = ControllerConfig(cell.controller, policy=policy, student=student, sampler=sampler,
                               optimise=cell.optimise, naive_share=cell.naive_share, shares=cell.shares,
                               ground=cell.plan_ground(), seed=args.seed, naive_gait=cell.naive_gait,
                               com_height=com_height)
        t0 = time.monotonic()
        seconds = args.seconds if getattr(args, "seconds_given", False) else cell.seconds or args.seconds
        traces = run_controllers([cfg], commands(args.episodes, args.seed, cell.vx, cell.scenario), seconds, args.seed,
                                 args.num_workers, sampler_seeds=args.sampler_seeds,
                                 scenario=cell.scenario, push_speed=cell.push_speed)[cell.controller]
        summary = summarize(traces, replicas=traces.replicas)
        student_txt = [str(x) for x in student] if isinstance(student, tuple) else str(student) if student else None
        summary.update({"cell": cell.name, "student": student_txt, "row": cell.row, "policy": str(policy),
                        "scenario": cell.scenario, "push_speed": cell.push_speed, "ground": cell.plan_ground(),
                        "naive_gait": list(cell.naive_gait) if cell.naive_gait else None, "com_height": com_height,
                        "shares": list(cell.shares) if cell.shares else None,
                        "sampler": cell.sampler, "optimise": list(cell.optimise), "vx": cell.vx,
                        "naive_share": cell.naive_share, "seconds": seconds, **provenance(),
                        "seconds_wall": time.monotonic() - t0})
        if len(cell.students) > 1:  # Fig. 34: the winning group of every solve of robot 0 (-1: none)
            summary["winner_trace_robot0"] = traces.winner[..., 0].reshape(-1).tolist()
        write_json(summary, path, indent=1)
        out[cell.name] = summary
        s = summary
        print(f"[{args.out.name}] {k + 1}/{len(cells)} {cell.name}: reward {s['rl_reward']['median']:.3f}, "
              f"initial cost {s['initial_cost']['median']:.1f}, survival {s['survival']['rate']:.2f}, "
              f"{summary['seconds_wall']:.0f} s", flush=True)
    bar.close()
    if shard is not None:  # the table needs every shard's cells: the run without --shard writes it
        print(f"[{args.out.name}] shard {shard[0]}/{shard[1]}: {len(todo)} cells in {args.out / 'cells'}; when every "
              "shard is done, run once more without --shard to write the table", flush=True)
        raise SystemExit(0)
    return out


"""Physics cost of the terrain: time of one ``mj_step`` per tile type (``make bench-terrain``).

A standing AlienGo (home pose, 0.5 mm into the ground, state restored before every step so the
four feet are the only contacts) on the centre of each tile of a task's terrain, against the same
robot on MuJoCo's plane, with MuJoCo's own timers split into kinematics (world poses of every
geom), broad phase, narrow phase (incl. the mid phase over the terrain's geoms) and constraint
solver. Wall-clock time like MuJoCo's timers (the CPU time is recorded too: the two differ when
other processes share the core). Writes ``results/bench/terrain_step.json`` and prints the markdown table of
``docs/benchmarks.md``. Usage::

    python -m dls_quadruped.bench.terrain [--task rough] [--rows 0 5] [--steps 3000]
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import mujoco
import numpy as np

from dls_quadruped.cli import ArgumentParser, run_cli
from dls_quadruped.core.json_io import write_json
from dls_quadruped.core.machine import cpu_model
from dls_quadruped.core.progress import progress
from dls_quadruped.envs.config import load_task
from dls_quadruped.envs.value_checks import dataclass_from_dict
from dls_quadruped.robots.aliengo import constants as C
from dls_quadruped.sim.terrain import TerrainConfig, build_scene

TIMERS = ("POS_KINEMATICS", "COL_BROAD", "COL_NARROW", "CONSTRAINT")


def step_cost(model: mujoco.MjModel, x: float, y: float, z_ground: float, steps: int) -> dict[str, float]:
    """Mean wall and CPU time [us] of ``mj_step`` and MuJoCo's (wall-clock) timers, robot standing at
    (x, y, z_ground)."""
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, 0)
    data.qpos[:3] = (x, y, C.STANDING_BASE_HEIGHT + z_ground - 0.0005)
    qpos0 = data.qpos.copy()
    for timer in data.timer:
        timer.duration = 0.0
    t0, c0 = time.perf_counter(), time.process_time()
    for _ in range(steps):
        data.qpos[:] = qpos0
        data.qvel[:] = 0.0
        mujoco.mj_step(model, data)
    out = {"step_us": (time.perf_counter() - t0) / steps * 1e6, "step_cpu_us": (time.process_time() - c0) / steps * 1e6,
           "contacts": int(data.ncon)}
    for name in TIMERS:
        out[name.lower() + "_us"] = data.timer[int(getattr(mujoco.mjtTimer, "mjTIMER_" + name))].duration / steps * 1e6
    return out


def run(task: str, rows: list[int], steps: int) -> dict:
    """Plane reference, then every (row, type) tile centre of ``task``'s terrain."""
    spec = load_task(task)
    cfg = dataclass_from_dict(TerrainConfig, spec.section("terrain"), spec, "terrain")
    model, terrain = build_scene(cfg)
    plane = mujoco.MjModel.from_xml_path(str(C.SCENE_PATH))
    result = {"task": task, "ngeom": int(model.ngeom), "plane": step_cost(plane, 0.0, 0.0, 0.0, steps), "tiles": []}
    with progress(total=len(rows) * len(cfg.types), desc=f"{task} tiles", unit="tile") as bar:
        for row in rows:
            for col, kind in enumerate(cfg.types):
                x, y, z = terrain.tile_origins_w[min(row, terrain.num_rows - 1), col]
                result["tiles"].append({"type": kind, "row": row, **step_cost(model, x, y, z, steps)})
                bar.update(1)
    return result


def markdown(result: dict) -> str:
    """The docs table: per tile type (mean over the measured rows) beside the plane."""
    lines = ["| ground | mj_step [us] | x plane | kinematics | broad phase | narrow phase | solver | contacts |",
             "|---|---|---|---|---|---|---|---|"]
    plane = result["plane"]

    def row(name: str, r: dict) -> str:
        return (f"| {name} | {r['step_us']:.1f} | {r['step_us'] / plane['step_us']:.1f} | "
                f"{r['pos_kinematics_us']:.1f} | "
                f"{r['col_broad_us']:.1f} | {r['col_narrow_us']:.1f} | {r['constraint_us']:.1f} | {r['contacts']} |")

    lines.append(row("plane", plane))
    for kind in dict.fromkeys(t["type"] for t in result["tiles"]):
        rs = [t for t in result["tiles"] if t["type"] == kind]
        mean = {k: float(np.mean([r[k] for r in rs])) for k in rs[0] if k not in ("type", "row")}
        mean["contacts"] = max(r["contacts"] for r in rs)
        lines.append(row(f"{kind} ({result['ngeom']} geoms)", mean))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict:
    parser = ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="rough")
    parser.add_argument("--rows", type=int, nargs="+", default=[0, 5])
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument("--out", type=Path, default=Path("results/bench"))
    args = parser.parse_args(argv)
    result = run(args.task, args.rows, args.steps)
    result["machine"] = {"cpu": cpu_model(), "cores": os.cpu_count(),
                         "load_avg": os.getloadavg(), "mujoco": mujoco.__version__}
    args.out.mkdir(parents=True, exist_ok=True)
    write_json(result, args.out / "terrain_step.json")
    print(markdown(result))
    return result


if __name__ == "__main__":
    run_cli(main)  # a bad flag or a user error: one line, exit 2; Ctrl-C: one line, exit 130

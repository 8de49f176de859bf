"""Short, fixed simulator runs whose trajectories on the ``cpu`` backend are committed as references.

The GPU check (``bench/gpu_check.py``) runs the same scenarios on ``cuda`` (or ``warp-cpu``) and reports how far
each trajectory is from the reference: the check that the GPU simulates the same robots, with no CPU backend
and no Pinocchio on the GPU machine. Each scenario drives the backend directly (no env, no RNG on the device):

* ``standing`` -- 3 robots on the standing references for 1 s (the ground carries the weight);
* ``trot`` -- the balance controller's trot at 0.4 m/s from a noisy home pose, 1 s (closed loop, 100 Hz);
* ``push`` -- trotting in place for 0.5 s: +5 kg trunk mass (robot 0), a 60 N lateral force (robots 1, 3),
  a 0.8 m/s sideways push (robot 2, 0.2 s), foot friction 0.05 (robot 3);
* ``rough`` -- one robot standing on each tile type of a small rough terrain (rugged height field, slopes,
  boxes, stairs), off the flat spawn platform, for 0.3 s.

Each returns ``(T, N, 19)``: base position [m], quaternion (w, x, y, z) and joint positions [rad] after each
control step. Tolerances (:data:`TOLERANCES`) are those of ``tests/sim/test_warp_backend.py`` for the flat
scenarios (MuJoCo Warp is float32 and its solver is MuJoCo's algorithm, not its bits); rough terrain,
where a robot may slide or topple, gets a looser one.

``python -m dls_quadruped.bench.reference_runs`` (re)writes :data:`REFERENCE_PATH`: every scenario on ``cpu`` and
on ``warp-cpu`` (keys ``"<backend>/<scenario>"``).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import mujoco
import numpy as np
import torch

from dls_quadruped.cli import ArgumentParser, run_cli
from dls_quadruped.control.action_config import LatentActionConfig
from dls_quadruped.control.balance import BalanceController
from dls_quadruped.control.latent_action import (
    clip,
    flat_ground,
    to_world,
)
from dls_quadruped.core.rotations import quat_to_rotmat, rpy_from_rotmat
from dls_quadruped.robots.aliengo import constants as C
from dls_quadruped.sim.interface import SimBackend, SimConfig
from dls_quadruped.sim.registry import make_backend
from dls_quadruped.sim.terrain import TerrainConfig, build_scene

REFERENCE_PATH = Path(__file__).with_name("reference_runs.npz")
"""The committed ``cpu`` trajectories (a few hundred kB)."""

TOLERANCES: dict[str, tuple[float, float, float]] = {
    # (base position [m], quaternion, joints [rad]), max over time and robots
    "standing": (1e-4, 1e-4, 1e-3),
    "trot": (1e-4, 1e-4, 1e-3),
    "push": (1e-3, 1e-3, 5e-2),
    "rough": (2e-2, 0.3, 1.0),
}
"""The rough tolerance is coarse on purpose: on the rugged height field MuJoCo C and MuJoCo Warp generate
different contacts (measured on ``warp-cpu`` against ``cpu``: 1.5 cm and 0.8 rad at a knee within 0.3 s, every
other tile within 4e-4 m), so ``compare`` also reports each robot's (tile's) deviation, and the references hold
a ``warp-cpu`` run too: the GPU's trajectories against the same algorithm's on the CPU."""

ROUGH_TERRAIN = TerrainConfig(types=("rugged", "slope_up", "slope_down", "boxes", "stairs_up", "stairs_down"),
                              num_rows=2, step_height=(0.05, 0.15))


def _home(num: int, seed: int, noise: float) -> dict[str, torch.Tensor]:
    gen = torch.Generator().manual_seed(seed)
    joint = torch.as_tensor(C.NOMINAL_JOINT_POS, dtype=torch.float64).expand(num, 12).clone()
    joint += noise * (2 * torch.rand(num, 12, generator=gen, dtype=torch.float64) - 1)
    pos = torch.tensor([0.0, 0.0, C.STANDING_BASE_HEIGHT + 0.005], dtype=torch.float64).expand(num, 3).clone()
    quat = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=torch.float64).expand(num, 4).clone()
    return {"base_pos_w": pos, "base_quat_w": quat, "joint_pos": joint}


def _record(state) -> torch.Tensor:
    s = state.to("cpu")
    return torch.cat([s.base_pos_w, s.base_quat_w, s.joint_pos], 1).clone()


def _trot(sim: SimBackend, steps: int, cmd: tuple[float, float, float], noise: float,
          events: Callable[[int, SimBackend], None] | None = None) -> np.ndarray:
    """The balance controller's closed-loop gait: ``steps`` control steps of 2 physics steps (100 Hz)."""
    n = sim.num_envs
    ctrl, acfg = BalanceController(), LatentActionConfig()
    command = torch.tensor([cmd], dtype=torch.float64).expand(n, 3)
    state = sim.reset(torch.arange(n), **_home(n, 0, noise)).to("cpu")
    out = []
    for k in range(steps):
        if events is not None:
            events(k, sim)
        action, _ = clip(ctrl(state, command), acfg)
        yaw = rpy_from_rotmat(quat_to_rotmat(state.base_quat_w.double()))[:, 2]
        p_td_w, F_w = to_world(action, state.base_pos_w.double(), yaw, flat_ground, acfg)
        sim.set_references(action.f, action.d, p_td_w, F_w)
        state = sim.step(2).to("cpu")
        out.append(_record(state))
    return torch.stack(out).numpy()


def standing(backend: str, cfg: SimConfig) -> np.ndarray:
    with make_backend(backend, mujoco.MjModel.from_xml_path(str(C.SCENE_PATH)), 3, cfg) as sim:
        return torch.stack([_record(sim.step(4)) for _ in range(50)]).numpy()


def trot(backend: str, cfg: SimConfig) -> np.ndarray:
    with make_backend(backend, mujoco.MjModel.from_xml_path(str(C.SCENE_PATH)), 3, cfg) as sim:
        return _trot(sim, 100, (0.4, 0.0, 0.3), noise=0.05)


def push(backend: str, cfg: SimConfig) -> np.ndarray:
    model = mujoco.MjModel.from_xml_path(str(C.SCENE_PATH))
    feet = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, g) for g in C.FOOT_GEOM_NAMES]
    trunk = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, C.BASE_BODY_NAME)

    def events(k: int, sim: SimBackend) -> None:
        if k == 0:
            sim.set_model_field("geom_friction", [3], torch.tensor([[[0.05, 0.02, 0.01]] * 4]), index=feet)
            mass = torch.as_tensor(model.body_mass).clone()[None]
            mass[0, trunk] += 5.0
            sim.set_model_field("body_mass", [0], mass)
        if k == 10:
            sim.set_external_wrench([1, 3], torch.tensor([[0.0, 60.0, 0.0]] * 2), torch.zeros(2, 3))
        if k == 20:
            sim.set_base_velocity([2], torch.tensor([[0.0, 0.8, 0.0]]))

    with make_backend(backend, model, 4, cfg) as sim:
        return _trot(sim, 50, (0.0, 0.0, 0.0), noise=0.0, events=events)


def rough(backend: str, cfg: SimConfig) -> np.ndarray:
    model, terrain = build_scene(ROUGH_TERRAIN)
    origins = torch.as_tensor(terrain.tile_origins_w[1], dtype=torch.float64)  # (num_types, 3), harder row
    n = len(origins)
    xy = origins[:, :2] + torch.tensor([1.6, 0.4], dtype=torch.float64)  # off the 2 m platform
    z = terrain.height_at(xy[:, 0], xy[:, 1]).double()
    home = _home(n, 0, 0.0)
    home["base_pos_w"] = torch.cat([xy, (z + C.STANDING_BASE_HEIGHT + 0.02)[:, None]], 1)
    with make_backend(backend, model, n, cfg) as sim:
        sim.reset(torch.arange(n), **home)
        return torch.stack([_record(sim.step(2)) for _ in range(30)]).numpy()


SCENARIOS: dict[str, Callable[[str, SimConfig], np.ndarray]] = {
    "standing": standing, "trot": trot, "push": push, "rough": rough}


def compare(name: str, traj: np.ndarray, ref: np.ndarray) -> dict:
    """Largest deviation of ``traj`` from ``ref`` per part, and whether each is within :data:`TOLERANCES`."""
    if traj.shape != ref.shape:
        return {"ok": False, "error": f"shape {traj.shape} != reference {ref.shape}"}
    err = np.abs(traj.astype(np.float64) - ref.astype(np.float64))
    parts = {"base_pos_m": err[..., 0:3], "quat": err[..., 3:7], "joints_rad": err[..., 7:]}
    out: dict = {k: float(np.nanmax(v)) if np.isfinite(v).all() else float("inf") for k, v in parts.items()}
    out["final_base_pos_m"] = float(err[-1, :, 0:3].max())
    out["per_robot_base_pos_m"] = [float(x) for x in err[..., 0:3].max(axis=(0, 2))]
    out["tolerance"] = dict(zip(parts, TOLERANCES[name]))
    out["ok"] = all(out[k] <= tol for k, tol in zip(parts, TOLERANCES[name]))
    return out


def main(argv: list[str] | None = None) -> None:
    p = ArgumentParser(prog="dls_quadruped.bench.reference_runs", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, default=REFERENCE_PATH)
    p.add_argument("--backends", nargs="+", default=["cpu", "warp-cpu"])
    args = p.parse_args(argv)
    cfg = SimConfig(num_workers=0, nthread=1)
    arrays = {}
    for backend in args.backends:
        for name, run in SCENARIOS.items():
            arrays[f"{backend}/{name}"] = a = run(backend, cfg).astype(np.float32)
            print(f"[reference_runs] {backend} {name}: {a.shape}", flush=True)
    tmp = args.out.with_suffix(".tmp.npz")
    np.savez_compressed(tmp, **arrays)
    tmp.replace(args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    run_cli(main)

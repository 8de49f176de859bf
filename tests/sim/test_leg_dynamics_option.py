"""``SimConfig.leg_dynamics = "mujoco"`` (issue 25): the cpu backend's leg terms from MuJoCo's own mass matrix and
bias forces (a persistent ``Batch`` stepping with ``stage=mjSTAGE_VEL``) + ``TorchLegDynamics``, beside the default
Pinocchio terms.

Tolerances (float64 shard state and torques, standing then trotting in place on the plane):

* the first 10 physics steps: |qpos, qvel| and |torque| within 1e-9 of the Pinocchio path (observed <= 9e-13: the
  two term builders agree to round-off, tests/control/test_torch_dynamics.py, and the physics given the same
  torques is the same MuJoCo step);
* after 1 s (200 physics steps): within 1e-6 (observed 7e-13 N m and 9e-13 on the state; round-off grows through
  contacts, and on rough terrain a chaotic robot amplifies a 1e-13 perturbation to metres within a second, with
  either term builder, so the terrain-regions test compares the new path with itself on the whole terrain).
"""

from __future__ import annotations

from dataclasses import fields

import mujoco
import numpy as np
import pytest
import torch

from dls_quadruped.control.balance import BalanceController
from dls_quadruped.control.latent_action import (
    LatentActionConfig,
    clip,
    flat_ground,
    to_world,
)
from dls_quadruped.core.state import RobotState
from dls_quadruped.eval.balance_run import _yaw
from dls_quadruped.robots.aliengo import constants as C
from dls_quadruped.sim.cpu_backend import VecSim
from dls_quadruped.sim.interface import LEG_DYNAMICS, SimConfig, home_state
from dls_quadruped.sim.regions import RegionConfig
from dls_quadruped.sim.terrain import TerrainConfig, build_scene

N = 4


@pytest.fixture(scope="module")
def model() -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_path(str(C.SCENE_PATH))


def _drive(sim: VecSim, steps: int, trot_after: int, record=None) -> list[RobotState]:
    """Stand for ``trot_after`` physics steps, then trot in place with the balance controller;
    one physics step per call. ``record(sim)`` is called after every step."""
    ctrl, acfg = BalanceController(), LatentActionConfig()
    cmd = torch.zeros(sim.num_envs, 3, dtype=torch.float64)
    state = sim.state
    out = []
    for k in range(steps):
        action, _ = clip(ctrl(state, cmd, stand=k < trot_after), acfg)
        p_td_w, F_w = to_world(action, state.base_pos_w.double(), _yaw(state), flat_ground, acfg)
        sim.set_references(action.f, action.d, p_td_w, F_w)
        state = sim.step(1)
        out.append(state.clone())
        if record is not None:
            record(sim)
    return out


def _shard_run(model, leg_dynamics: str, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """(steps, N, 37) float64 qpos+qvel and (steps, N, 12) torques of an in-process run."""
    states, taus = [], []

    def record(sim):
        sh = sim._shard
        states.append(np.concatenate([sh.qpos, sh.qvel], axis=1).copy())
        taus.append(sh.tau.numpy().copy())

    with VecSim(model, N, SimConfig(num_workers=0, leg_dynamics=leg_dynamics)) as sim:
        sim.reset(torch.arange(N), **home_state(N, 0, 0.05))
        _drive(sim, steps, trot_after=steps // 2, record=record)
    return np.stack(states), np.stack(taus)


def test_bad_value_is_a_one_line_error():
    with pytest.raises(ValueError) as err:
        SimConfig(leg_dynamics="rbdl")
    msg = str(err.value)
    assert "\n" not in msg and "'rbdl'" in msg and all(k in msg for k in LEG_DYNAMICS)
    assert SimConfig().leg_dynamics == "pinocchio" and tuple(LEG_DYNAMICS) == ("pinocchio", "mujoco")


def test_scene_key_reaches_the_backend_and_is_validated():
    from dls_quadruped.envs.config import load_task
    from dls_quadruped.envs.env import LocomotionEnv

    with pytest.raises(ValueError) as err:
        LocomotionEnv(load_task("base", overrides={"scene": {"num_workers": 0, "leg_dynamics": "nope"}}),
                      num_envs=2, verbose=False)
    assert "scene.leg_dynamics" in str(err.value) and "pinocchio" in str(err.value)
    env = LocomotionEnv(load_task("base", overrides={"scene": {"num_workers": 0, "leg_dynamics": "mujoco"}}),
                        num_envs=2, verbose=False)
    try:
        assert env.scene.sim.cfg.leg_dynamics == "mujoco" and env.scene.sim._shard.batch.persistent
        for _ in range(3):
            obs, rew, _, _ = env.step(torch.zeros(2, 28))
            assert torch.isfinite(obs["policy"]).all() and torch.isfinite(rew).all()
    finally:
        env.close()


def test_matches_pinocchio_to_round_off_standing_and_trotting(model):
    """1 s: 0.5 s standing, 0.5 s trotting in place; float64 state and torques against the Pinocchio path."""
    steps = 200
    qa, ta = _shard_run(model, "pinocchio", steps)
    qb, tb = _shard_run(model, "mujoco", steps)
    assert np.isfinite(qb).all() and qa[-1, :, 2].min() > 0.3  # standing up, not fallen
    assert np.abs(qb[:10] - qa[:10]).max() <= 1e-9
    assert np.abs(tb[:10] - ta[:10]).max() <= 1e-9
    assert np.abs(qb - qa).max() <= 1e-6
    assert np.abs(tb - ta).max() <= 1e-6
    assert np.abs(tb).max() > 1.0  # the torques compared are real ones


@pytest.mark.parametrize("workers", [0, 2])
def test_worker_count_does_not_change_the_run(model, workers):
    """num_workers 0 and 2 on the new path give the same published states, and those of the Pinocchio path to
    the float32 buffers' resolution."""
    runs = {}
    for ld, w in (("mujoco", workers), ("mujoco", 0), ("pinocchio", 0)):
        if (ld, w) in runs:
            continue
        with VecSim(model, N, SimConfig(num_workers=w, leg_dynamics=ld)) as sim:
            sim.reset(torch.arange(N), **home_state(N, 1, 0.05))
            runs[(ld, w)] = _drive(sim, 40, trot_after=10)
    for x, y, z in zip(runs[("mujoco", workers)], runs[("mujoco", 0)], runs[("pinocchio", 0)]):
        for f in fields(RobotState):
            a, b, c = getattr(x, f.name), getattr(y, f.name), getattr(z, f.name)
            assert torch.equal(a, b), f.name
            torch.testing.assert_close(a, c, rtol=0, atol=1e-4, msg=f.name)


def test_terrain_regions_and_per_robot_mass(model):
    """On a small tiled terrain with regions, robots pushed across cell and tile borders (their model switches
    mid-run) with per-robot friction and mass move as on the whole terrain (same tolerance as
    tests/sim/test_regions.py); the controller's leg terms follow a robot's changed body_mass."""
    cfg = TerrainConfig(types=("flat", "rugged", "stairs_up"), num_rows=1, tile_size=4.0, border=1.0, platform=1.0,
                        step_height=(0.05, 0.1), step_width=0.4, seed=3)
    full, terrain = build_scene(cfg)
    pos, vel = [], []
    for col in range(len(cfg.types)):
        x, y, z = terrain.tile_origins_w[0, col]
        pos.append([x, y, z + C.STANDING_BASE_HEIGHT + 0.01])
        vel.append([0.0, 0.0, 0.0])
        for dx, dy in ((0.8, 0.0), (0.0, 1.85)):
            p = (x + dx, y + dy)
            pos.append([*p, float(terrain.height_at(torch.tensor([p[0]]), torch.tensor([p[1]]))[0])
                        + C.STANDING_BASE_HEIGHT + 0.03])
            vel.append([1.5 * np.sign(dx), 1.5 * np.sign(dy), 0.0])
    pos, vel = np.array(pos), np.array(vel)
    n = len(pos)
    feet = [mujoco.mj_name2id(full, mujoco.mjtObj.mjOBJ_GEOM, g) for g in C.FOOT_GEOM_NAMES]
    thigh = mujoco.mj_name2id(full, mujoco.mjtObj.mjOBJ_BODY, "FL_thigh")

    def run(regions):
        with VecSim(full, n, SimConfig(num_workers=0, regions=regions, leg_dynamics="mujoco")) as sim:
            nominal = sim._shard._terms
            fr = np.repeat(full.geom_friction[None, feet], n, axis=0)
            fr[:, :, 0] = np.linspace(0.4, 0.8, n)[:, None]
            sim.set_model_field("geom_friction", torch.arange(n), fr, index=feet)
            mass = np.repeat(full.body_mass[None], n, axis=0)
            mass[:, 1] *= np.linspace(0.9, 1.1, n)
            mass[0, thigh] *= 1.5
            sim.set_model_field("body_mass", torch.arange(n), mass)
            changed = sim._shard._terms
            # the 50 % heavier FL thigh of robot 0 shows in its FL leg's M block and bias at once; the trunk masses
            # (+-10 %) leave the leg terms alone but for round-off (MuJoCo works about the subtree's centre of mass)
            assert (changed.M_leg[0, 0] - nominal.M_leg[0, 0]).abs().max() > 1e-3
            assert (changed.h_leg[0, 0] - nominal.h_leg[0, 0]).abs().max() > 1e-2
            torch.testing.assert_close(changed.M_leg[1:], nominal.M_leg[1:], rtol=0, atol=1e-12)
            torch.testing.assert_close(changed.M_leg[0, 1:], nominal.M_leg[0, 1:], rtol=0, atol=1e-12)
            quat = torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(n, 1)
            joints = torch.as_tensor(C.NOMINAL_JOINT_POS).repeat(n, 1)
            sim.reset(torch.arange(n), torch.as_tensor(pos), quat, joints, base_lin_vel_w=torch.as_tensor(vel))
            return [sim.step(4).clone() for _ in range(15)]

    whole = run(None)
    region = run(RegionConfig(cfg))
    cells = RegionConfig(cfg).build(full).grid.cells
    start, end = whole[0].base_pos_w.numpy(), whole[-1].base_pos_w.numpy()
    assert (cells(start[:, 0], start[:, 1]) != cells(end[:, 0], end[:, 1])).sum() >= 3  # models switched
    for a, b in zip(whole, region):
        for k in ("base_pos_w", "joint_pos", "foot_force_w", "base_contact"):
            torch.testing.assert_close(getattr(b, k), getattr(a, k), rtol=0, atol=1e-5, msg=k)


def test_snapshot_restore_is_bit_identical(model):
    """After standing, trotting, a push and a per-robot mass, a snapshot restored into the same backend and into a
    fresh one (given the same model values) gives the next steps bit for bit on the new path."""
    cfg = SimConfig(num_workers=0, leg_dynamics="mujoco")
    mass = np.repeat(model.body_mass[None], N, axis=0)
    mass[2] *= 1.2

    with VecSim(model, N, cfg) as sim:
        sim.reset(torch.arange(N), **home_state(N, 2, 0.05))
        sim.set_model_field("body_mass", torch.arange(N), mass)
        _drive(sim, 30, trot_after=10)
        sim.set_base_velocity([1], torch.tensor([[0.4, 0.0, 0.0]]))
        snap = sim.snapshot()
        first = _drive(sim, 12, trot_after=0)
        sim.restore(snap)
        again = _drive(sim, 12, trot_after=0)
    with VecSim(model, N, cfg) as fresh:
        fresh.set_model_field("body_mass", torch.arange(N), mass)
        _drive(fresh, 3, trot_after=3)  # another state and other derived stages before the restore
        fresh.restore(snap)
        other = _drive(fresh, 12, trot_after=0)
    for run in (again, other):
        for x, y in zip(first, run):
            for f in fields(RobotState):
                assert torch.equal(getattr(x, f.name), getattr(y, f.name)), f.name

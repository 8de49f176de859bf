"""Vectorised backend + low-level controller: physical behaviour, equalities, bad input."""

from __future__ import annotations

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
from dls_quadruped.eval.balance_run import _yaw, run_balance
from dls_quadruped.robots.aliengo import constants as C
from dls_quadruped.sim.cpu_backend import SimConfig, VecSim
from dls_quadruped.sim.interface import home_state


@pytest.fixture(scope="module")
def model() -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_path(str(C.SCENE_PATH))


def _rollout(model, num_envs, steps, cfg, seed=0, noise=0.05, init_lin_vel=None):
    """Trot in place with the balance controller; returns stacked base poses and joint positions."""
    ctrl, acfg = BalanceController(), LatentActionConfig()
    cmd = torch.zeros(num_envs, 3, dtype=torch.float64)
    out = []
    with VecSim(model, num_envs, cfg) as sim:
        state = sim.reset(torch.arange(num_envs), **home_state(num_envs, seed, noise), base_lin_vel_w=init_lin_vel)
        for _ in range(steps):
            action, _ = clip(ctrl(state, cmd), acfg)
            p_td_w, F_w = to_world(action, state.base_pos_w.double(), _yaw(state), flat_ground, acfg)
            sim.set_references(action.f, action.d, p_td_w, F_w)
            state = sim.step(2)
            out.append(torch.cat([state.base_pos_w, state.base_quat_w, state.joint_pos, state.foot_pos_w.flatten(1)],
                                 1))
        return torch.stack(out), state.diverged.clone()


@pytest.mark.slow  # default suite under 10 min on 2 cores (make test-all runs it)
def test_64_robots_stand_then_trot_in_place():
    """Issue 2 acceptance: 10 s standing + 10 s trotting, height +-3 cm, |roll|,|pitch| < 0.1, feet lift >= 3 cm."""
    run = run_balance(num_envs=64, stand_seconds=10.0, trot_seconds=10.0)
    s = run.summary
    assert s["num_fallen"] == 0
    for phase in ("stand", "trot"):
        assert s[f"{phase}_height_err_max"] < 0.03, s
        assert s[f"{phase}_roll_abs_max"] < 0.1, s
        assert s[f"{phase}_pitch_abs_max"] < 0.1, s
    assert s["trot_min_foot_lift"] >= 0.03, s
    # the trot really alternates: both diagonal pairs spend time in swing, and stance carries the weight
    contact = run.contact_cmd[run.trotting]
    assert 0.5 < contact.mean() < 0.7  # duty 0.6
    total_fz = run.foot_force_z[~run.trotting].sum(axis=-1)
    np.testing.assert_allclose(total_fz.mean(), C.WEIGHT, rtol=0.05)


def test_worker_processes_match_in_process(model):
    a, _ = _rollout(model, 4, 30, SimConfig(num_workers=0))
    b, _ = _rollout(model, 4, 30, SimConfig(num_workers=2))
    torch.testing.assert_close(a, b, rtol=0, atol=1e-6)


def test_same_seed_same_run_and_different_seed_differs(model):
    a, _ = _rollout(model, 3, 20, SimConfig(num_workers=0), seed=1)
    b, _ = _rollout(model, 3, 20, SimConfig(num_workers=0), seed=1)
    c, _ = _rollout(model, 3, 20, SimConfig(num_workers=0), seed=2)
    assert torch.equal(a, b)
    assert not torch.equal(a, c)


def test_batched_equals_single_robot(model):
    batched, _ = _rollout(model, 3, 20, SimConfig(num_workers=0), seed=3)
    init = home_state(3, 3, 0.05)
    for i in range(3):
        ctrl, acfg = BalanceController(), LatentActionConfig()
        with VecSim(model, 1, SimConfig(num_workers=0)) as sim:
            state = sim.reset(torch.arange(1), **{k: v[i : i + 1] for k, v in init.items()})
            for k in range(20):
                action, _ = clip(ctrl(state, torch.zeros(1, 3, dtype=torch.float64)), acfg)
                p_td_w, F_w = to_world(action, state.base_pos_w.double(), _yaw(state), flat_ground, acfg)
                sim.set_references(action.f, action.d, p_td_w, F_w)
                state = sim.step(2)
                single = torch.cat([state.base_pos_w, state.base_quat_w, state.joint_pos, state.foot_pos_w.flatten(1)],
                                   1)
                torch.testing.assert_close(single[0], batched[k, i], rtol=0, atol=1e-6)


def test_diverged_robot_is_flagged_and_others_go_on(model):
    lin_vel = torch.zeros(3, 3, dtype=torch.float64)
    lin_vel[1, 2] = 5.0e3  # far beyond anything physical: robot 1 must be flagged
    traj, diverged = _rollout(model, 3, 10, SimConfig(num_workers=0), seed=4, init_lin_vel=lin_vel)
    assert diverged.tolist() == [False, True, False]
    assert torch.isfinite(traj).all()
    reference, ref_div = _rollout(model, 3, 10, SimConfig(num_workers=0), seed=4)
    assert not ref_div.any()
    torch.testing.assert_close(traj[:, [0, 2]], reference[:, [0, 2]], rtol=0, atol=0)


def test_reset_only_touches_selected_robots(model):
    with VecSim(model, 3, SimConfig(num_workers=0)) as sim:
        sim.reset(torch.arange(3), **home_state(3, 0, 0.0))
        state = sim.step(20).clone()
        init = home_state(1, 0, 0.0)
        init["base_pos_w"] = init["base_pos_w"] + torch.tensor([[1.0, 2.0, 0.0]], dtype=torch.float64)
        after = sim.reset(torch.tensor([1]), **init)
        assert torch.equal(after.base_pos_w[[0, 2]], state.base_pos_w[[0, 2]])
        torch.testing.assert_close(after.base_pos_w[1].double(), init["base_pos_w"][0], rtol=0, atol=1e-6)
        assert after.time[1] == 0 and after.time[0] > 0


def test_bad_references_raise_clear_errors(model):
    with VecSim(model, 2, SimConfig(num_workers=0)) as sim:
        ok = {"freq": torch.ones(2, 4), "duty": torch.full((2, 4), 0.6), "p_td_w": torch.zeros(2, 4, 3),
              "F_w": torch.zeros(2, 4, 3)}
        with pytest.raises(ValueError, match=r"freq must have shape \(2, 4\)"):
            sim.set_references(**{**ok, "freq": torch.ones(2, 3)})
        bad = ok["F_w"].clone()
        bad[1, 2, 0] = float("nan")
        with pytest.raises(ValueError, match=r"F_w has non-finite values in rows \[1\]"):
            sim.set_references(**{**ok, "F_w": bad})
        with pytest.raises(ValueError, match="num_physics_steps"):
            sim.step(0)


def test_external_wrench_pushes_the_base(model):
    """A constant lateral force on a standing robot moves it sideways, only in the targeted env."""
    with VecSim(model, 2, SimConfig(num_workers=0)) as sim:
        sim.reset(torch.arange(2), **home_state(2, 0, 0.0))
        sim.set_external_wrench(torch.tensor([0]), torch.tensor([[0.0, 60.0, 0.0]]), torch.zeros(1, 3))
        state = sim.step(60)
        assert state.base_lin_vel_w[0, 1] > 0.05
        assert abs(float(state.base_lin_vel_w[1, 1])) < 0.02


def test_balance_baseline_works_at_any_heading():
    """Attitude feedback lives in the yaw-aligned frame: robots facing any direction stand and trot."""
    yaw = torch.tensor([0.0, 1.5, 3.0, -2.0], dtype=torch.float64)
    run = run_balance(num_envs=4, stand_seconds=1.0, trot_seconds=2.0, yaw=yaw)
    assert run.summary["num_fallen"] == 0, run.summary
    assert run.summary["trot_roll_abs_max"] < 0.1 and run.summary["trot_pitch_abs_max"] < 0.1, run.summary
    q = run.qpos[-1, :, 3:7]
    final_yaw = 2 * np.arctan2(q[:, 3], q[:, 0])
    np.testing.assert_allclose(np.angle(np.exp(1j * (final_yaw - yaw.numpy()))), 0.0, atol=0.1)


@pytest.mark.parametrize("workers", [0, 2])
def test_model_field_rows_by_index_reach_only_those_envs_and_rows(model, workers):
    """``set_model_field(..., index=)`` writes only the given rows (the foot geoms) of the given envs:
    the feet of a robot with near-zero friction slide under a side push, the others' stay planted."""
    feet = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, g) for g in C.FOOT_GEOM_NAMES]
    with VecSim(model, 4, SimConfig(num_workers=workers)) as sim:
        sim.reset(torch.arange(4), **home_state(4, 0, 0.0))
        values = np.repeat(model.geom_friction[None, feet].copy(), 1, axis=0)
        values[..., 0] = 0.02
        sim.set_model_field("geom_friction", torch.tensor([2]), values, index=feet)
        if workers == 0:  # the per-sim field itself: env 2's foot rows changed, nothing else
            field = sim._shard.batch.expanded("geom_friction")
            assert (field[2, feet, 0] == 0.02).all() and (field[2, feet, 1:] == model.geom_friction[feet, 1:]).all()
            others = [g for g in range(model.ngeom) if g not in feet]
            assert (field[2, others] == model.geom_friction[others]).all()
            assert (field[[0, 1, 3]] == model.geom_friction).all()
        state = sim.step(1)
        sim.set_references(freq=torch.zeros(4, 4), duty=torch.ones(4, 4), p_td_w=state.foot_pos_w.clone().double(),
                           F_w=torch.tensor([0.0, 0.0, C.WEIGHT / 4]).expand(4, 4, 3).double())
        feet_y0 = state.foot_pos_w[..., 1].clone()
        # 60 N sideways on every base: feet with friction 0.8 hold, feet at 0.02 slide
        sim.set_external_wrench(torch.arange(4), torch.tensor([0.0, 60.0, 0.0]).expand(4, 3), torch.zeros(4, 3))
        for _ in range(50):
            state = sim.step(2)
        assert not state.diverged.any()
        slide = (state.foot_pos_w[..., 1] - feet_y0).mean(dim=1)
        # the 0.8-friction feet only roll a few cm as the body leans; identical envs move identically
        assert slide[2] > 0.15 and slide[[0, 1, 3]].abs().max() < 0.06, slide
        assert torch.allclose(slide[[0, 1, 3]], slide[0].expand(3), atol=1e-6)

"""Non-finite MPC inputs: each one sends only its robot to the fallback, named in ``reason``, and a
solve never returns a non-finite action with ``fallback = False``; non-finite sigmas are refused."""

from __future__ import annotations

import math

import pytest
import torch

from dls_quadruped.mpc import warm_start
from dls_quadruped.mpc.config import CostWeights, SamplerConfig
from dls_quadruped.mpc.sampler import SamplingMPC

B = 3
PHASE = torch.tensor([[0.0, 0.5, 0.5, 0.0]]).repeat(B, 1)
FIELDS = ("f", "d", "foot_target_w", "force_w", "p_h", "F_h", "best_encoded")


def _inputs(standing) -> dict:
    state, refs = standing(B)
    return {"state": state, "refs": refs, "phase": PHASE.clone(), "base_xy_w": torch.zeros(B, 2),
            "base_yaw": torch.zeros(B), "terrain_z_w": torch.zeros(B, 4)}


def _solve(mpc: SamplingMPC, inp: dict, cfg: SamplerConfig):
    return mpc.solve(inp["state"], inp["refs"], [warm_start.nominal_trot(B, cfg)], phase=inp["phase"],
                     base_xy_w=inp["base_xy_w"], base_yaw=inp["base_yaw"], terrain_z_w=inp["terrain_z_w"])


def _poison(inp: dict, name: str, robot: int, value: float) -> None:
    if name.startswith("refs."):
        getattr(inp["refs"], name.split(".")[1])[robot].view(-1)[0] = value
    else:
        inp[name][robot].view(-1)[-1] = value


def _assert_finite_unless_fallback(r) -> None:
    for name in FIELDS:
        rows = torch.isfinite(getattr(r, name)).reshape(B, -1).all(dim=1)
        assert (rows | r.fallback).all(), f"{name} not finite without fallback"


@pytest.mark.parametrize("kernel", ["reference", "cpp"])
@pytest.mark.parametrize("name", ["phase", "base_xy_w", "base_yaw", "terrain_z_w", "refs.com_height_w",
                                  "refs.lin_vel_w", "refs.yaw_rate", "refs.foothold_w"])
@pytest.mark.parametrize("value", [math.nan, math.inf])
def test_non_finite_input_falls_back_for_that_robot_only(name, value, kernel, standing):
    cfg = SamplerConfig(num_samples=64, horizon=4, kernel=kernel)
    mpc = SamplingMPC(cfg, seed=0)
    first = _solve(mpc, _inputs(standing), cfg)
    inp = _inputs(standing)
    _poison(inp, name, 1, value)
    r = _solve(mpc, inp, cfg)
    assert r.fallback.tolist() == [False, True, False]
    assert f"{name} of robots [1] is not finite" in r.reason and "previous solution" in r.reason
    assert torch.equal(r.force_w[1], first.force_w[1])
    _assert_finite_unless_fallback(r)
    twin = SamplingMPC(cfg, seed=0)  # same seeds, clean inputs: robots 0 and 2 must not notice robot 1
    _solve(twin, _inputs(standing), cfg)
    clean = _solve(twin, _inputs(standing), cfg)
    assert torch.equal(r.best_index[[0, 2]], clean.best_index[[0, 2]])
    assert torch.equal(r.force_w[[0, 2]], clean.force_w[[0, 2]])


def test_random_poisoning_never_leaks_a_non_finite_action(standing):
    cfg = SamplerConfig(num_samples=64, horizon=4, kernel="reference")
    mpc = SamplingMPC(cfg, seed=0)
    gen = torch.Generator().manual_seed(0)
    names = ["phase", "base_xy_w", "base_yaw", "terrain_z_w", "refs.com_height_w", "refs.lin_vel_w",
             "refs.yaw_rate", "refs.foothold_w"]
    for _ in range(20):
        inp = _inputs(standing)
        for robot in range(B):
            if torch.rand((), generator=gen) < 0.5:
                name = names[int(torch.randint(len(names), (), generator=gen))]
                _poison(inp, name, robot, [math.nan, math.inf, -math.inf][int(torch.randint(3, (), generator=gen))])
        r = _solve(mpc, inp, cfg)
        _assert_finite_unless_fallback(r)


def test_first_solve_with_a_bad_reference_uses_the_warm_start(standing):
    cfg = SamplerConfig(num_samples=64, horizon=4, kernel="reference")
    inp = _inputs(standing)
    _poison(inp, "refs.lin_vel_w", 0, math.nan)
    r = _solve(SamplingMPC(cfg), inp, cfg)
    assert r.fallback.tolist() == [True, False, False] and "first warm start" in r.reason
    _assert_finite_unless_fallback(r)
    assert torch.isfinite(r.force_w).all()


@pytest.mark.parametrize("name", ["sigma_f", "sigma_d", "sigma_p", "sigma_F", "dt", "mpc_period"])
@pytest.mark.parametrize("value", [math.inf, math.nan])
def test_non_finite_sigmas_and_periods_are_refused(name, value):
    with pytest.raises(ValueError, match=f"SamplerConfig.{name} must be"):
        SamplerConfig(**{name: value})


def test_non_finite_cost_weight_is_refused():
    with pytest.raises(ValueError, match="CostWeights.yaw_rate must be >= 0 and finite"):
        CostWeights(yaw_rate=math.inf)

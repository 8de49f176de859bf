"""``mpc/solve_inputs.py``: the solve's argument checks, and the torch path's cleaning of the per-robot inputs, by
hand and against the fused solve's C++ cleaning of the same inputs."""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch

from dls_quadruped.mpc import solve_inputs, warm_start
from dls_quadruped.mpc.config import SamplerConfig
from dls_quadruped.mpc.encodings import encoded_dim
from dls_quadruped.mpc.samples import group_layout
from dls_quadruped.mpc.solve_glue import INPUT_WIDTHS, FusedSolve
from dls_quadruped.mpc.srbd import robot_srbd_model

CFG = SamplerConfig(num_samples=8, horizon=4)
DIM = encoded_dim(CFG.encoding)


def _validate(state, refs, warm_starts, proportions=None, phase=None):
    phase = torch.zeros(state.batch_size, 4) if phase is None else phase
    return solve_inputs.validate(CFG, DIM, torch.device("cpu"), state, refs, warm_starts, proportions, phase)


def test_validate_stacks_the_warm_starts_and_names_what_is_wrong(standing):
    state, refs = standing(3)
    trot = warm_start.nominal_trot(3, CFG)
    ws, props = _validate(state, refs, [trot, trot[0]], (0.25, 0.75))  # a (D,) warm start is broadcast
    assert ws.shape == (3, 2, DIM) and props == (0.25, 0.75) and torch.equal(ws[:, 1], trot[0].expand(3, DIM))
    assert _validate(state, refs, [trot])[1] == (1.0,)
    with pytest.raises(ValueError, match=rf"warm_starts\[1\] must have shape \(B, D\) = \(3, {DIM}\)"):
        _validate(state, refs, [trot, trot[:, :4]], (0.5, 0.5))
    with pytest.raises(ValueError, match=r"proportions must be >= 0 and sum to 1, got \(0.5, 0.6\)"):
        _validate(state, refs, [trot, trot], (0.5, 0.6))
    with pytest.raises(ValueError, match="proportions must be given"):
        _validate(state, refs, [trot, trot])
    with pytest.raises(ValueError, match=r"num_samples \(M = 8\) must be >= the number of warm starts \(9\)"):
        _validate(state, refs, [trot] * 9, [1 / 9] * 9)
    bad = trot.clone()
    bad[2, 0] = float("inf")
    with pytest.raises(ValueError, match=r"warm_starts\[0\] contains NaN/inf"):
        _validate(state, refs, [bad])
    with pytest.raises(ValueError, match="state must be an SRBDState"):
        solve_inputs.validate(CFG, DIM, torch.device("cpu"), refs, refs, [trot], None, torch.zeros(3, 4))


def _dirty(standing):
    """Three robots; robot 0's CoM velocity is NaN, robot 2's phase and yaw-rate reference are infinite."""
    state, refs = standing(3)
    euler = torch.tensor([[0.0, 0.0, 0.3], [0.1, -0.05, -1.2], [0.0, 0.0, 2.0]])
    state = dataclasses.replace(state, euler=euler, com_vel_w=state.com_vel_w.clone())
    state.com_vel_w[0, 1] = float("nan")
    refs = dataclasses.replace(refs, yaw_rate=refs.yaw_rate.clone())
    refs.yaw_rate[2] = float("inf")
    phase = torch.tensor([[0.1, 0.6, 0.6, 0.1], [0.2, 0.7, 0.7, 0.2], [0.3, float("inf"), 0.8, 0.3]])
    return state, refs, phase


def test_clean_zeroes_what_is_not_finite_and_flags_its_robot(standing):
    state, refs, phase = _dirty(standing)
    model = robot_srbd_model()
    x0, clean, refs_c, bad = solve_inputs.clean(state, refs, phase, (None, None, None), model, torch.device("cpu"))
    assert list(bad) == list(INPUT_WIDTHS)
    flagged = {name: flags.nonzero().flatten().tolist() for name, flags in bad.items() if flags.any()}
    assert flagged == {"state": [0], "phase": [2], "refs.yaw_rate": [2]}
    assert torch.equal(x0[0], torch.zeros(24)) and torch.equal(x0[1:], state.as_vector()[1:])  # the whole state row
    assert clean["phase"][2].tolist() == [pytest.approx(0.3), 0.0, pytest.approx(0.8), pytest.approx(0.3)]
    assert refs_c.yaw_rate.tolist() == [0.0, 0.0, 0.0]
    # the default frame: the state's yaw (0 for the zeroed robot), base = CoM - R(euler) c_b
    assert clean["base_yaw"].tolist() == pytest.approx([0.0, -1.2, 2.0])
    assert torch.equal(clean["terrain_z_w"], torch.zeros(3, 4))
    c_b = torch.tensor(model.com_offset_b, dtype=torch.float32)
    yaw = 2.0  # robot 2: flat, so R c_b is c_b turned by the yaw
    turned = (math.cos(yaw) * c_b[0] - math.sin(yaw) * c_b[1], math.sin(yaw) * c_b[0] + math.cos(yaw) * c_b[1])
    expected = (state.com_pos_w[2, 0] - turned[0], state.com_pos_w[2, 1] - turned[1])
    assert clean["base_xy_w"][2].tolist() == pytest.approx([float(v) for v in expected], abs=1e-6)
    assert torch.equal(clean["base_xy_w"][0], -c_b[:2])  # a zeroed state: CoM at the origin, level, yaw 0


def test_the_fused_cleaning_is_the_torch_cleaning_bit_for_bit(standing):
    fused = FusedSolve()
    if not fused.ready():
        pytest.skip("no C++ compiler: the fused solve is not available")
    state, refs, phase = _dirty(standing)
    model = robot_srbd_model()
    x0, clean, refs_c, bad = solve_inputs.clean(state, refs, phase, (None, None, None), model, torch.device("cpu"))
    ws = warm_start.nominal_trot(3, CFG)[:, None]
    group, perturb, _ = group_layout(CFG.num_samples, (1.0,))
    run = fused.costs(CFG, model, ws, group, perturb, torch.tensor(7), state, refs, phase, None, None, None)
    inp = run.inp
    for mine, theirs in ((x0, inp.x0), (clean["phase"], inp.phase), (clean["base_xy_w"], inp.base_xy_w),
                         (clean["base_yaw"], inp.base_yaw), (clean["terrain_z_w"], inp.terrain_z_w),
                         (refs_c.lin_vel_w, inp.refs.lin_vel_w), (refs_c.yaw_rate, inp.refs.yaw_rate),
                         (refs_c.foothold_w, inp.refs.foothold_w)):
        assert torch.equal(mine, theirs)
    assert all(torch.equal(bad[name], flags) for name, flags in FusedSolve.bad_inputs(run).items())

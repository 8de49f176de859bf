"""A horizon action scored by the MPC's model and cost: by hand, and against the sampler's own solve.

Hand case: a robot standing still with its CoM at 0.384 m, feet placed symmetrically about the CoM, all four legs in
stance for the whole horizon (f = 1.5 Hz, duty 0.9, phase 0: the phase reaches 0.27 < 0.9) and zero force offsets
(each leg carries m g / 4). The forces cancel gravity and their moments about the CoM cancel, so the state stays as
it is; with a zero command and a 0.404 m height reference only the height term costs, on each of the N steps:
J = N Q_z (0.384 - 0.404)^2 = 10 x 111 500 x 0.0004 = 446.

Cross-check: ``SamplingMPC.solve`` with one sample scores its warm start unperturbed (sample 0 of a group) with its
kernel and, with ``record_step_costs``, fills ``state_terms`` from the reference rollout; its full cost minus its
input part is the state cost :func:`score_horizon` computes with R = 0, whichever kernel each side uses (the C++
kernel and the eager reference rollout are two implementations of the SRBD and the cost).
"""

from __future__ import annotations

import math

import pytest
import torch

from dls_quadruped.control.action_config import LatentActionConfig
from dls_quadruped.core.state import RobotState
from dls_quadruped.mpc import cpp_kernel, warm_start
from dls_quadruped.mpc.baseline import BaselineConfig
from dls_quadruped.mpc.config import EncodingConfig, SamplerConfig
from dls_quadruped.mpc.encodings import decode, encode
from dls_quadruped.mpc.horizon import (
    TERM_NAMES,
    first_raw_action,
    horizon_sampler_config,
    score_horizon,
)
from dls_quadruped.mpc.inputs import heuristic_footholds_h, mpc_inputs
from dls_quadruped.mpc.sampler import SamplingMPC
from dls_quadruped.mpc.srbd import robot_srbd_model

ENC = EncodingConfig("first", "spline", 10)
CFG = horizon_sampler_config(ENC, 0.02, LatentActionConfig())


def _state(b: int, com_z: float, yaw: float = 0.0, vel_w=(0.0, 0.0, 0.0), phase: float = 0.0) -> RobotState:
    """B robots at rest (or moving at ``vel_w``), CoM at (0, 0, com_z), feet +-0.2 m, +-0.15 m about the CoM."""
    model = robot_srbd_model()
    c_b = torch.tensor(model.com_offset_b)
    quat = torch.tensor([[math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]]).expand(b, 4)
    rot_z = torch.tensor([[math.cos(yaw), -math.sin(yaw), 0.0], [math.sin(yaw), math.cos(yaw), 0.0], [0, 0, 1.0]])
    base = torch.tensor([0.0, 0.0, com_z]) - rot_z @ c_b  # base origin so that the CoM is at (0, 0, com_z)
    feet = torch.tensor([[0.2, 0.15, 0.02], [0.2, -0.15, 0.02], [-0.2, 0.15, 0.02], [-0.2, -0.15, 0.02]])
    z = torch.zeros(b)
    return RobotState(
        base_pos_w=base.expand(b, 3).clone(), base_quat_w=quat.clone(),
        base_lin_vel_w=torch.tensor([vel_w]).expand(b, 3),
        base_ang_vel_b=torch.zeros(b, 3), joint_pos=torch.zeros(b, 12), joint_vel=torch.zeros(b, 12),
        joint_torque=torch.zeros(b, 12), foot_pos_w=feet.expand(b, 4, 3).clone(), foot_vel_w=torch.zeros(b, 4, 3),
        foot_force_w=torch.zeros(b, 4, 3), phase=torch.full((b, 4), phase), contact_cmd=torch.ones(b, 4),
        base_contact=torch.zeros(b, dtype=torch.bool), time=z, diverged=torch.zeros(b, dtype=torch.bool))


def _raw(encoded: torch.Tensor) -> torch.Tensor:
    """The raw (student-unit) horizon whose MPC encoding is ``encoded`` (inverse of ``warm_start.from_student``)."""
    scale, shift = warm_start.student_to_mpc_map(CFG)
    return (encoded - shift) / scale


def _standing_horizon(b: int) -> torch.Tensor:
    """(B, D) MPC encoding: 1.5 Hz, duty 0.9, footholds nominal, zero force offsets."""
    a = torch.zeros(b, 10, 28)
    a[..., 0:4], a[..., 4:8] = 1.5, 0.9
    return encode(a, ENC)


@pytest.mark.parametrize("kernel", ["cpp", "reference"])
def test_standing_still_costs_the_height_error_alone_by_hand(kernel):
    if kernel == "cpp" and cpp_kernel.load() is None:
        pytest.skip("no C++ compiler for the MPC kernel")
    cfg = horizon_sampler_config(ENC, 0.02, LatentActionConfig(), kernel)
    score = score_horizon(_raw(_standing_horizon(2)), _state(2, 0.384), torch.zeros(2, 3), 0.404, cfg, terms=True)
    expected = 10 * 111500.0 * (0.384 - 0.404) ** 2  # 446
    torch.testing.assert_close(score.state_cost, torch.full((2,), expected), rtol=1e-4, atol=0)
    z = TERM_NAMES.index("z")
    torch.testing.assert_close(score.state_terms[:, z], torch.full((2,), expected), rtol=1e-4, atol=0)
    others = torch.cat([score.state_terms[:, :z], score.state_terms[:, z + 1:]], dim=1)
    assert float(others.abs().max()) < 1e-3  # nothing moves: velocity, attitude and rate terms ~0


def test_at_the_reference_height_standing_costs_nothing():
    """Neither the height nor any other term costs, and no input term: the footholds' R is 0."""
    score = score_horizon(_raw(_standing_horizon(1)), _state(1, 0.404), torch.zeros(1, 3), 0.404, CFG)
    assert float(score.state_cost[0]) < 1e-2


@pytest.mark.parametrize(("kernel", "mpc_kernel"), [("cpp", "reference"), ("reference", "cpp"), ("cpp", "cpp")])
def test_equals_the_mpc_solve_of_the_same_horizon(kernel, mpc_kernel):
    if cpp_kernel.load() is None:
        pytest.skip("no C++ compiler for the MPC kernel")
    gen = torch.Generator().manual_seed(3)
    b = 6
    state = _state(b, 0.39, yaw=0.4, vel_w=(0.3, -0.1, 0.05), phase=0.3)
    state.base_ang_vel_b[:] = 0.3 * torch.randn(b, 3, generator=gen)
    state.phase[:] = torch.rand(b, 4, generator=gen)
    raw = 0.3 * torch.randn(b, ENC_DIM, generator=gen)  # any student output
    command = torch.tensor([[0.5, -0.2, 0.3]]).expand(b, 3).clone()
    score = score_horizon(raw, state, command, 0.404, horizon_sampler_config(ENC, 0.02, LatentActionConfig(), kernel),
                          terms=True)

    mpc_cfg = SamplerConfig(num_samples=1, horizon=10, dt=0.02, kernel=mpc_kernel)
    mpc = SamplingMPC(mpc_cfg, seed=0)
    mpc.record_step_costs = True
    base = BaselineConfig(com_height=0.404, sampler=mpc_cfg)
    srbd, refs, frame = mpc_inputs(state, command, heuristic_footholds_h(state, command, base), 0.404, mpc_cfg,
                                   mpc.model)
    result = mpc.solve(srbd, refs, [warm_start.from_student(raw, mpc_cfg)], phase=state.phase, **frame)
    assert not bool(result.fallback.any())
    torch.testing.assert_close(score.state_cost, result.best_cost - result.best_input_cost, rtol=2e-4, atol=1e-2)
    assert float(result.best_input_cost.min()) > 1.0  # the solve's J has an input part, R = 0 took it out here
    torch.testing.assert_close(score.state_terms.sum(-1), score.state_cost, rtol=2e-4, atol=1e-2)
    torch.testing.assert_close(score.state_terms, result.state_terms, rtol=1e-4, atol=1e-3)
    assert float(score.state_cost.min()) > 1.0  # a moving, turning robot costs something: the check is not 0 == 0


ENC_DIM = 64


def test_first_raw_action_is_the_students_first_action():
    """Step 0 of the MPC's decoding of the raw horizon is the entry the student's ``first_action`` selects."""
    from dls_quadruped.learning.student import first_action_index

    raw = torch.randn(5, ENC_DIM, generator=torch.Generator().manual_seed(0))
    torch.testing.assert_close(first_raw_action(raw, ENC), raw.index_select(-1, first_action_index(ENC)))
    torch.testing.assert_close(first_raw_action(raw, ENC), decode(raw, ENC)[:, 0])


def test_bad_shape_is_named():
    with pytest.raises(ValueError, match=r"raw_horizon must have shape \(B, D\) = \(2, 64\)"):
        score_horizon(torch.zeros(2, 28), _state(2, 0.384), torch.zeros(2, 3), 0.404, CFG)


def test_terms_only_on_request():
    assert score_horizon(torch.zeros(1, ENC_DIM), _state(1, 0.384), torch.zeros(1, 3), 0.404, CFG).state_terms is None


def test_a_height_reference_out_of_range_is_named():
    with pytest.raises(ValueError, match="com_height"):
        score_horizon(torch.zeros(1, ENC_DIM), _state(1, 0.384), torch.zeros(1, 3), 4.04, CFG)

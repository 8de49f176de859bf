"""Forces sampled as offsets from gravity compensation (issue 12 item 1), in every kernel and the warm starts.

F_i(k) = c_i(k) (dF_i(k) + (0, 0, m g / max(sum_j c_j(k), 1))): a leg in swing gets zero force whatever its
parameters, a stance leg m g / (stance legs of that step) plus its offset. The naive warm start zeroes the
offsets of swing steps and shifts with the tail held.
"""

from __future__ import annotations

import pytest
import torch

from dls_quadruped.control.action_config import LatentActionConfig
from dls_quadruped.mpc import cpp_kernel, warm_start
from dls_quadruped.mpc.config import SamplerConfig
from dls_quadruped.mpc.cost import rollout_cost_reference
from dls_quadruped.mpc.encodings import decode_parts, encode, encoded_dim
from dls_quadruped.mpc.kernel import KernelInputs, fast_costs, reference_costs
from dls_quadruped.mpc.samples import (
    decode_samples,
    forces_from_offsets,
    group_layout,
    offsets_from_forces,
)
from dls_quadruped.mpc.srbd import robot_srbd_model

WEIGHT = LatentActionConfig().weight  # m g = 24.638 kg * 9.81 m/s^2 = 241.7 N


def test_forces_from_offsets_by_hand():
    act = LatentActionConfig()
    offset = torch.tensor([[1.0, 2.0, 3.0], [50.0, -40.0, 500.0], [-4.0, 5.0, -6.0], [7.0, 8.0, 9.0]])
    # FL, RL, RR in stance, FR swinging: m g / 3 each + offset; FR zero whatever its (large) parameters
    F = forces_from_offsets(offset, torch.tensor([True, False, True, True]), act)
    third = WEIGHT / 3  # 80.57 N
    expected = torch.tensor([[1.0, 2.0, third + 3.0], [0.0, 0.0, 0.0], [-4.0, 5.0, third - 6.0],
                             [7.0, 8.0, third + 9.0]])
    torch.testing.assert_close(F, expected)
    # all four down: m g / 4 = 60.4 N each; none down: no force at all (the shift's max(n, 1) keeps it finite)
    torch.testing.assert_close(forces_from_offsets(torch.zeros(4, 3), torch.ones(4, dtype=torch.bool), act)[:, 2],
                               torch.full((4,), WEIGHT / 4))
    assert torch.equal(forces_from_offsets(offset, torch.zeros(4, dtype=torch.bool), act), torch.zeros(4, 3))
    # inverse on stance legs, zero offset for the swing leg
    back = offsets_from_forces(F, torch.tensor([True, False, True, True]), act)
    torch.testing.assert_close(back, offset * torch.tensor([1.0, 0.0, 1.0, 1.0])[:, None])


def test_decoded_samples_zero_swing_force_and_share_the_weight():
    """decode_samples (the reference kernel's decode): the F block's offsets on top of m g / (stance legs of each
    step)."""
    cfg = SamplerConfig(num_samples=1, horizon=10, encoding_p="first", encoding_F="discrete")
    act = torch.zeros(1, 10, 28)
    act[..., 0:4], act[..., 4:8] = 1.5, 0.6
    act[..., 16 + 2::3] = torch.tensor([10.0, -20.0, 30.0, -40.0])  # F_z offsets per leg, every step
    act[..., 16 + 3 * 1] = 999.0  # FR's F_x offset: large, only felt while FR is down
    # phases: FL, RR at 0.55 (stance until 0.6, then swing), FR, RL at 0.05 (stance throughout 10 steps)
    phase = torch.tensor([[0.55, 0.05, 0.05, 0.55]])
    dec = decode_samples(encode(act, cfg.encoding)[:, None], phase, torch.zeros(1, 2), torch.zeros(1),
                         torch.zeros(1, 4), cfg)
    c = dec["contact"][0, 0]  # (N, 4): phase + k 1.5 * 0.02 = +0.03 per step
    assert c[0].tolist() == [True, True, True, True] and c[1].tolist() == [True, True, True, True]
    assert c[2].tolist() == [False, True, True, False]  # 0.55 + 0.06 = 0.61 >= 0.6: FL, RR lift off
    F = dec["F_h"][0, 0]  # (N, 4, 3)
    torch.testing.assert_close(F[0, :, 2], WEIGHT / 4 + torch.tensor([10.0, -20.0, 30.0, -40.0]))
    torch.testing.assert_close(F[5, :, 2], torch.tensor([0.0, WEIGHT / 2 - 20.0, WEIGHT / 2 + 30.0, 0.0]))
    assert torch.equal(F[5, 0], torch.zeros(3)) and torch.equal(F[5, 3], torch.zeros(3))
    # FR's F_x offset is clipped to the friction cone mu F_z (radially: F_y stays 0)
    torch.testing.assert_close(F[5, 1, 0], torch.tensor(0.5 * (WEIGHT / 2 - 20.0)))


def _single_sample_inputs(standing, ws: torch.Tensor, phase: torch.Tensor, seed: int = 5) -> KernelInputs:
    """Every kernel input for B robots with M = 16 samples; sample 0 is the warm start itself (perturb 0)."""
    b = ws.shape[0]
    state, refs = standing(b)
    x0 = state.as_vector()
    x0[:, 3] = 0.3  # moving forward
    x0[:, 9:12] = torch.tensor([0.1, -0.2, 0.05])  # rotating
    group, perturb, _ = group_layout(16, (1.0,))
    return KernelInputs(seed=torch.tensor(seed), warm_starts=ws[:, None], group=group, perturb=perturb, x0=x0,
                        phase=phase, base_xy_w=torch.zeros(b, 2), base_yaw=torch.zeros(b),
                        terrain_z_w=torch.zeros(b, 4), refs=refs)


def _kernels(cfg: SamplerConfig):
    out = {"reference": lambda inp: reference_costs(inp, cfg, robot_srbd_model()),
           "fast": lambda inp: fast_costs(inp, cfg, robot_srbd_model(), compiled=False)}
    lib = cpp_kernel.load()
    if lib is not None:
        out["cpp"] = lambda inp: cpp_kernel.cpp_costs(inp, cfg, robot_srbd_model(), lib)
    return out


@pytest.mark.parametrize("enc_F", ["spline", "first", "discrete"])
def test_every_kernel_ignores_swing_parameters_and_costs_the_hand_forces(enc_F, standing):
    """Two robots whose warm starts differ only in the force offsets of legs that swing through the whole
    horizon cost the same in every kernel; and sample 0's cost equals a rollout with forces written by hand
    (m g / stance legs + offset), costed by cost.rollout_cost_reference without any decode."""
    cfg = SamplerConfig(num_samples=16, horizon=5, encoding_p="first", encoding_F=enc_F, sigma_f=0.0, sigma_d=0.0)
    n = cfg.horizon
    act = torch.zeros(2, n, 28)
    act[..., 0:4], act[..., 4:8] = 1.5, 0.6
    # FR, RL at phase 0.62: swing for 0.38 / 1.5 = 0.25 s > 5 x 0.02 s; FL, RR at 0.1: stance throughout
    phase = torch.tensor([[0.1, 0.62, 0.62, 0.1]]).expand(2, 4).clone()
    dz = torch.tensor([12.0, 0.0, 0.0, -7.0])
    act[..., 18::3] = dz
    act[1, :, 16 + 3 * 1:16 + 3 * 2] = torch.tensor([80.0, -60.0, 300.0])  # robot 1: FR's offsets, never felt
    act[1, :, 16 + 3 * 2:16 + 3 * 3] = torch.tensor([-90.0, 40.0, -200.0])  # robot 1: RL's
    ws = encode(act, cfg.encoding)
    inp = _single_sample_inputs(standing, ws, phase)
    # by hand: FL, RR carry m g / 2 + their offset, F_xy = 0; targets at the nominal footholds p = 0
    contact = torch.tensor([True, False, False, True]).expand(2, 1, n, 4)
    force = torch.zeros(2, 1, n, 4, 3)
    force[..., 2] = (WEIGHT / 2 + dz) * contact
    nominal = torch.tensor(cfg.action.nominal_foothold_b)
    target = torch.cat([nominal, torch.full((4, 1), cfg.action.foot_radius)], dim=-1).expand(2, 1, n, 4, 3)
    by_hand = rollout_cost_reference(inp.x0, contact, target, force, inp.refs, robot_srbd_model(), cfg.weights, cfg.dt)
    for name, costs_of in _kernels(cfg).items():
        costs = costs_of(inp)
        assert costs[0, 0] == costs[1, 0], name  # swing-leg parameters change nothing, bit for bit
        torch.testing.assert_close(costs[:, 0], by_hand[:, 0], rtol=2e-5, atol=1e-3, msg=name)
        assert (costs[:, 1:] != costs[:, :1]).any(), name  # the other samples do differ (F is sampled)


def test_all_zero_offsets_hold_the_robot_in_every_kernel(standing, feet_w):
    """Zero offsets with all four legs down (d = 1): F_z = m g / 4 each, total m g (the model's mass is the
    latent action's), so a robot at rest at the reference height with feet around the CoM barely moves:
    the z and v_z costs stay tiny for every kernel."""
    cfg = SamplerConfig(num_samples=16, horizon=10, sigma_f=0.0, sigma_d=0.0, sigma_p=0.0, sigma_F=0.0)
    ws = warm_start.nominal_trot(1, cfg, duty=1.0)
    inp = _single_sample_inputs(standing, ws, torch.zeros(1, 4))
    inp.x0[:, 3:12] = 0.0
    inp.refs.lin_vel_w[:] = 0.0
    inp.x0[:, 12:] = feet_w.flatten()  # symmetric about the CoM: no moment
    nominal = torch.tensor(cfg.action.nominal_foothold_b)  # the targets of p = 0 (base at the origin)
    inp.refs.foothold_w[:] = torch.cat([nominal, torch.full((4, 1), cfg.action.foot_radius)], dim=-1)
    assert abs(robot_srbd_model().mass * robot_srbd_model().gravity - WEIGHT) < 1e-3
    for name, costs_of in _kernels(cfg).items():
        costs = costs_of(inp)
        # ~1e-11 (float32 rounding); a 1 mm drop would cost Q_z 1e-6 = 0.11 per step, absolute forces of m g / 2
        # on each of four legs (the old parameterisation's zero) would lift it by 0.5 g t^2 = 2 cm in 0.2 s
        assert (costs < 1e-3).all(), (name, costs)


def test_from_horizon_round_trips_physical_forces():
    cfg = SamplerConfig(num_samples=1, horizon=10, encoding_F="discrete")
    act = torch.zeros(1, 10, 28)
    act[..., 0:4], act[..., 4:8] = 1.5, 0.6
    act[..., 16:28] = torch.tensor([5.0, -3.0, 110.0] * 4)
    phase = torch.tensor([[0.0, 0.5, 0.5, 0.0]])
    enc = warm_start.from_horizon(act, cfg, phase)
    dec = decode_samples(enc[:, None], phase, torch.zeros(1, 2), torch.zeros(1), torch.zeros(1, 4), cfg)
    c = dec["contact"][0, 0].unsqueeze(-1).float()  # (N, 4, 1)
    torch.testing.assert_close(dec["F_h"][0, 0], act[0, :, 16:28].view(10, 4, 3) * c)
    # the encoded F block holds offsets: 110 - m g / n(k) on stance legs (n = 4 while both pairs are down,
    # steps 0-3 at d = 0.6, then 2), 0 in swing
    offsets = decode_parts(enc, cfg.encoding)[3][0]
    n = c[..., 0].sum(dim=-1, keepdim=True)
    assert n[:4, 0].tolist() == [4.0] * 4 and n[4:, 0].tolist() == [2.0] * 6
    torch.testing.assert_close(offsets[..., 2], (110.0 - WEIGHT / n) * c[..., 0])
    torch.testing.assert_close(warm_start.from_latent_action(act[:, 0], cfg, phase), enc)


def test_naive_warm_start_zeroes_swing_offsets_and_holds_the_tail():
    """discrete encoding, shift by one whole step: new[k] = c[k+1] dF[k+1], the last step held."""
    cfg = SamplerConfig(num_samples=1, horizon=4, dt=0.02, mpc_period=0.02, encoding_p="first", encoding_F="discrete")
    act = torch.zeros(1, 4, 28)
    act[..., 0:4], act[..., 4:8] = 1.5, 0.6
    act[0, :, 16 + 2] = torch.tensor([1.0, 2.0, 3.0, 4.0])  # FL F_z offsets per step
    act[0, :, 16 + 3] = torch.tensor([10.0, 20.0, 30.0, 40.0])  # FR F_x offsets per step
    prev = encode(act, cfg.encoding)
    contact = torch.tensor([[True, True, True, True], [True, False, True, True], [False, False, True, True],
                            [False, True, True, True]]).unsqueeze(0)  # (1, N, 4): FL lifts off at 2, FR swings at 1-2
    new = decode_parts(warm_start.naive(prev, cfg, contact), cfg.encoding)[3][0]  # (N, 4, 3)
    torch.testing.assert_close(new[:, 0, 2], torch.tensor([2.0, 0.0, 0.0, 0.0]))
    torch.testing.assert_close(new[:, 1, 0], torch.tensor([0.0, 0.0, 40.0, 40.0]))
    # without the contact sequence: the plain shift (no zeroing)
    plain = decode_parts(warm_start.naive(prev, cfg), cfg.encoding)[3][0]
    torch.testing.assert_close(plain[:, 0, 2], torch.tensor([2.0, 3.0, 4.0, 4.0]))


def test_naive_spline_warm_start_does_not_extrapolate_the_cubic():
    """first-spline, half a step per solve: a leg swinging through the whole horizon has all four spline
    parameters zeroed, and the stance legs' cubic is held flat past the horizon's end instead of being
    extrapolated (x^3 at x = 1 + 0.5 / 9 would add 3 x 0.0556 = 17 % of the cubic coefficient)."""
    cfg = SamplerConfig(num_samples=1, horizon=10)  # mpc_period 0.01 s, dt 0.02 s: 0.5 step
    x = torch.linspace(0.0, 1.0, 10)
    act = torch.zeros(1, 10, 28)
    act[0, :, 16 + 2] = 100.0 * x**3  # FL F_z offset: a cubic the spline represents exactly
    act[0, :, 16 + 5] = 50.0  # FR F_z offset
    prev = encode(act, cfg.encoding)
    contact = torch.tensor([True, False, True, True]).expand(1, 10, 4)  # FR swings throughout
    ws = warm_start.naive(prev, cfg, contact)
    off = decode_parts(ws, cfg.encoding)[3][0]
    assert torch.equal(off[:, 1], torch.zeros(10, 3))
    # held tail: the shifted sequence ends at 100 (the value at x = 1), the fit is least squares
    assert abs(off[-1, 0, 2].item() - 100.0) < 5.0
    exact = decode_parts(warm_start.naive(prev, cfg, None), cfg.encoding)[3][0]
    assert exact[-1, 0, 2].item() > 117.0  # the exact re-parameterisation extrapolates: (1 + 1/18)^3 x 100


def test_nominal_trot_is_zero_offsets():
    cfg = SamplerConfig()
    ws = warm_start.nominal_trot(3, cfg)
    assert ws.shape == (3, encoded_dim(cfg.encoding))
    assert torch.equal(ws[:, 16:], torch.zeros(3, ws.shape[1] - 16))
    assert torch.equal(ws[:, :8], torch.tensor([1.5] * 4 + [0.6] * 4).expand(3, 8))

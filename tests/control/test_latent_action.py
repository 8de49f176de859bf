"""Tests of the latent-action interface: layout, normalisation, clipping, frames, validation."""

from __future__ import annotations

import math
import re

import pytest
import torch

from dls_quadruped.control.action_config import LatentActionConfig
from dls_quadruped.control.latent_action import (
    ACTION_COMPONENT_NAMES,
    ActionInterface,
    LatentAction,
    clip,
    denormalise,
    flat_ground,
    normalise,
    to_world,
)
from dls_quadruped.robots.aliengo import constants as C

CFG = LatentActionConfig()
MG = C.TOTAL_MASS * C.GRAVITY  # 24.638 * 9.81 = 241.699 N


def _action(f=1.5, d=0.6, p=(0.0, 0.0), F=(0.0, 0.0, 60.0), batch=1) -> LatentAction:
    """Same values on every leg, shapes (batch, 4[, k])."""
    return LatentAction(
        f=torch.full((batch, 4), float(f)),
        d=torch.full((batch, 4), float(d)),
        p_h=torch.tensor(p, dtype=torch.float32).expand(batch, 4, 2).clone(),
        F_h=torch.tensor(F, dtype=torch.float32).expand(batch, 4, 3).clone(),
    )


def test_component_names_layout():
    assert len(ACTION_COMPONENT_NAMES) == 28
    assert ACTION_COMPONENT_NAMES[:5] == ("f[FL]", "f[FR]", "f[RL]", "f[RR]", "d[FL]")
    assert ACTION_COMPONENT_NAMES[8:11] == ("p_x[FL]", "p_y[FL]", "p_x[FR]")
    assert ACTION_COMPONENT_NAMES[16:19] == ("F_x[FL]", "F_y[FL]", "F_z[FL]")
    assert ACTION_COMPONENT_NAMES[24] == "F_z[RL]"


def test_vector_round_trip_and_layout():
    vec = torch.arange(2 * 28, dtype=torch.float32).reshape(2, 28)
    a = LatentAction.from_vector(vec)
    assert a.f.shape == (2, 4) and a.p_h.shape == (2, 4, 2) and a.F_h.shape == (2, 4, 3)
    assert a.p_h[0, 1].tolist() == [10.0, 11.0]  # FR (p_x, p_y) at indices 10, 11
    assert a.F_h[0, 2].tolist() == [22.0, 23.0, 24.0]  # RL (F_x, F_y, F_z) at 22..24
    torch.testing.assert_close(a.to_vector(), vec)


@pytest.mark.parametrize("n_stance", [2, 4])
def test_zero_raw_action_is_nominal(n_stance):
    """raw = 0 -> f = 1.5 Hz, d = 0.6, p = 0, F = (0, 0, m g / n): 120.85 N (n=2), 60.42 N (n=4)."""
    a = denormalise(torch.zeros(1, 28), torch.tensor([n_stance]), CFG)
    torch.testing.assert_close(a.f, torch.full((1, 4), 1.5))
    torch.testing.assert_close(a.d, torch.full((1, 4), 0.6))
    torch.testing.assert_close(a.p_h, torch.zeros(1, 4, 2))
    fz = {2: 120.8495, 4: 60.4247}[n_stance]  # 241.699 / n
    torch.testing.assert_close(a.F_h[0, :, 2], torch.full((4,), fz), atol=1e-3, rtol=0)
    torch.testing.assert_close(a.F_h[..., :2], torch.zeros(1, 4, 2))


def test_unit_raw_action_is_one_scale():
    """raw = 1 adds one scale: f 1.7, d 0.63, p 0.0175 m (5 % of 0.35), F_xy 6.042 N, F_z + 24.17 N."""
    a = denormalise(torch.ones(1, 28), 4, CFG)
    torch.testing.assert_close(a.f, torch.full((1, 4), 1.7))
    torch.testing.assert_close(a.d, torch.full((1, 4), 0.63))
    torch.testing.assert_close(a.p_h, torch.full((1, 4, 2), 0.0175))
    torch.testing.assert_close(a.F_h[0, 0], torch.tensor([6.0425, 6.0425, 60.4247 + 24.1699]), atol=1e-3, rtol=0)


def test_zero_stance_legs_uses_full_weight():
    a = denormalise(torch.zeros(1, 28), torch.tensor([0]), CFG)
    torch.testing.assert_close(a.F_h[0, :, 2], torch.full((4,), MG))


def test_normalise_denormalise_round_trip():
    g = torch.Generator().manual_seed(0)
    raw = torch.randn(6, 28, generator=g, dtype=torch.float64) * 3
    n = torch.tensor([0, 1, 2, 3, 4, 2])
    torch.testing.assert_close(normalise(denormalise(raw, n, CFG), n, CFG), raw)
    # Any leading dims (MPC: B x M x N).
    raw3 = torch.randn(2, 3, 5, 28, generator=g, dtype=torch.float64)
    n3 = torch.randint(0, 5, (2, 3, 5), generator=g)
    torch.testing.assert_close(normalise(denormalise(raw3, n3, CFG), n3, CFG), raw3)


def test_clip_inside_limits_is_identity_with_zero_violation():
    a = _action(f=2.0, d=0.5, p=(0.05, -0.05), F=(3.0, -4.0, 60.0))  # |F_xy| = 5 <= 0.5 * 60
    clipped, violation = clip(a, CFG)
    torch.testing.assert_close(clipped.to_vector(), a.to_vector())
    assert violation.shape == (1, 28)
    assert torch.count_nonzero(violation) == 0


def test_clip_each_quantity_and_hand_computed_violation():
    a = _action(f=3.4, d=-0.09, p=(0.25, -0.13), F=(0.0, 0.0, 300.0))
    clipped, v = clip(a, CFG)
    torch.testing.assert_close(clipped.f, torch.full((1, 4), 3.0))
    torch.testing.assert_close(clipped.d, torch.zeros(1, 4))
    torch.testing.assert_close(clipped.p_h[0, 0], torch.tensor([0.15, -0.10]))
    torch.testing.assert_close(clipped.F_h[0, :, 2], torch.full((4,), MG))
    # violation = (value - clipped) / scale
    torch.testing.assert_close(v[0, 0:4], torch.full((4,), 0.4 / 0.2))  # f: 2.0
    torch.testing.assert_close(v[0, 4:8], torch.full((4,), -0.09 / 0.03))  # d: -3.0
    torch.testing.assert_close(v[0, 8:10], torch.tensor([0.10 / 0.0175, -0.03 / 0.0175]))  # 5.714, -1.714
    torch.testing.assert_close(v[0, 18], torch.tensor((300.0 - MG) / (0.1 * MG)))  # F_z: 2.412
    assert v[0, 16].item() == 0.0 and v[0, 17].item() == 0.0


def test_clip_negative_fz_and_friction_cone_345():
    """F = (30, 40, 20): |F_xy| = 50 > mu F_z = 10 -> scaled to (6, 8), direction kept."""
    a = _action(F=(30.0, 40.0, 20.0))
    clipped, v = clip(a, CFG)
    torch.testing.assert_close(clipped.F_h[0, 1], torch.tensor([6.0, 8.0, 20.0]))
    scale_xy = 0.025 * MG  # 6.0425 N
    torch.testing.assert_close(v[0, 19:21], torch.tensor([24.0, 32.0]) / scale_xy)
    # Negative F_z -> 0, and then no tangential force at all.
    clipped, _ = clip(_action(F=(3.0, 4.0, -10.0)), CFG)
    torch.testing.assert_close(clipped.F_h[0, 2], torch.zeros(3))
    # Cone uses the clamped F_z: F_z = 400 -> m g, |F_xy| = 150 > 0.5 m g = 120.85 -> scaled.
    clipped, _ = clip(_action(F=(90.0, 120.0, 400.0)), CFG)
    torch.testing.assert_close(clipped.F_h[0, 3], torch.tensor([0.6 * 0.5 * MG, 0.8 * 0.5 * MG, MG]))


def test_clipping_violation_equals_raw_minus_normalised_clipped():
    g = torch.Generator().manual_seed(3)
    raw = torch.randn(64, 28, generator=g) * 20
    n = torch.randint(0, 5, (64,), generator=g)
    clipped, v = clip(denormalise(raw, n, CFG), CFG)
    torch.testing.assert_close(v, raw - normalise(clipped, n, CFG), atol=2e-4, rtol=1e-5)
    assert (v != 0).any(dim=1).all()  # raw * 20 leaves every row somewhere out of bounds


def test_to_world_yaw_half_pi_turns_x_offset_into_y():
    """yaw = pi/2: FL nominal (0.2399, 0.134) + p = (0.1, 0) -> H (0.3399, 0.134) -> world (-0.134, 0.3399)."""
    a = _action(p=(0.1, 0.0), F=(10.0, 0.0, 50.0))
    base = torch.tensor([[1.0, 2.0, 0.35]])
    p_td, F_w = to_world(a, base, torch.tensor([math.pi / 2]), flat_ground, CFG)
    assert p_td.shape == F_w.shape == (1, 4, 3)
    torch.testing.assert_close(p_td[0, 0], torch.tensor([1.0 - 0.134, 2.0 + 0.3399, C.FOOT_RADIUS]))
    # RR nominal (-0.2399, -0.134) + (0.1, 0) = (-0.1399, -0.134) -> world (1 + 0.134, 2 - 0.1399)
    torch.testing.assert_close(p_td[0, 3], torch.tensor([1.134, 2.0 - 0.1399, C.FOOT_RADIUS]))
    torch.testing.assert_close(F_w[0, 0], torch.tensor([0.0, 10.0, 50.0]), atol=1e-5, rtol=0)


def test_to_world_yaw_zero_flat_ground_and_terrain():
    a = _action()
    base = torch.tensor([[0.0, 0.0, 0.35]])
    p_td, F_w = to_world(a, base, torch.zeros(1), flat_ground, CFG)
    expected_xy = torch.tensor([[0.2399, 0.134], [0.2399, -0.134], [-0.2399, 0.134], [-0.2399, -0.134]])
    torch.testing.assert_close(p_td[0, :, :2], expected_xy)
    torch.testing.assert_close(p_td[0, :, 2], torch.full((4,), C.FOOT_RADIUS))
    torch.testing.assert_close(F_w, a.F_h)

    def slope(x, y):  # z = 0.5 x + 0.1
        return 0.5 * x + 0.1

    p_td, _ = to_world(a, base, torch.zeros(1), slope, CFG)
    torch.testing.assert_close(p_td[0, :, 2], 0.5 * expected_xy[:, 0] + 0.1 + C.FOOT_RADIUS)


def test_interface_pipeline_and_batched_equals_per_row():
    g = torch.Generator().manual_seed(7)
    B = 8
    raw = torch.randn(B, 28, generator=g) * 4
    n = torch.randint(0, 5, (B,), generator=g)
    base = torch.randn(B, 3, generator=g)
    yaw = torch.rand(B, generator=g) * 6.28 - 3.14
    iface = ActionInterface()
    out = iface(raw, n, base, yaw)
    assert out.f.shape == (B, 4) and out.p_td_w.shape == (B, 4, 3) and out.violation.shape == (B, 28)
    # Same as composing the free functions.
    clipped, v = clip(denormalise(raw, n, CFG), CFG)
    p_td, F_w = to_world(clipped, base, yaw, flat_ground, CFG)
    torch.testing.assert_close(out.F_w, F_w)
    torch.testing.assert_close(out.p_td_w, p_td)
    torch.testing.assert_close(out.violation, v)
    # Batched vs one robot at a time.
    for b in range(B):
        one = iface(raw[b : b + 1], n[b : b + 1], base[b : b + 1], yaw[b : b + 1])
        torch.testing.assert_close(one.p_td_w[0], out.p_td_w[b])
        torch.testing.assert_close(one.F_w[0], out.F_w[b])
        torch.testing.assert_close(one.violation[0], out.violation[b])
        torch.testing.assert_close(one.action.to_vector()[0], out.action.to_vector()[b])
    # Output respects the limits.
    assert (out.f >= 0).all() and (out.f <= 3).all() and (out.d >= 0).all() and (out.d <= 1).all()
    f_xy = torch.linalg.vector_norm(out.F_w[..., :2], dim=-1)
    assert (f_xy <= 0.5 * out.F_w[..., 2] + 1e-4).all()


@pytest.mark.parametrize("shape", [(28,), (4, 27), (2, 4, 28)])
def test_bad_shape_raises(shape):
    with pytest.raises(ValueError, match=r"shape \(B, 28\).*got " + re.escape(str(shape))):
        ActionInterface()(torch.zeros(shape), torch.zeros(4), torch.zeros(4, 3), torch.zeros(4))


def test_non_finite_raises_naming_robots_and_components():
    raw = torch.zeros(5, 28)
    raw[1, 24] = float("nan")  # F_z[RL] = 16 + 3 * 2 + 2
    raw[3, 0] = float("inf")  # f[FL]
    with pytest.raises(ValueError, match=r"robots \[1, 3\] in components \['f\[FL\]', 'F_z\[RL\]'\]"):
        ActionInterface()(raw, torch.full((5,), 4), torch.zeros(5, 3), torch.zeros(5))


def test_mismatched_state_shape_raises():
    with pytest.raises(ValueError, match=r"base_yaw must have shape \(3,\)"):
        ActionInterface()(torch.zeros(3, 28), torch.full((3,), 4), torch.zeros(3, 3), torch.zeros(2))


def test_config_validation_and_from_dict():
    cfg = LatentActionConfig.from_dict({"step_height": 0.05, "foothold_x_range": [-0.2, 0.2]})
    assert cfg.step_height == 0.05 and cfg.foothold_x_range == (-0.2, 0.2)
    with pytest.raises(ValueError, match="unknown LatentActionConfig keys \\['stepheight'\\]"):
        LatentActionConfig.from_dict({"stepheight": 0.05})
    with pytest.raises(ValueError, match="freq_range"):
        LatentActionConfig(freq_range=(3.0, 0.0))
    assert CFG.weight == pytest.approx(241.699, abs=1e-3)


def test_float64_and_dtype_preserved():
    raw = torch.zeros(2, 28, dtype=torch.float64)
    out = ActionInterface()(raw, torch.full((2,), 3), torch.zeros(2, 3, dtype=torch.float64), torch.zeros(2))
    assert out.p_td_w.dtype == out.F_w.dtype == out.violation.dtype == torch.float64
    assert out.F_w[0, 0, 2].item() == pytest.approx(MG / 3, rel=1e-12)


def test_from_physical_matches_raw_path():
    """A physical action through from_physical equals its normalised form through __call__."""
    g = torch.Generator().manual_seed(11)
    raw = torch.randn(4, 28, generator=g, dtype=torch.float64) * 5
    n = torch.tensor([4, 3, 2, 0])
    base = torch.randn(4, 3, generator=g, dtype=torch.float64)
    yaw = torch.randn(4, generator=g, dtype=torch.float64)
    iface = ActionInterface()
    a = iface(raw, n, base, yaw)
    b = iface.from_physical(denormalise(raw, n, CFG), base, yaw)
    torch.testing.assert_close(a.p_td_w, b.p_td_w)
    torch.testing.assert_close(a.F_w, b.F_w)
    torch.testing.assert_close(a.violation, b.violation)
    bad = denormalise(raw, n, CFG)
    bad.F_h[2, 1, 0] = float("nan")
    with pytest.raises(ValueError, match=r"robots \[2\] in components \['F_x\[FR\]'\]"):
        iface.from_physical(bad, base, yaw)


def test_docs_worked_example():
    """The worked example of docs/latent_action.md, numbers by hand."""
    raw = torch.zeros(1, 28, dtype=torch.float64)
    raw[0, 0], raw[0, 4], raw[0, 8], raw[0, 16], raw[0, 18] = 1.0, 15.0, 2.0, 10.0, -1.0
    base = torch.tensor([[1.0, 2.0, 0.35]], dtype=torch.float64)
    out = ActionInterface()(raw, torch.tensor([2]), base, torch.tensor([math.pi / 2], dtype=torch.float64))
    assert out.f[0, 0].item() == pytest.approx(1.7) and out.d[0, 0].item() == 1.0
    expected_v = torch.zeros(28, dtype=torch.float64)
    expected_v[4] = 0.05 / 0.03  # d: 1.05 -> 1
    expected_v[16] = (10 * 0.025 * MG - 0.5 * (MG / 2 - 0.1 * MG)) / (0.025 * MG)  # F_x: 60.42 -> 48.34 N = 2.0
    torch.testing.assert_close(out.violation[0], expected_v)
    torch.testing.assert_close(out.p_td_w[0, 0], torch.tensor([0.866, 2.2749, 0.0265], dtype=torch.float64))
    torch.testing.assert_close(out.F_w[0, 0], torch.tensor([0.0, 48.339756, 96.679512], dtype=torch.float64))

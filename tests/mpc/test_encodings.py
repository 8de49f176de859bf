"""Action encodings: Table 13 dimensions, exact round trips, spline fits, time shifts."""

from __future__ import annotations

import pytest
import torch

from dls_quadruped.mpc.config import EncodingConfig
from dls_quadruped.mpc.encodings import (
    HERMITE_TO_POLY,
    decode,
    decode_parts,
    encode,
    encoded_dim,
    fit_spline,
    shift_encoded,
    spline_basis,
    spline_grid,
)

# Table 13 (p encoding, F encoding, H) -> dimension. Row 35 prints 204 for first-discrete H=15 where
# row 17 (same encoding and H, dt 0.02) prints 196 = 8 + 8 + 12 * 15: row 35 is a typo.
TABLE_13 = [
    ("discrete", "discrete", 5, 108), ("discrete", "spline", 5, 96), ("spline", "discrete", 5, 100),
    ("spline", "spline", 5, 88), ("first", "discrete", 5, 76), ("first", "spline", 5, 64),
    ("discrete", "discrete", 10, 208), ("discrete", "spline", 10, 136), ("spline", "discrete", 10, 160),
    ("spline", "spline", 10, 88), ("first", "discrete", 10, 136), ("first", "spline", 10, 64),
    ("discrete", "discrete", 15, 308), ("discrete", "spline", 15, 176), ("spline", "discrete", 15, 220),
    ("spline", "spline", 15, 88), ("first", "discrete", 15, 196), ("first", "spline", 15, 64),
]


@pytest.mark.parametrize("p,F,H,dim", TABLE_13)
def test_table13_dimensions(p, F, H, dim):
    cfg = EncodingConfig(p=p, F=F, horizon=H)
    assert encoded_dim(cfg) == dim
    assert encode(torch.zeros(3, H, 28), cfg).shape == (3, dim)


def test_other_dimensions_by_formula():
    # eqs. 5.1.2-5.1.4: 8 + (8 or 8H or 32) + (12 or 12H or 48)
    assert encoded_dim(EncodingConfig("first", "first", 10)) == 8 + 8 + 12
    assert encoded_dim(EncodingConfig("spline", "first", 10)) == 8 + 32 + 12
    assert encoded_dim(EncodingConfig("discrete", "first", 7)) == 8 + 56 + 12


def _horizon(gen, H):
    a = torch.randn(4, H, 28, generator=gen)
    a[:, :, :8] = a[:, :1, :8]  # gait constant over the horizon (the encoding keeps (f_0, d_0))
    return a


def test_discrete_round_trip_exact():
    gen = torch.Generator().manual_seed(0)
    cfg = EncodingConfig("discrete", "discrete", 6)
    a = _horizon(gen, 6)
    assert torch.equal(decode(encode(a, cfg), cfg), a)


def test_first_round_trip_exact():
    gen = torch.Generator().manual_seed(1)
    cfg = EncodingConfig("first", "first", 5)
    a = _horizon(gen, 5)
    a[:, :, 8:] = a[:, :1, 8:]  # a constant horizon is representable
    assert torch.equal(decode(encode(a, cfg), cfg), a)
    enc = torch.randn(2, encoded_dim(cfg), generator=gen)
    assert torch.equal(encode(decode(enc, cfg), cfg), enc)


def test_hermite_basis_matches_eq_a119():
    """s(0) = theta_0, s(1) = theta_1, s'(0) = (theta_1 - theta_-1) / 2, s'(1) = (theta_2 - theta_0) / 2."""
    theta = torch.tensor([0.3, -1.0, 2.0, 0.5], dtype=torch.float64)
    a, b, c, d = torch.tensor(HERMITE_TO_POLY, dtype=torch.float64) @ theta
    assert d == theta[1] and a + b + c + d == pytest.approx(theta[2].item())
    assert c == pytest.approx((theta[2] - theta[0]).item() / 2)
    assert 3 * a + 2 * b + c == pytest.approx((theta[3] - theta[1]).item() / 2)
    H = 7
    x = spline_grid(H, torch.float64)
    torch.testing.assert_close(spline_basis(H, torch.float64) @ theta, a * x**3 + b * x**2 + c * x + d)
    assert x[0] == 0 and x[-1] == 1 and torch.allclose(x[1] - x[0], torch.tensor(1 / 6, dtype=torch.float64))


@pytest.mark.parametrize("constrained", [False, True])
def test_cubic_is_fitted_exactly(constrained):
    H = 10
    x = spline_grid(H, torch.float64)
    y = torch.stack([2 * x**3 - x**2 + 0.5 * x - 3, -x**3 + 4 * x, 0 * x + 7.0], dim=-1)  # (H, 3 scalars)
    theta = fit_spline(y, constrained)
    torch.testing.assert_close((theta @ spline_basis(H, torch.float64).T).T, y, rtol=0, atol=1e-9)


def test_least_squares_matches_lstsq_and_constrained_exact_at_first_sample():
    gen = torch.Generator().manual_seed(2)
    H = 10
    y = torch.randn(5, H, 12, generator=gen, dtype=torch.float64)
    basis = spline_basis(H, torch.float64)
    theta = fit_spline(y, constrained=False)
    expected = torch.linalg.lstsq(basis.expand(5, H, 4), y).solution.transpose(-1, -2)
    torch.testing.assert_close(theta, expected, rtol=1e-8, atol=1e-8)
    theta_c = fit_spline(y, constrained=True)
    fitted_c = (theta_c @ basis.T).transpose(-1, -2)
    torch.testing.assert_close(fitted_c[:, 0], y[:, 0], rtol=0, atol=1e-12)  # exact at sample 0 (A.3)
    fitted = (theta @ basis.T).transpose(-1, -2)
    assert not torch.allclose(fitted[:, 0], y[:, 0])  # the plain fit is generally not
    # the unconstrained fit has the smaller residual; the constrained one is optimal among theta_0 = y_0
    assert ((fitted - y) ** 2).sum() <= ((fitted_c - y) ** 2).sum()
    perturbed = theta_c.clone()
    perturbed[..., 2] += 1e-3
    assert (((perturbed @ basis.T).transpose(-1, -2) - y) ** 2).sum() > ((fitted_c - y) ** 2).sum()


def test_spline_encoding_float32_decode():
    cfg = EncodingConfig("spline", "spline", 8, constrained_fit=True)
    gen = torch.Generator().manual_seed(4)
    a = _horizon(gen, 8)
    dec = decode(encode(a, cfg), cfg)
    torch.testing.assert_close(dec[:, 0], a[:, 0], rtol=0, atol=1e-5)  # first action exact
    assert torch.equal(dec[:, :, :8], a[:, :, :8])


def test_shift_discrete_drops_first_repeats_last():
    cfg = EncodingConfig("discrete", "discrete", 5)
    gen = torch.Generator().manual_seed(5)
    a = _horizon(gen, 5)
    shifted = decode(shift_encoded(encode(a, cfg), cfg, 1.0), cfg)
    assert torch.equal(shifted[:, :4, 8:], a[:, 1:, 8:])
    assert torch.equal(shifted[:, 4, 8:], a[:, 4, 8:])
    half = decode(shift_encoded(encode(a, cfg), cfg, 0.5), cfg)
    torch.testing.assert_close(half[:, :4, 8:], 0.5 * (a[:, :4, 8:] + a[:, 1:, 8:]))


def test_shift_spline_is_exact_time_shift():
    cfg = EncodingConfig("first", "spline", 10)
    gen = torch.Generator().manual_seed(6)
    enc = torch.randn(3, encoded_dim(cfg), generator=gen, dtype=torch.float64)
    shifted = shift_encoded(enc, cfg, 0.5)
    # value at x of the shifted spline = value at x + 0.5 / 9 of the original
    _, _, _, F = decode_parts(enc, cfg)
    _, _, _, F_s = decode_parts(shifted, cfg)
    theta = enc[:, 16:].unflatten(-1, (12, 4))
    x = spline_grid(10, torch.float64) + 0.5 / 9
    poly = theta @ torch.tensor(HERMITE_TO_POLY, dtype=torch.float64).T  # (3, 12, 4) = a, b, c, d
    expected = (poly[..., 0:1] * x**3 + poly[..., 1:2] * x**2 + poly[..., 2:3] * x + poly[..., 3:4]).transpose(-1, -2)
    torch.testing.assert_close(F_s.flatten(-2), expected, rtol=1e-10, atol=1e-10)
    assert torch.equal(shifted[:, :16], enc[:, :16])  # gait and `first` p unchanged
    assert not torch.allclose(F_s, F)


def test_bad_shapes_raise():
    cfg = EncodingConfig("first", "spline", 10)
    with pytest.raises(ValueError, match=r"\(\.\.\., 64\)"):
        decode(torch.zeros(2, 63), cfg)
    with pytest.raises(ValueError, match="H=10"):
        encode(torch.zeros(2, 9, 28), cfg)
    with pytest.raises(ValueError, match="discrete"):
        EncodingConfig("cubic", "spline", 10)
    with pytest.raises(ValueError, match="horizon"):
        EncodingConfig("spline", "spline", 3)

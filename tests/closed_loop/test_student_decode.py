"""Student -> MPC decode (issue 12 item 2): the linear map against the encodings' own decode followed by
the action manager's denormalisation with each step's stance count, for every encoding kind; the
metadata check; and the committed student's output turned into a warm start the MPC accepts."""

from __future__ import annotations

import pytest
import torch

from dls_quadruped.control import gait
from dls_quadruped.control.latent_action import denormalise
from dls_quadruped.learning.student import load_student, metadata
from dls_quadruped.mpc import warm_start as W
from dls_quadruped.mpc.config import EncodingConfig, SamplerConfig
from dls_quadruped.mpc.encodings import decode, encoded_dim
from dls_quadruped.mpc.samples import decode_samples

ENCODINGS = [("first", "spline"), ("discrete", "discrete"), ("spline", "spline"), ("first", "first"),
             ("spline", "discrete"), ("discrete", "spline")]
STUDENT = "docs/policies/base_student_first_spline_h10.pt"


@pytest.mark.parametrize("p,F", ENCODINGS)
def test_student_horizon_equals_denormalised_decode(p: str, F: str) -> None:
    cfg = SamplerConfig(encoding_p=p, encoding_F=F, horizon=6)
    gen = torch.Generator().manual_seed(3)
    out = torch.randn(5, encoded_dim(cfg.encoding), generator=gen, dtype=torch.float64)
    phase = torch.rand(5, 4, generator=gen, dtype=torch.float64)
    actions, contact = W.student_horizon(out, cfg, phase)
    # independent path: decode in raw units, then Table 5 with the stance count of each step
    raw = decode(out, cfg.encoding)                                   # (B, N, 28) raw
    f = 1.5 + 0.2 * out[:, 0:4]
    d = 0.6 + 0.03 * out[:, 4:8]
    _, expect_contact = gait.contact_sequence(phase, f, d, cfg.dt, cfg.horizon)
    assert torch.equal(contact, expect_contact)
    phys = denormalise(raw, expect_contact.sum(-1), cfg.action).to_vector()
    torch.testing.assert_close(actions[..., :16], phys[..., :16], rtol=0, atol=1e-9)
    stance = expect_contact.to(phys.dtype).repeat_interleave(3, dim=-1)  # (B, N, 12) per force scalar
    torch.testing.assert_close(actions[..., 16:], phys[..., 16:] * stance, rtol=0, atol=1e-9)


def test_zero_output_is_the_nominal_trot() -> None:
    """A zero raw output = f 1.5 Hz, d 0.6, feet on the nominal footholds, zero force offsets."""
    cfg = SamplerConfig()
    ws = W.from_student(torch.zeros(2, encoded_dim(cfg.encoding)), cfg)
    torch.testing.assert_close(ws, W.nominal_trot(2, cfg))


def test_mpc_decodes_the_student_warm_start_like_the_student_horizon() -> None:
    """Sample 0 of the MPC's decode (clip aside) is the student's physical horizon."""
    cfg = SamplerConfig(encoding_p="discrete", encoding_F="discrete", horizon=5)
    out = 0.3 * torch.randn(3, encoded_dim(cfg.encoding), generator=torch.Generator().manual_seed(0))
    phase = torch.rand(3, 4, generator=torch.Generator().manual_seed(1))
    actions, contact = W.student_horizon(out, cfg, phase)
    dec = decode_samples(W.from_student(out, cfg)[:, None], phase, torch.zeros(3, 2), torch.zeros(3), torch.zeros(3, 4),
                         cfg)
    assert torch.equal(dec["contact"][:, 0], contact)
    torch.testing.assert_close(dec["p_h"][:, 0].flatten(-2), actions[..., 8:16].clamp(-0.1, 0.1), atol=1e-5, rtol=0)
    torch.testing.assert_close(dec["F_h"][:, 0, ..., 2], actions[..., 18::3].clamp(0, cfg.action.weight), atol=1e-3,
                               rtol=0)


def test_check_student_encoding_names_every_mismatch() -> None:
    meta = metadata(EncodingConfig("first", "spline", 10), 0.02, 259)
    W.check_student_encoding(meta, SamplerConfig())  # matches
    with pytest.raises(ValueError, match=r"horizon = 10 \(MPC: 5\)"):
        W.check_student_encoding(meta, SamplerConfig(horizon=5))
    with pytest.raises(ValueError, match=r"p = 'first' \(MPC: 'discrete'\).*F = 'spline' \(MPC: 'discrete'\)"):
        W.check_student_encoding(meta, SamplerConfig(encoding_p="discrete", encoding_F="discrete"))
    with pytest.raises(ValueError, match=r"dt = 0.02 \(MPC: 0.04\)"):
        W.check_student_encoding(meta, SamplerConfig(dt=0.04))
    with pytest.raises(ValueError, match="no 'encoding' section"):
        W.check_student_encoding({"obs_dim": 259}, SamplerConfig())
    with pytest.raises(ValueError, match=r"shape \(B, 64\)"):
        W.from_student(torch.zeros(2, 63), SamplerConfig())


def test_committed_student_gives_a_warm_start_the_mpc_solves(standing) -> None:
    from dls_quadruped.mpc.sampler import SamplingMPC

    module, meta = load_student(STUDENT)
    cfg = SamplerConfig(num_samples=64, kernel="reference", sigma_f=0.0, sigma_d=0.0, sigma_p=0.0)
    W.check_student_encoding(meta, cfg)
    out = module(torch.zeros(2, meta["obs_dim"]))
    ws = W.from_student(out, cfg)
    assert ws.shape == (2, 64) and torch.isfinite(ws).all()
    # the f, d it proposes are a plausible trot around the Table 5 shift
    assert ((ws[:, :4] > 0.5) & (ws[:, :4] < 3.0)).all() and ((ws[:, 4:8] > 0.3) & (ws[:, 4:8] < 0.9)).all()
    state, refs = standing(2)
    mpc = SamplingMPC(cfg)
    mpc.record_step_costs = True
    res = mpc.solve(state, refs, [ws], phase=torch.zeros(2, 4))
    assert not res.fallback.any()
    torch.testing.assert_close(res.step_costs.sum(-1), res.best_cost, rtol=1e-4, atol=1e-3)

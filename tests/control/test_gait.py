"""Tests of the phase-oscillator gait generator (thesis 2.2.2, SPEC 4)."""

from __future__ import annotations

import pytest
import torch

from dls_quadruped.control.gait import (
    TROT_PHASE_OFFSETS,
    advance_phase,
    contact_from_phase,
    contact_sequence,
    swing_progress,
    trot_phases,
)


@pytest.mark.parametrize(("f", "d"), [(1.5, 0.6), (1.0, 0.3), (2.5, 0.75), (0.7, 0.9)])
def test_stance_fraction_equals_duty(f, d):
    """Step N = 1000 times per cycle with advance_phase: stance fraction = d within 1/N."""
    steps = 1000
    dt = 1.0 / (f * steps)
    phase = trot_phases(1, dtype=torch.float64)
    freq = torch.full((1, 4), f, dtype=torch.float64)
    duty = torch.full((1, 4), d, dtype=torch.float64)
    stance = torch.zeros(1, 4, dtype=torch.float64)
    for _ in range(steps):
        stance += contact_from_phase(phase, duty).double()
        phase = advance_phase(phase, freq, dt)
    frac = stance / steps
    assert torch.all((frac - d).abs() <= 1.0 / steps + 1e-9), frac


@pytest.mark.parametrize(("f", "d"), [(1.5, 0.6), (2.2, 0.35)])
def test_stance_fraction_at_200hz_over_many_cycles(f, d):
    """At the real 200 Hz rate (non-integer steps per cycle) over 20 cycles: within one step per cycle."""
    dt, cycles = 0.005, 20
    horizon = round(cycles / (f * dt))
    phase0 = torch.rand(3, 4, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    _, contacts = contact_sequence(
        phase0, torch.full((3, 4), f, dtype=torch.float64), torch.full((3, 4), d, dtype=torch.float64), dt, horizon
    )
    frac = contacts.double().mean(dim=-2)  # (3, 4)
    steps_per_cycle = 1.0 / (f * dt)
    assert torch.all((frac - d).abs() <= 1.0 / steps_per_cycle), frac


def test_contact_is_stance_below_duty():
    phase = torch.tensor([0.0, 0.59, 0.6, 0.99])
    duty = torch.full((4,), 0.6)
    assert contact_from_phase(phase, duty).tolist() == [True, True, False, False]


def test_contact_sequence_equals_repeated_advance_phase():
    g = torch.Generator().manual_seed(1)
    phase0 = torch.rand(5, 4, generator=g, dtype=torch.float64)
    freq = 0.5 + 2.5 * torch.rand(5, 4, generator=g, dtype=torch.float64)
    duty = 0.2 + 0.7 * torch.rand(5, 4, generator=g, dtype=torch.float64)
    dt, horizon = 0.01, 150
    phases, contacts = contact_sequence(phase0, freq, duty, dt, horizon)
    assert phases.shape == contacts.shape == (5, horizon, 4)
    phase = phase0.clone()
    for k in range(horizon):
        diff = (phases[:, k] - phase).abs()
        circular = torch.minimum(diff, 1.0 - diff)  # 0.9999999 and 0.0 are the same phase
        assert circular.max().item() < 1e-9, k
        assert torch.equal(contacts[:, k], contact_from_phase(phase, duty)), k
        phase = advance_phase(phase, freq, dt)


def test_trot_offsets_and_diagonal_pairs():
    phase = trot_phases(3)
    assert phase.shape == (3, 4)
    assert phase[0].tolist() == [0.0, 0.5, 0.5, 0.0] == list(TROT_PHASE_OFFSETS)
    # With d = 0.5 the diagonals FL+RR and FR+RL alternate: always exactly two feet down.
    freq = torch.full((3, 4), 1.5)
    duty = torch.full((3, 4), 0.5)
    _, c = contact_sequence(phase + 1e-4, freq, duty, 0.005, 400)  # tiny shift keeps phases off the d boundary
    assert torch.equal(c[..., 0], c[..., 3]) and torch.equal(c[..., 1], c[..., 2])
    assert torch.equal(c[..., 0], ~c[..., 1])


def test_swing_progress_endpoints():
    duty = torch.full((5,), 0.6)
    phase = torch.tensor([0.3, 0.6, 0.8, 1.0 - 1e-7, 0.0])
    s = swing_progress(phase, duty)
    torch.testing.assert_close(s, torch.tensor([0.0, 0.0, 0.5, 1.0, 0.0]), atol=1e-6, rtol=0)
    # A leg with d = 1 never swings.
    assert swing_progress(torch.tensor([0.99]), torch.tensor([1.0])).item() == 0.0

"""Gait generator (thesis 2.2.2): per-leg phase oscillators.

Each leg i has a phase ``theta_i`` in [0, 1) that advances by ``f_i * dt`` per control
step; the leg is in stance while ``theta_i < d_i`` and in swing otherwise (eq. 2.2.3 of
the thesis has the inequality typo'd). All functions are pure and batched over any
leading dimensions, so the low-level controller (B robots) and the sampling MPC
(B robots x M samples x N horizon steps) share them.
"""

from __future__ import annotations

import torch

from dls_quadruped.core.torch_cache import constant_cache

TROT_PHASE_OFFSETS = (0.0, 0.5, 0.5, 0.0)
"""Phases at reset for (FL, FR, RL, RR): diagonal pairs move together."""


def trot_phases(num: int, device: torch.device | str = "cpu", dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """Initial trot phases.

    Returns:
        phase: (num, 4) in [0, 1).
    """
    return _trot_offsets(torch.device(device), dtype).expand(num, 4).clone()


@constant_cache
def _trot_offsets(device: torch.device, dtype: torch.dtype) -> torch.Tensor:
    """(4,) ``TROT_PHASE_OFFSETS`` as a tensor, built once per device and dtype (read-only)."""
    return torch.tensor(TROT_PHASE_OFFSETS, device=device, dtype=dtype)


def advance_phase(phase: torch.Tensor, freq: torch.Tensor, dt: float) -> torch.Tensor:
    """Advance phases by one step: theta <- (theta + f dt) mod 1.

    Args:
        phase: (..., 4) current phase in [0, 1).
        freq: (..., 4) step frequency [Hz].
        dt: step [s].

    Returns:
        (..., 4) new phase in [0, 1).
    """
    return torch.remainder(phase + freq * dt, 1.0)


def contact_from_phase(phase: torch.Tensor, duty: torch.Tensor) -> torch.Tensor:
    """Contact (stance) flag: c = theta < d (the thesis's eq. 2.2.3 with its typo fixed).

    Args:
        phase: (..., 4) in [0, 1).
        duty: (..., 4) duty cycle in [0, 1].

    Returns:
        (..., 4) bool, True in stance.
    """
    return phase < duty


def contact_sequence(
    phase0: torch.Tensor, freq: torch.Tensor, duty: torch.Tensor, dt: float, horizon: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """Contacts over a horizon for constant (f, d), computed in closed form.

    Step k (k = 0..horizon-1) has phase ``(theta_0 + k f dt) mod 1``; this equals ``k``
    calls of :func:`advance_phase` up to float rounding, without a Python loop.

    Args:
        phase0: (..., 4) phase at step 0.
        freq, duty: (..., 4) gait parameters, held over the horizon.
        dt: step [s].
        horizon: number of steps N.

    Returns:
        phases: (..., N, 4); contacts: (..., N, 4) bool.
    """
    k = torch.arange(horizon, device=phase0.device, dtype=phase0.dtype).unsqueeze(-1)  # (N, 1)
    phases = torch.remainder(phase0.unsqueeze(-2) + k * (freq * dt).unsqueeze(-2), 1.0)
    return phases, phases < duty.unsqueeze(-2)


def swing_progress(phase: torch.Tensor, duty: torch.Tensor) -> torch.Tensor:
    """Fraction of the swing phase elapsed, s = (theta - d) / (1 - d), clamped to [0, 1].

    Zero in stance. Legs with d >= 1 never swing (returns 0).

    Args:
        phase, duty: (..., 4).

    Returns:
        (..., 4) in [0, 1].
    """
    swing_len = (1.0 - duty).clamp_min(1e-6)
    return ((phase - duty) / swing_len).clamp(0.0, 1.0)

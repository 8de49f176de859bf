"""Inputs the MPC refuses at its boundary: a gait phase outside the cycle (at each solve, naming the robots and
the range) and a device this machine does not have (at construction, as the command lines say it)."""

from __future__ import annotations

import math
import re

import pytest
import torch

from dls_quadruped.mpc import warm_start
from dls_quadruped.mpc.config import SamplerConfig
from dls_quadruped.mpc.sampler import SamplingMPC

PHASE = torch.tensor([[0.0, 0.5, 0.5, 0.0], [0.25, 0.75, 0.75, 0.25]])


def _solve(mpc: SamplingMPC, standing_pair, phase: torch.Tensor):
    state, refs = standing_pair
    return mpc.solve(state, refs, [warm_start.nominal_trot(2, mpc.cfg)], phase=phase)


@pytest.mark.parametrize("kernel", ["reference", "cpp"])
@pytest.mark.parametrize("value", [7.25, -0.5, 1.5])
def test_phase_outside_the_cycle_is_refused_naming_robot_and_range(kernel, value, standing_pair):
    mpc = SamplingMPC(SamplerConfig(num_samples=16, horizon=4, kernel=kernel), seed=0)
    phase = PHASE.clone()
    phase[1, 2] = value
    with pytest.raises(ValueError, match=rf"^phase must be in \[0, 1\) \(the fraction of the gait cycle\), "
                                         rf"got \[{value}\] for robots \[1\]$"):
        _solve(mpc, standing_pair, phase)
    assert mpc.last_result is None  # refused before anything was solved


@pytest.mark.parametrize("kernel", ["reference", "cpp"])
def test_phase_at_the_cycle_ends_and_non_finite_phase_still_solve(kernel, standing_pair):
    """0 and 1.0 (a float64 phase just below 1 rounded to float32) solve; NaN is the fallback's, not an error."""
    mpc = SamplingMPC(SamplerConfig(num_samples=16, horizon=4, kernel=kernel), seed=0)
    phase = PHASE.clone()
    phase[0, 0], phase[1, 1] = 0.0, torch.tensor(1.0 - 1e-9, dtype=torch.float64).float()
    assert phase[1, 1] == 1.0
    assert not _solve(mpc, standing_pair, phase).fallback.any()
    phase[1, 1] = math.nan
    assert _solve(mpc, standing_pair, phase).fallback.tolist() == [False, True]


@pytest.mark.skipif(torch.cuda.is_available(), reason="needs a machine without CUDA")
@pytest.mark.parametrize("device", ["cuda", torch.device("cuda:0")])
def test_cuda_without_cuda_is_refused_at_construction(device):
    why = "this torch build has no CUDA" if not torch.backends.cuda.is_built() else "no CUDA GPU is visible"
    with pytest.raises(ValueError, match=rf"^SamplingMPC: {device}: {why}; use cpu$"):
        SamplingMPC(SamplerConfig(num_samples=16, horizon=4), device=device)


@pytest.mark.parametrize("device, message", [
    ("cpux", "unknown device 'cpux'; use cpu, cuda or cuda:<index>"),
    ("meta", "unsupported device 'meta'; use cpu, cuda or cuda:<index>"),
])
def test_unknown_devices_are_refused_at_construction(device, message):
    with pytest.raises(ValueError, match=f"^{re.escape(f'SamplingMPC: {message}')}$"):
        SamplingMPC(SamplerConfig(num_samples=16, horizon=4), device=device)

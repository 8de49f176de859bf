"""SamplingMPC.reset(robots): only the named robots forget their previous solution (the closed loop calls
it when the env restarts an episode); the kernel time is accounted."""

from __future__ import annotations

import torch

from dls_quadruped.mpc import warm_start
from dls_quadruped.mpc.config import SamplerConfig
from dls_quadruped.mpc.sampler import SamplingMPC


def test_reset_some_robots_gives_them_the_default(standing) -> None:
    cfg = SamplerConfig(num_samples=64, kernel="reference")
    mpc = SamplingMPC(cfg)
    state, refs = standing(3)
    default = warm_start.nominal_trot(3, cfg)
    before = mpc.kernel_seconds
    mpc.solve(state, refs, [default], phase=torch.zeros(3, 4))
    assert mpc.kernel_seconds > before
    shifted = mpc.naive_warm_start(default)
    assert not torch.equal(shifted[1], default[1])  # the solver moved away from the nominal trot
    mpc.reset(torch.tensor([1]))
    after = mpc.naive_warm_start(default)
    assert torch.equal(after[1], default[1])
    assert torch.equal(after[[0, 2]], shifted[[0, 2]])
    mpc.solve(state, refs, [after], phase=torch.zeros(3, 4))  # a new solve clears the mark
    assert not torch.equal(mpc.naive_warm_start(default)[1], default[1])
    mpc.reset()
    assert torch.equal(mpc.naive_warm_start(default), default)

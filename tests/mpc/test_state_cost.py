"""The state-only rollout cost: the same states give the same cost whatever the footholds' deviation.

Every leg swings for the whole horizon (duty 0): no leg carries a force, so the CoM follows the same
ballistic trajectory whatever the touch-down targets, and a naive warm start (footholds = the
reference) and an RL one (footholds 5 cm ahead, 3 cm inwards) reach identical states. Their full
costs differ by exactly the foothold term, worked out by hand: R_px = R_py = 1000 on every horizon
step of every leg, 1000 (0.05^2 + 0.03^2) x 4 legs x N steps.
"""

from __future__ import annotations

import pytest
import torch

from dls_quadruped.mpc import cpp_kernel
from dls_quadruped.mpc.config import SamplerConfig
from dls_quadruped.mpc.cost import Refs
from dls_quadruped.mpc.encodings import encode
from dls_quadruped.mpc.sampler import SamplingMPC
from dls_quadruped.mpc.samples import decode_samples
from dls_quadruped.mpc.srbd import robot_srbd_model

PHASE = torch.tensor([[0.0, 0.5, 0.5, 0.0], [0.2, 0.7, 0.7, 0.2]])
DP = (0.05, -0.03)
"""[m] the RL warm start's foothold offset from the reference (x, y), every leg and step."""


def _horizon(cfg: SamplerConfig, dp: tuple[float, float]) -> torch.Tensor:
    """(2, D) encoded: f 1.5 Hz, duty 0 (every leg swings), footholds offset by ``dp``, no force offsets."""
    a = torch.zeros(2, cfg.horizon, 28)
    a[..., 0:4] = 1.5
    a[..., 8:16:2], a[..., 9:16:2] = dp[0], dp[1]
    return encode(a, cfg.encoding)


@pytest.mark.parametrize("kernel", ["reference", "cpp"])
def test_same_states_same_state_cost_whatever_the_footholds(kernel, standing):
    if kernel == "cpp" and cpp_kernel.load() is None:
        pytest.skip("no C++ compiler for the MPC kernel")
    cfg = SamplerConfig(num_samples=8, horizon=6, kernel=kernel, sigma_f=0.0, sigma_d=0.0, sigma_p=0.0, sigma_F=0.0)
    state, refs = standing(2)
    naive, rl = _horizon(cfg, (0.0, 0.0)), _horizon(cfg, DP)
    base_xy = state.com_pos_w[:, :2] - torch.tensor(robot_srbd_model().com_offset_b[:2])
    dec = decode_samples(naive[:, None], PHASE, base_xy, torch.zeros(2), torch.zeros(2, 4), cfg)
    assert not dec["contact"].any()  # duty 0: no stance, no force
    refs = Refs(refs.com_height_w, refs.lin_vel_w, refs.yaw_rate, dec["foot_target_w"][:, 0, 0])  # naive = reference
    out = {}
    for name, ws in (("naive", naive), ("rl", rl)):
        mpc = SamplingMPC(cfg, seed=0)
        mpc.record_step_costs = True
        out[name] = mpc.solve(state, refs, [ws], phase=PHASE, base_xy_w=base_xy, base_yaw=torch.zeros(2))
    a, b = out["naive"], out["rl"]
    assert (a.best_input_cost == 0).all()  # the naive warm start's footholds are the reference
    expected = 1000.0 * (DP[0] ** 2 + DP[1] ** 2) * 4 * cfg.horizon
    torch.testing.assert_close(b.best_input_cost, torch.full((2,), expected), rtol=1e-4, atol=1e-4)
    torch.testing.assert_close(b.best_state_cost, a.best_state_cost, rtol=1e-5, atol=1e-3)  # the fair comparison
    torch.testing.assert_close(b.best_cost - a.best_cost, torch.full((2,), expected), rtol=1e-3, atol=1e-2)
    assert (a.best_state_cost > 100).all()  # falling from 0.33 m at 0.5 m/s below the command is costly: not trivial
    # per horizon step: the input part is the foothold term of that step, the rest is the state's
    torch.testing.assert_close(b.step_input_costs, torch.full((2, cfg.horizon), expected / cfg.horizon))
    torch.testing.assert_close(b.step_costs - b.step_input_costs, a.step_costs - a.step_input_costs)

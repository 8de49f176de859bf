"""The crossed warm starts (``closed_loop/split_warm_start.py``): each block of the warm start the MPC receives comes
from the source the arm names, checked against ``rl_warm_start``'s own warm start and the naive warm start's rules
on the same episode, solve by solve."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from dls_quadruped.closed_loop.controllers import CONTROLLERS, ControllerConfig, make_controller
from dls_quadruped.closed_loop.episodes import commands, make_env
from dls_quadruped.mpc import warm_start
from dls_quadruped.mpc.baseline import BaselineConfig, held_footholds_block
from dls_quadruped.mpc.config import SamplerConfig
from dls_quadruped.mpc.encodings import block_slices, decode_parts
from dls_quadruped.mpc.inputs import heuristic_footholds_h

REPO = Path(__file__).resolve().parents[2]
STUDENT = REPO / "docs" / "policies" / "base_student_first_spline_h10.pt"
SMALL = SamplerConfig(num_samples=300)
SLICES = block_slices(SMALL.encoding)


def _one_policy_step(name: str):
    """One policy step (two solves) of 2 robots: per solve (warm start, result), the state and command at the
    first solve."""
    env = make_env(commands(2, 0, None), 1.0, seed=0, num_workers=0)
    try:
        ctrl = make_controller(ControllerConfig(name, student=STUDENT, sampler=SMALL, seed=3), env)
        seen = []
        solve = ctrl.mpc.solve

        def spy(state, refs, ws, props, **kw):
            assert len(ws) == 1 and tuple(props) == (1.0,)
            result = solve(state, refs, ws, props, **kw)
            seen.append((ws[0].clone(), result))
            return result

        ctrl.mpc.solve = spy
        state0 = env.state.clone()
        cmd0 = env.command_manager.command.clone()
        with torch.inference_mode():
            ctrl.step(env.get_observations())
        return seen, state0, cmd0, ctrl
    finally:
        env.close()


@pytest.fixture(scope="module")
def arms():
    return {name: _one_policy_step(name) for name in ("rl_warm_start", "rl_gait_naive_forces", "naive_gait_rl_forces")}


def test_both_crossed_arms_are_registered_and_need_one_student() -> None:
    assert {"rl_gait_naive_forces", "naive_gait_rl_forces"} <= set(CONTROLLERS)
    for name in ("rl_gait_naive_forces", "naive_gait_rl_forces"):
        with pytest.raises(ValueError, match="needs a student"):
            ControllerConfig(name)
        with pytest.raises(ValueError, match="rl_warm_start only"):
            ControllerConfig(name, student=(STUDENT, STUDENT))
        assert ControllerConfig(name, student=STUDENT).uses_mpc


def test_student_gait_arm_keeps_the_students_gait_and_footholds_and_takes_the_naive_forces(arms) -> None:
    rl, _, _, _ = arms["rl_warm_start"]
    arm, _, _, ctrl = arms["rl_gait_naive_forces"]
    assert len(arm) == len(rl) == 2
    F = SLICES["F"]
    for (ws, _), (ws_rl, _) in zip(arm, rl):  # the student's f, d, p: the same query, the same shift
        torch.testing.assert_close(ws[:, :F.start], ws_rl[:, :F.start], rtol=0, atol=0)
    # first solve: no previous plan, the nominal trot's force offsets: zero (gravity compensation)
    assert torch.equal(arm[0][0][:, F], torch.zeros_like(arm[0][0][:, F]))
    # second solve: the first plan shifted by one MPC period, its swing-step offsets zeroed
    first = arm[0][1]
    naive = warm_start.naive(first.best_encoded, ctrl.sampler_cfg, first.contact_horizon)
    torch.testing.assert_close(arm[1][0][:, F], naive[:, F])
    assert arm[1][0][:, F].abs().sum() > 0  # the MPC moved the forces: the check above compared something


def test_naive_gait_arm_takes_the_trot_and_heuristic_footholds_and_keeps_the_students_forces(arms) -> None:
    rl, _, _, _ = arms["rl_warm_start"]
    arm, state0, cmd0, _ = arms["naive_gait_rl_forces"]
    trot = BaselineConfig()
    for (ws, _), (ws_rl, _) in zip(arm, rl):
        assert torch.all(ws[:, SLICES["f"]] == trot.freq) and torch.all(ws[:, SLICES["d"]] == trot.duty)
        torch.testing.assert_close(ws[:, SLICES["F"]], ws_rl[:, SLICES["F"]], rtol=0, atol=0)
    p_h = heuristic_footholds_h(state0, cmd0, BaselineConfig(sampler=SMALL))  # eq. 2.2.4 at the first solve
    torch.testing.assert_close(arm[0][0][:, SLICES["p"]], p_h.reshape(2, 8))


@pytest.mark.parametrize("p", ["first", "discrete", "spline"])
def test_held_footholds_decode_to_the_footholds_at_every_step(p) -> None:
    cfg = SamplerConfig(encoding_p=p, encoding_F="first", horizon=10)
    p_h = torch.randn(3, 4, 2, generator=torch.Generator().manual_seed(0)) * 0.1
    s = block_slices(cfg.encoding)
    encoded = torch.zeros(3, s["F"].stop)
    encoded[:, s["p"]] = held_footholds_block(p_h, cfg)
    decoded = decode_parts(encoded, cfg.encoding)[2]  # (3, H, 4, 2)
    torch.testing.assert_close(decoded, p_h[:, None].expand(-1, 10, -1, -1), atol=1e-6, rtol=0)

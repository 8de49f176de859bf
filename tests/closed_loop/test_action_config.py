"""The latent action is configured once, in the task: a ``--set actions.latent.<field>=...`` override reaches the
env's action manager and the MPC alike, so the raw action the MPC encodes decodes in the env to the MPC's own
solution; with the MPC's own default configuration it would not."""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch

from dls_quadruped.cli import set_overrides, set_pair
from dls_quadruped.closed_loop.controllers import ControllerConfig, make_controller
from dls_quadruped.closed_loop.episodes import commands, make_env
from dls_quadruped.control.latent_action import (
    LatentAction,
    LatentActionConfig,
    denormalise,
    normalise,
)
from dls_quadruped.mpc.config import SamplerConfig

SETS = ("actions.latent.freq_shift=1.4", "actions.latent.force_xy_scale_frac=0.05")
"""Table 5 changed twice: f = 1.4 + 0.2 raw (default 1.5 + 0.2 raw), F_xy = 0.05 m g raw (default 0.025 m g raw)."""
SMALL = SamplerConfig(num_samples=64)


@pytest.fixture(scope="module")
def env():
    """The closed loop's simple-task env (2 episodes at 0.5 m/s) with the ``--set`` overrides of ``SETS``."""
    env = make_env(commands(2, 0, 0.5), 1.0, seed=0, num_workers=0,
                   overrides=set_overrides([set_pair(text) for text in SETS]))
    yield env
    env.close()


def test_the_mpc_encodes_its_solution_as_the_env_decodes_it(env) -> None:
    act_cfg = env.action_manager.cfg
    assert (act_cfg.freq_shift, act_cfg.force_xy_scale_frac) == (1.4, 0.05)  # the override reached the env
    ctrl = make_controller(ControllerConfig("naive_warm_start", sampler=SMALL), env)
    assert ctrl.sampler_cfg.action == act_cfg and ctrl.cfg.sampler.action == act_cfg
    obs = env.get_observations()
    with torch.inference_mode():
        for _ in range(3):
            obs, *_ = ctrl.step(obs)
    res = ctrl.mpc.last_result
    solution = LatentAction(res.f, res.d, res.p_h, res.F_h)
    # the env decoded the MPC's raw action (normalised with the stance count of its solve) back to the solution
    decoded = env.action_manager.applied_physical
    torch.testing.assert_close(decoded[:, :16], solution.to_vector()[:, :16], atol=1e-5, rtol=0)  # f, d, p
    torch.testing.assert_close(decoded[:, 16:], res.F_h.flatten(-2), atol=1e-3, rtol=0)  # F [N]
    assert float(env.action_manager.violation.abs().max()) < 1e-5  # nothing was clipped on the way

    # with the MPC's default configuration (what it used before it took the env's) the env would decode
    # f - 0.1 Hz (raw = (f - 1.5) / 0.2, decoded 1.4 + 0.2 raw) and twice the horizontal forces
    # (raw = F_xy / (0.025 m g), decoded 0.05 m g raw); neither needs the stance count
    default = LatentActionConfig()
    stale = denormalise(normalise(solution, 2.0, default), 2.0, act_cfg)
    torch.testing.assert_close(stale.f, solution.f - 0.1, atol=1e-5, rtol=0)
    torch.testing.assert_close(stale.F_h[..., :2], 2.0 * solution.F_h[..., :2], atol=1e-3, rtol=0)
    assert float(solution.F_h[..., :2].abs().max()) > 1.0  # the MPC's forces have a horizontal part to double


def test_a_conflicting_sampler_action_is_refused_and_outside_an_env_the_mpc_keeps_its_own(env) -> None:
    # the env's configuration given explicitly is the same single configuration: accepted
    same = ControllerConfig("naive_warm_start", sampler=replace(SMALL, action=env.action_manager.cfg))
    assert same.for_env(env) is same
    # a third configuration would make the MPC and the env disagree: refused, naming the fields
    other = replace(LatentActionConfig(), freq_shift=1.6)
    cfg = ControllerConfig("naive_warm_start", sampler=replace(SMALL, action=other))
    with pytest.raises(ValueError, match=r"differs from the env's action configuration \(the task's actions\.latent\) "
                                         r"in freq_shift \(sampler 1\.6, env 1\.4\), force_xy_scale_frac "
                                         r"\(sampler 0\.025, env 0\.05\); .*--set actions\.latent"):
        cfg.for_env(env)
    # outside an env (library use, benches) the config keeps the MPC's own default
    assert ControllerConfig("naive_warm_start", sampler=SMALL).sampler.action == LatentActionConfig()

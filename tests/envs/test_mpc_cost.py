"""A policy acting in the MPC's horizon space (``actions.horizon``) and the ``mpc_trajectory_cost`` reward term.

The term is checked against the MPC's own solve of the same horizon from the state it was chosen at (a one-sample
``SamplingMPC`` with the controller's kernel scores its warm start unperturbed), its split against its value, and
the env's applied action against the student's own first action.
"""

from __future__ import annotations

import pytest
import torch

from dls_quadruped.envs.config import ConfigError, load_task
from dls_quadruped.envs.env import LocomotionEnv
from dls_quadruped.mpc import warm_start
from dls_quadruped.mpc.baseline import BaselineConfig
from dls_quadruped.mpc.config import SamplerConfig
from dls_quadruped.mpc.horizon import TERM_NAMES
from dls_quadruped.mpc.inputs import heuristic_footholds_h, mpc_inputs
from dls_quadruped.mpc.sampler import SamplingMPC

STUDENT = "docs/policies/base_recipe_student_first_spline_h10.pt2"
NO_WORKERS = {"scene": {"num_workers": 0}}


def _env(**overrides) -> LocomotionEnv:
    data = {**NO_WORKERS, **overrides}
    return LocomotionEnv(load_task("base_mpc_cost", overrides=data), num_envs=3, verbose=False, seed=1)


@pytest.fixture(scope="module")
def walked():
    """The task on 3 robots driven by the DAgger student for 20 policy steps: (env, student, last obs)."""
    from dls_quadruped.learning.student import load_student

    env = _env()
    student, _ = load_student(STUDENT)
    obs, _ = env.reset()
    for _ in range(20):
        with torch.no_grad():
            obs, *_ = env.step(student(obs["policy"]))
    yield env, student, obs
    env.close()


def _mpc_solve(env):
    """The MPC's one-sample solve of the env's last horizon from its decision state (``SamplingMPC.solve``, the
    controller's kernel, its state terms recorded)."""
    am = env.action_manager
    cfg = SamplerConfig(num_samples=1, horizon=10, dt=0.02)
    mpc = SamplingMPC(cfg, seed=0)
    mpc.record_step_costs = True
    state, cmd = am.decision_state, am.decision_command
    base = BaselineConfig(com_height=0.404, sampler=cfg)
    srbd, refs, frame = mpc_inputs(state, cmd, heuristic_footholds_h(state, cmd, base), 0.404, cfg, mpc.model)
    return mpc.solve(srbd, refs, [warm_start.from_student(am.raw_horizon, cfg)], phase=state.phase, **frame)


def _mpc_state_cost(env) -> torch.Tensor:
    """(B,) the solve's state cost: its J less its input part."""
    result = _mpc_solve(env)
    return result.best_cost - result.best_input_cost


def test_the_term_is_the_mpc_cost_of_the_horizon_over_the_reference(walked):
    env, _, _ = walked
    from dls_quadruped.envs.mdp import rewards

    value = rewards.mpc_trajectory_cost(env, reference_cost=200.0, com_height=0.404, clip=1e9, split_every=1)
    result = _mpc_solve(env)
    torch.testing.assert_close(value, (result.best_cost - result.best_input_cost) / 200.0, rtol=2e-4, atol=1e-4)
    assert float(value.min()) > 0.1
    parts = rewards.mpc_trajectory_cost.parts(env)
    assert list(parts) == list(TERM_NAMES)
    torch.testing.assert_close(torch.stack(list(parts.values()), dim=1), result.state_terms / 200.0, rtol=1e-3,
                               atol=1e-4)
    torch.testing.assert_close(torch.stack(list(parts.values())).sum(0), value, rtol=1e-5, atol=1e-6)


def test_between_splits_the_parts_keep_the_last_shares(walked):
    env, _, _ = walked
    from dls_quadruped.envs.mdp import rewards

    rewards.mpc_trajectory_cost(env, clip=1e9, split_every=1)
    shares = torch.stack(list(rewards.mpc_trajectory_cost.parts(env).values()), dim=1)
    shares = shares / shares.sum(1, keepdim=True)
    value = rewards.mpc_trajectory_cost(env, reference_cost=100.0, clip=1e9, split_every=1000)  # no split: calls > 0
    parts = torch.stack(list(rewards.mpc_trajectory_cost.parts(env).values()), dim=1)
    torch.testing.assert_close(parts, value[:, None] * shares, rtol=1e-5, atol=1e-6)


def test_the_reward_manager_adds_the_weighted_clipped_term(walked):
    env, _, _ = walked
    rm = env.reward_manager
    i = [t.name for t in rm.terms].index("mpc_trajectory_cost")
    rewards_step = rm.step_reward[:, i].clone()
    expected = -0.1 * torch.clamp(_mpc_state_cost(env) / 200.0, max=100.0) * env.step_dt  # the task's weight and clip
    torch.testing.assert_close(rewards_step, expected, rtol=2e-4, atol=1e-6)


def test_clipped_value_keeps_its_split_summing_to_it(walked):
    env, _, _ = walked
    from dls_quadruped.envs.mdp import rewards

    value = rewards.mpc_trajectory_cost(env, reference_cost=200.0, com_height=0.404, clip=0.05, split_every=1)
    torch.testing.assert_close(value, torch.full((3,), 0.05))
    parts = torch.stack(list(rewards.mpc_trajectory_cost.parts(env).values()))
    torch.testing.assert_close(parts.sum(0), value, rtol=1e-5, atol=1e-7)


def test_env_applies_the_students_first_action_and_keeps_the_state_it_was_chosen_at(walked):
    env, student, obs = walked
    am = env.action_manager
    before = env.state.clone()
    with torch.no_grad():
        horizon = student(obs["policy"])
        first = student.first_action(obs["policy"])
    env.step(horizon)
    torch.testing.assert_close(am.raw_action, first)
    torch.testing.assert_close(am.raw_horizon, horizon)
    torch.testing.assert_close(am.decision_state.base_pos_w, before.base_pos_w)
    assert not torch.allclose(env.state.base_pos_w, before.base_pos_w)  # the robots moved since


def test_split_is_logged_per_term_at_reset(walked):
    env, _, _ = walked
    logs = env.reward_manager.reset(torch.ones(3, dtype=torch.bool))
    split = sum(float(logs[f"Episode_Reward/mpc_trajectory_cost/{n}"]) for n in TERM_NAMES)
    assert split == pytest.approx(float(logs["Episode_Reward/mpc_trajectory_cost"]), rel=1e-4)
    assert float(logs["Episode_Reward/mpc_trajectory_cost"]) < 0


def test_a_latent_action_is_refused_by_a_horizon_task(walked):
    env, _, _ = walked
    with pytest.raises(ValueError, match=r"\(3, 64\)"):
        env.step(torch.zeros(3, 28))


@pytest.mark.parametrize(("params", "match"), [
    ({"reference_cost": 0.0}, "reference_cost must be > 0"),
    ({"com_height": 4.04}, "com_height"),
    ({"clip": float("inf")}, "clip must be > 0 and finite"),
    ({"split_every": 0}, "split_every must be an int >= 1"),
])
def test_bad_term_parameters_are_named(walked, params, match):
    env, _, _ = walked
    from dls_quadruped.envs.mdp import rewards

    with pytest.raises(ValueError, match=match):
        rewards.mpc_trajectory_cost(env, **params)


def test_the_term_needs_a_horizon_action(small_base_env):
    from dls_quadruped.envs.mdp import rewards

    with pytest.raises(ValueError, match="needs actions.horizon"):
        rewards.mpc_trajectory_cost(small_base_env)


@pytest.mark.parametrize(("horizon", "key", "match"), [
    ({"p": "first", "H": 10}, "actions.horizon.H", "unknown key"),
    ({"p": "linear"}, "actions.horizon", "must be one of"),
    ({"F": "spline", "horizon": 3}, "actions.horizon", "horizon must be >= 4"),
    ({"dt": 0}, "actions.horizon.dt", "seconds in"),
])
def test_bad_horizon_config_is_named(horizon, key, match):
    with pytest.raises(ConfigError, match=match) as err:
        load_task("base_mpc_cost", overrides={"actions": {"horizon": horizon}})
    assert f": {key}: " in str(err.value)

"""Actions of absurd but finite size: 1e20 is clipped and penalised as 1e6 is (a large, finite penalty and the
clipped action observed), and an entry whose physical value overflows float32 (-3e38 in a force) is refused as an
inf is: its robot is terminated in ``step``, and ``apply_action`` names the robot and the component."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from dls_quadruped.control.latent_action import RAW_LIMIT, ActionInterface
from dls_quadruped.envs.gym_spaces import action_bounds
from dls_quadruped.envs.mdp import observations as obs_mdp
from dls_quadruped.envs.mdp import rewards


@pytest.fixture(scope="module")
def env(small_base_env):
    return small_base_env  # tests/conftest.py


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_1e20_is_clipped_and_penalised_as_1e6(env, sign):
    env.reset(seed=0)
    action = torch.zeros(3, 28)
    action[1], action[2] = sign * RAW_LIMIT, sign * 1e20
    obs, reward, dones, _ = env.step(action)
    am = env.action_manager
    assert not dones.any() and torch.isfinite(reward).all()
    violation = rewards.clipping_violation(env)
    # every entry is outside its clip range by about 1e6 raw units: ||v||^2 ~ 28e12
    assert 2.7e13 < violation[1] < 2.9e13 and violation[2] == violation[1]
    assert torch.isfinite(rewards.action_rate(env)).all() and rewards.action_rate(env)[2] == rewards.action_rate(env)[1]
    assert torch.equal(am.applied_physical[2], am.applied_physical[1])  # the same clipped references
    last = obs_mdp.last_action(env)
    assert torch.equal(last[2], last[1]) and torch.isfinite(obs["policy"]).all()
    low, high = (torch.as_tensor(b, dtype=torch.float32) for b in action_bounds(am.cfg))
    # the clipped action in network units, up to float32 round-off of 1e6 (its spacing is 0.0625)
    assert ((last[1] >= low - 0.25) & (last[1] <= high + 0.25)).all(), last[1]
    assert (last[1] - (high if sign > 0 else low)).abs()[:8].max() < 0.25  # f and d sit at their limits


def test_a_force_that_overflows_terminates_its_robot_like_an_inf(env):
    env.reset(seed=0)
    env.episode_log.read()  # what earlier steps logged
    action = torch.zeros(3, 28)
    action[1] = -3e38
    obs, reward, dones, _ = env.step(action)
    assert dones.tolist() == [0, 1, 0]
    assert env.episode_log.read()["Episode_Termination/nonfinite_action"] == 1.0
    assert torch.isfinite(obs["policy"]).all() and torch.isfinite(reward).all()
    assert torch.isfinite(obs_mdp.last_action(env)).all() and torch.isfinite(env.action_manager.raw_action).all()


def test_apply_action_names_the_robot_and_the_component_that_overflow(env):
    env.reset(seed=0)
    env.step(torch.zeros(3, 28))
    before = [b.clone() for b in (env.action_manager.raw_action, env.action_manager.prev_raw_action)]
    action = torch.zeros(3, 28)
    action[1, 4] = -3e38   # d[FL]: 0.03 x -3e38 is still a float32
    action[1, 24] = -3e38  # F_z[RL]: 21 N x -3e38 is not
    with pytest.raises(ValueError, match=r"^latent action has non-finite values \(NaN/inf, or inf once scaled to "
                                         r"physical units\) for robots \[1\] in components \['F_z\[RL\]'\]; "):
        env.step_controlled(lambda: env.apply_action(action, env.decimation))
    for a, b in zip(before, (env.action_manager.raw_action, env.action_manager.prev_raw_action)):
        assert torch.equal(a, b)  # refused before any buffer changed


def test_action_interface_clips_1e20_as_1e6_and_refuses_an_overflow():
    interface = ActionInterface()
    state = (torch.full((2,), 2), torch.zeros(2, 3), torch.zeros(2))
    raw = torch.from_numpy(np.array([[RAW_LIMIT] * 28, [1e20] * 28], dtype=np.float32))
    refs = interface(raw, *state)
    for name in ("f", "d", "p_td_w", "F_w", "violation"):
        value = getattr(refs, name)
        assert torch.isfinite(value).all() and torch.equal(value[0], value[1]), name
    raw[1, 16] = 3e38  # F_x[FL]
    with pytest.raises(ValueError, match=r"for robots \[1\] in components \['F_x\[FL\]'\]"):
        interface(raw, *state)

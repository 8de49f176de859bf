"""The episode recorder (``envs/recorder.py``) on a scripted env whose episodes end at known steps: what belongs
to each robot's first episode (``active``, ``valid``), lengths, falls, probes read before and after a step,
the controller's reset at every restart, the early stop, and the dtypes the probes came in."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch
from tensordict import TensorDict

from dls_quadruped.envs.controller import EnvController
from dls_quadruped.envs.recorder import EpisodeRecord, record

DT = 0.02


class ScriptedEnv:
    """Three robots. Robot 0 times out at step 6; robot 1 falls at step 2; robot 2 falls at step 4 and, in the
    episode the env restarted it in, again at step 5. Reward of robot e at step k: (k + 10 e) DT. ``k`` counts
    the steps taken; after a step, each robot reads its episode's own step count (0 right after a restart)."""

    num_envs, step_dt, max_episode_length = 3, DT, 6

    def __init__(self):
        self.k = 0
        self.episode_k = torch.zeros(3)
        self.command_manager = SimpleNamespace(
            command=torch.tensor([[0.5, 0.0, 0.0], [0.2, 0.1, 0.0], [0.0, 0.0, 1.0]]))

    def get_observations(self) -> TensorDict:
        return TensorDict({"policy": torch.full((3, 1), float(self.k))}, batch_size=[3])

    def step(self, actions: torch.Tensor):
        assert actions[0, 0] == self.k  # the controller acted on the last observation
        self.k += 1
        fall = torch.tensor([False, self.k == 2, self.k in (4, 5)])
        time_out = torch.tensor([self.k == 6, False, False])
        dones = fall | time_out
        reward = (self.k + 10.0 * torch.arange(3)) * DT
        self.episode_k = torch.where(dones, 0.0, self.episode_k + 1)  # the env restarts ended robots in step
        return self.get_observations(), reward, dones.long(), {"time_outs": time_out}


class Echo(EnvController):
    """At the policy rate: its action is the observation; keeps the ids of every reset."""

    def __init__(self, env):
        super().__init__(env)
        self.resets: list[list[int]] = []

    def act(self, obs: TensorDict, substep: int) -> torch.Tensor:
        return obs["policy"]

    def reset(self, env_ids: torch.Tensor) -> None:
        self.resets.append(env_ids.tolist())


def _record(env, steps=None, **kw) -> tuple[EpisodeRecord, list[list[int]]]:
    ctrl = Echo(env)
    rec = record(env, ctrl, {"episode_k": lambda e: e.episode_k.clone(),
                             "bool": lambda e: torch.tensor([True, False, True]),
                             "f64": lambda e: torch.full((3, 2), e.k, dtype=torch.float64)},
                 steps, before={"k_before": lambda e: torch.full((3,), float(e.k))}, **kw)
    return rec, ctrl.resets


def test_masks_lengths_and_falls_by_hand():
    env = ScriptedEnv()
    rec, resets = _record(env)
    assert rec.steps == 6 and rec.step_dt == DT
    np.testing.assert_array_equal(rec.command, env.command_manager.command.numpy())
    # step index i is step k = i + 1; a robot's steps up to and including the one that ends it are active
    assert rec.active[:, 0].tolist() == [True] * 6
    assert rec.active[:, 1].tolist() == [True, True, False, False, False, False]
    assert rec.active[:, 2].tolist() == [True] * 4 + [False] * 2
    # the state after the ending step already belongs to the next episode
    assert rec.valid[:, 0].tolist() == [True] * 5 + [False]
    assert rec.valid[:, 1].tolist() == [True, False, False, False, False, False]
    assert rec.valid[:, 2].tolist() == [True] * 3 + [False] * 3
    assert rec.fell.tolist() == [False, True, True]  # a time-out is not a fall; robot 2's second end is not counted
    assert rec.length.tolist() == [6, 2, 4]
    assert resets == [[1], [2], [2], [0]]  # every restart, the second episode's too


def test_rewards_and_probes_by_hand():
    rec, _ = _record(ScriptedEnv())
    k = np.arange(1, 7, dtype=np.float32)
    np.testing.assert_allclose(rec.reward, k[:, None] + 10.0 * np.arange(3)[None, :], rtol=1e-6)  # per step, no dt
    reward = rec.masked(rec.reward, rec.active)
    assert np.isnan(reward[2:, 1]).all() and np.isfinite(reward[:2, 1]).all()
    assert reward[3, 2] == np.float32(rec.reward[3, 2]) and abs(reward[3, 2] - 24.0) < 1e-4  # the ending step keeps it
    np.testing.assert_array_equal(rec.before["k_before"][:, 0], k - 1)  # read before each step
    after = rec.after["episode_k"]  # (T, E) read after each step: raw, the next episode's values included
    assert after[:, 1].tolist() == [1, 0, 1, 2, 3, 4] and after[:, 2].tolist() == [1, 2, 3, 0, 0, 1]
    kept = rec.masked(after, rec.valid)
    np.testing.assert_array_equal(kept[:, 2], [1, 2, 3, np.nan, np.nan, np.nan])
    assert np.array_equal(rec.masked(after, rec.valid, fill=-1.0)[:, 1], [1, -1, -1, -1, -1, -1])
    # probes keep their dtype and trailing shape; masking broadcasts over it
    assert rec.after["bool"].dtype == bool and rec.after["f64"].dtype == np.float64
    assert rec.after["f64"].shape == (6, 3, 2) and rec.after["f64"][4, 1, 0] == 5.0
    assert np.isnan(rec.masked(rec.after["f64"], rec.valid)[1:, 1]).all()


def test_the_loop_stops_once_every_episode_has_ended():
    env = ScriptedEnv()
    rec, resets = _record(env, steps=10, stop_when_all_ended=True)
    assert env.k == 6 and rec.steps == 6  # robot 0 timed out at step 6, the last one still up
    assert rec.active.shape == (10, 3) and not rec.active[6:].any() and not rec.valid[6:].any()
    assert (rec.after["episode_k"][6:] == 0).all()  # rows not simulated stay zero, and masked
    assert resets == [[1], [2], [2]]  # no restart after the stop
    assert rec.length.tolist() == [6, 2, 4]
    rec, _ = _record(ScriptedEnv(), steps=8)  # without the stop the env goes on; the masks are the same
    assert rec.steps == 8 and not rec.active[6:].any()


def test_the_start_command_is_a_copy():
    env = ScriptedEnv()
    rec, _ = _record(env)
    env.command_manager.command[:] = 9.0
    assert rec.command[0, 0] == 0.5


class ActedEnv(ScriptedEnv):
    """The scripted env stepped with actions (a policy's), which it keeps."""

    def __init__(self):
        super().__init__()
        self.applied: list[torch.Tensor] = []

    def step(self, actions: torch.Tensor):
        self.applied.append(actions.clone())
        return super().step(self.get_observations()["policy"])


def _double(obs: torch.Tensor) -> torch.Tensor:
    """(3, 1) -> (3, 2): (2 k, 2 k + e) for robot e at observation k."""
    return torch.cat([2.0 * obs, 2.0 * obs + torch.arange(3.0)[:, None]], dim=1)


def test_a_policy_its_captured_inputs_actions_and_returns_by_hand():
    env = ActedEnv()
    rec = record(env, policy=_double, obs_group="policy", capture=slice(1, 3))
    assert len(env.applied) == 6 and env.applied[4].tolist() == [[8.0, 8.0], [8.0, 9.0], [8.0, 10.0]]
    assert rec.obs.shape == (6, 2, 1) and rec.actions.shape == (6, 2, 2)  # robots 1 and 2 only
    assert rec.obs[:, 0, 0].tolist() == [0, 1, 2, 3, 4, 5]  # the observation each action was chosen at
    assert rec.actions[:, 1].tolist() == [[2 * k, 2 * k + 2] for k in range(6)]
    kept = rec.masked(rec.actions, rec.active[:, 1:3], fill=0.0)  # robot 1 fell at step 2: zeros after
    assert kept[:, 0, 1].tolist() == [1.0, 3.0, 0, 0, 0, 0] and kept[:, 1, 1].tolist() == [2.0, 4.0, 6.0, 8.0, 0, 0]
    # raw reward (k + 10 e) DT summed over each first episode, the ending step included: robot 0 steps 1-6,
    # robot 1 steps 1-2, robot 2 steps 1-4 (not its second episode's)
    np.testing.assert_allclose(rec.episode_return, np.array([21.0, 23.0, 90.0]) * DT, rtol=1e-6)
    assert rec.episode_return.dtype == np.float64
    assert rec.length.tolist() == [6, 2, 4] and rec.fell.tolist() == [False, True, True]
    every = record(ActedEnv(), policy=_double, obs_group="policy", capture=True)
    np.testing.assert_array_equal(every.actions[:, 1:3], rec.actions)
    assert record(ActedEnv(), policy=_double, obs_group="policy").obs is None  # nothing captured unasked


def test_until_ends_the_loop_before_the_chosen_action_is_applied():
    env = ActedEnv()
    asked = []

    def until() -> bool:
        asked.append(env.k)
        return env.k == 3

    rec = record(env, policy=_double, obs_group="policy", capture=True, until=until)
    assert asked == [0, 1, 2, 3] and env.k == 3 and len(env.applied) == 3  # the 4th action was not applied
    assert rec.steps == 3 and rec.active[:3, 0].all() and not rec.active[3:].any()
    assert rec.obs[3, 0, 0] == 3.0  # ... but its observation was taken (what the data collection relies on)
    assert rec.length.tolist() == [6, 2, 6]  # robot 0's and 2's episodes had not ended: the steps asked for


def test_grad_mode_inference_or_no_grad():
    seen = []

    def policy(obs):
        seen.append((torch.is_inference_mode_enabled(), torch.is_grad_enabled()))
        return _double(obs)

    record(ActedEnv(), policy=policy, obs_group="policy", num_steps=1)
    record(ActedEnv(), policy=policy, obs_group="policy", num_steps=1, no_grad=True)
    assert seen == [(True, False), (False, False)]


def test_bad_arguments_name_what_is_allowed():
    env = ActedEnv()
    with pytest.raises(ValueError, match="exactly one of controller"):
        record(env)
    with pytest.raises(ValueError, match="exactly one of controller"):
        record(env, Echo(env), policy=_double)
    with pytest.raises(ValueError, match="give policy and obs_group"):
        record(env, policy=_double, capture=True)
    with pytest.raises(ValueError, match="give policy and obs_group"):
        record(env, Echo(env), capture=True)


def test_the_controller_must_act_in_the_recorded_env():
    with pytest.raises(ValueError, match="another env"):
        record(ScriptedEnv(), Echo(ScriptedEnv()))

"""The episode recorder (``envs/recorder.py``) on a scripted env whose episodes end at known steps: what belongs
to each robot's first episode (``active``, ``valid``), lengths, falls, probes read before and after a step,
the restart hook, the early stop, and the dtypes the probes came in."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import torch
from tensordict import TensorDict

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

    def step(self, obs: TensorDict):
        assert obs["policy"][0, 0] == self.k  # the step function is handed the last observation
        self.k += 1
        fall = torch.tensor([False, self.k == 2, self.k in (4, 5)])
        time_out = torch.tensor([self.k == 6, False, False])
        dones = fall | time_out
        reward = (self.k + 10.0 * torch.arange(3)) * DT
        self.episode_k = torch.where(dones, 0.0, self.episode_k + 1)  # the env restarts ended robots in step
        return self.get_observations(), reward, dones.long(), {"time_outs": time_out}


def _record(env, steps=None, **kw) -> tuple[EpisodeRecord, list[list[int]]]:
    resets: list[list[int]] = []
    rec = record(env, env.step, {"episode_k": lambda e: e.episode_k.clone(),
                                 "bool": lambda e: torch.tensor([True, False, True]),
                                 "f64": lambda e: torch.full((3, 2), e.k, dtype=torch.float64)},
                 steps, before={"k_before": lambda e: torch.full((3,), float(e.k))},
                 on_reset=lambda ids: resets.append(ids.tolist()), **kw)
    return rec, resets


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

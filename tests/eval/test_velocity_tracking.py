"""Simple-task evaluation (issue 14 item 1): metrics on a scripted policy whose response is known,
the Table-4 evaluation task, and the command line end to end on a tiny run."""

from __future__ import annotations

import json
import math
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from tensordict import TensorDict

from dls_quadruped.envs.config import TASKS_DIR, load_task
from dls_quadruped.eval import metrics as M
from dls_quadruped.eval import velocity_tracking as V
from dls_quadruped.eval.rollout import run_episodes
from dls_quadruped.eval.scenario import EvalOptions
from dls_quadruped.eval.scenarios import SCENARIOS

GAIN = np.array([1.0, 0.5, 0.8])
BIAS = np.array([0.0, 0.02, -0.1])
STEP_DT = 0.02


class ScriptedEnv:
    """Stand-in env: the base velocity equals the first three action values from step ``lag`` on
    (0 before), a constant reward of 2 per second, env 0 falls at step 10 and every env times
    out at ``steps``; after its end an env reads nonsense (999) that must be masked out."""

    def __init__(self, command: np.ndarray, steps: int, lag: int = 20):
        self.num_envs, self.step_dt, self.max_episode_length = len(command), STEP_DT, steps
        self.command_manager = SimpleNamespace(command=torch.as_tensor(command, dtype=torch.float32))
        self.k, self.lag, self.vel = 0, lag, torch.zeros(len(command), 3)
        self.ended = torch.zeros(len(command), dtype=torch.bool)

    def get_observations(self) -> TensorDict:
        return TensorDict({"policy": self.command_manager.command.clone()}, batch_size=[self.num_envs])

    def step(self, actions):
        self.k += 1
        self.vel = actions[:, :3].clone() if self.k >= self.lag else torch.zeros_like(self.vel)
        fall = torch.zeros(self.num_envs, dtype=torch.bool)
        fall[0] = self.k == 10
        time_out = torch.full((self.num_envs,), self.k == self.max_episode_length)
        dones = fall | time_out
        self.vel[self.ended | dones] = 999.0
        self.ended |= dones
        return self.get_observations(), torch.full((self.num_envs,),
                                                   2.0 * STEP_DT), dones.long(), {"time_outs": time_out}


def scripted_policy(obs: TensorDict) -> torch.Tensor:
    """Achieves GAIN * command + BIAS on each axis."""
    return obs["policy"] * torch.tensor(GAIN, dtype=torch.float32) + torch.tensor(BIAS, dtype=torch.float32)


def test_metrics_of_a_scripted_policy_with_known_response():
    cmd = V.simple_commands(64, seed=3)
    steps = 250  # 5 s, 2 s of settle
    traces = run_episodes(ScriptedEnv(cmd, steps), scripted_policy, velocity=lambda env: env.vel)
    res = V.summarize(traces, settle_s=2.0, pairs=V.paired_indices(64))
    assert res["survival"]["survived"] == 63 and res["survival"]["rate"] == pytest.approx(63 / 64)
    lo, hi = res["survival"]["ci95"]
    assert lo < 63 / 64 < hi <= 1.0
    ok = np.arange(64) != 0  # env 0 fell before the settle: no velocity data
    for a, name in enumerate(V.AXES):
        axis = res["axes"][name]
        assert axis["slope"] == pytest.approx(GAIN[a], abs=1e-5)
        assert axis["n"] == 63
        expected = np.mean((GAIN[a] - 1.0) * cmd[ok, a] + BIAS[a])  # achieved - commanded
        assert axis["mean_error"] == pytest.approx(expected, abs=1e-5)
    # mirror: m(c) - M m(M c) = BIAS - M BIAS = (0, 2 b_y, 2 b_w) for every pair; pair 0 holds env 0
    for a, name in enumerate(V.AXES):
        assert res["mirror"][name]["n"] == 31
        assert res["mirror"][name]["mean_diff"] == pytest.approx([0.0, 0.04, -0.2][a], abs=1e-5)
        assert res["mirror"][name]["mean_abs_diff"] == pytest.approx([0.0, 0.04, 0.2][a], abs=1e-5)
    err_xy = np.abs((GAIN[1] - 1.0) * cmd[ok, 1] + BIAS[1])  # v_x is exact, so |v_xy - cmd| = |v_y error|
    assert res["tracking"]["vxy_error"]["median"] == pytest.approx(np.median(err_xy), abs=1e-5)
    assert res["tracking"]["vxy_error"]["q1"] == pytest.approx(np.percentile(err_xy, 25), abs=1e-5)
    assert res["tracking"]["yaw_rate_error"]["median"] == pytest.approx(
        np.median(np.abs(-0.2 * cmd[ok, 2] - 0.1)), abs=1e-5)
    assert res["reward"]["per_step"] == pytest.approx(2.0)
    targets = V.check_targets(res)
    assert targets["survival"]["met"] is False and targets["slope_v_x"]["met"] is True
    assert targets["slope_v_y"]["met"] is False and targets["reward_per_step"]["met"] is False


def test_statistics_by_hand():
    # Wilson interval of 256/256 at 95 %: lower = n / (n + z^2) = 256 / 259.84 = 0.98523
    assert M.wilson_interval(256, 256)[0] == pytest.approx(256 / (256 + M.Z95 ** 2), rel=1e-9)
    assert M.wilson_interval(256, 256)[1] == pytest.approx(1.0)
    fit = M.linear_fit(np.array([0.0, 1.0, 2.0, 3.0]), np.array([1.0, 3.0, 5.0, 7.0]))
    assert fit["slope"] == pytest.approx(2.0) and fit["intercept"] == pytest.approx(1.0)
    assert fit["slope_ci95"][0] == pytest.approx(2.0)  # no residual
    assert M.median_iqr(np.array([1.0, 2.0, 3.0, 4.0, 5.0])) == {"median": 3.0, "q1": 2.0, "q3": 4.0, "n": 5}
    x = np.arange(12.0).reshape(3, 2, 2)  # (T=3, E=2, 2)
    valid = np.array([[True, False], [True, False], [False, False]])
    out = M.masked_mean(x, valid)
    assert out[0].tolist() == [2.0, 3.0] and all(math.isnan(v) for v in out[1])


def test_simple_commands_are_mirrored_pairs_in_the_ranges():
    cmd = V.simple_commands(256, seed=0)
    lo, hi = np.array(V.SIMPLE_RANGES).T
    assert cmd.shape == (256, 3) and (cmd >= lo).all() and (cmd <= hi).all()
    np.testing.assert_array_equal(cmd[128:], cmd[:128] * [1.0, -1.0, -1.0])
    with pytest.raises(ValueError, match="even"):
        V.simple_commands(255, seed=0)


def test_evaluation_task_uses_table4_whatever_the_training_reward():
    task = V.flat_task(np.zeros((4, 3)), EvalOptions(episodes=4, num_workers=0))
    assert task.data["rewards"] == load_task(TASKS_DIR / "_base_rewards.yaml").data["rewards"]
    assert task.data["rewards"]["track_lin_vel_xy"] == {"weight": 1.5, "params": {"sigma": 0.5}}  # Table 4
    assert task.data["curriculum"] == {} and list(task.data["events"]) == ["reset_robot"]
    assert all(g["noise_scale"] == 0.0 for g in task.data["observations"].values())
    assert task.data["terrain"] == {"types": ["flat"]}
    assert task.data["commands"]["base_velocity"]["func"] == "fixed_velocity"


def test_fixed_velocity_command_term():
    from dls_quadruped.envs.mdp.commands import fixed_velocity

    env = SimpleNamespace(num_envs=3, device="cpu")
    values = [[0.1, 0.2, 0.3], [0.4, 0.5, 0.6], [0.7, 0.8, 0.9]]
    out = fixed_velocity(env, torch.tensor([2, 0]), values)
    assert torch.allclose(out, torch.tensor([[0.7, 0.8, 0.9], [0.1, 0.2, 0.3]]))
    with pytest.raises(ValueError, match=r"\(num_envs, 3\) = \(3, 3\)"):
        fixed_velocity(env, torch.tensor([0]), values[:2])


def test_scenarios_table():
    assert {"simple", "forward"} <= set(SCENARIOS)
    assert all(name == s.name for name, s in SCENARIOS.items())


class _Zero(torch.nn.Module):
    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.zeros(x.shape[0], 28)


def test_command_line_end_to_end(tmp_path, save_policy):
    """Real env, a scripted (zero-action) exported policy, 4 episodes of 0.6 s."""
    from dls_quadruped.eval.__main__ import main

    policy = save_policy(_Zero(), 259, tmp_path / "zero.pt2")
    res = main(["--policy", str(policy), "--scenario", "simple", "--episodes", "4", "--episode-length-s", "0.6",
                "--num-workers", "0", "--out", str(tmp_path / "out")])
    saved = json.loads((tmp_path / "out" / "simple.json").read_text())
    assert (tmp_path / "out" / "simple.png").stat().st_size > 0
    assert saved["episodes"] == 4 and saved["episode_steps"] == 30 and res["scenario"] == "simple"
    assert set(saved["targets"]) == set(V.TARGETS)
    assert np.isfinite(saved["reward"]["per_step"])
    # the commands the env ran are the scenario's
    np.testing.assert_allclose(saved["per_episode"]["command"], V.simple_commands(4, 0), atol=1e-5)

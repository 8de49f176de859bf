"""The faster PPO update (learning/fast_update.py) computes what rsl-rl-lib's stock update computes:
the same mini-batches, the same losses (the logged mirror loss included), learning rate and weights
after a full update (5 epochs x 4 mini-batches of the base task's config) from the same rollout."""

from __future__ import annotations

import copy

import pytest
import torch
from rsl_rl.runners import OnPolicyRunner
from rsl_rl.storage import RolloutStorage
from tensordict import TensorDict

from dls_quadruped.envs.config import load_task
from dls_quadruped.envs.env import LocomotionEnv
from dls_quadruped.learning import fast_update
from dls_quadruped.learning.fast_update import (
    ReusedForwardSymmetry,
    ShuffleOnceStorage,
    fused_optimizer,
    speed_up_update,
)
from dls_quadruped.learning.runner import runner_config


def _filled_storage(num_envs: int = 6, steps: int = 4, obs_dim: int = 5, num_actions: int = 3) -> RolloutStorage:
    gen = torch.Generator().manual_seed(0)
    obs = TensorDict({"policy": torch.zeros(num_envs, obs_dim)}, batch_size=[num_envs])
    st = RolloutStorage("rl", num_envs, steps, obs, [num_actions])
    for _ in range(steps):
        t = RolloutStorage.Transition()
        t.observations = TensorDict({"policy": torch.randn(num_envs, obs_dim, generator=gen)}, batch_size=[num_envs])
        t.actions = torch.randn(num_envs, num_actions, generator=gen)
        t.rewards, t.dones = torch.randn(num_envs, generator=gen), torch.zeros(num_envs)
        t.values = torch.randn(num_envs, 1, generator=gen)
        t.actions_log_prob = torch.randn(num_envs, generator=gen)
        t.distribution_params = (torch.randn(num_envs, num_actions, generator=gen),
                                 torch.rand(num_envs, num_actions, generator=gen))
        st.add_transition(t)
    st.returns.copy_(torch.randn(st.returns.shape, generator=gen))
    st.advantages = torch.randn(st.returns.shape, generator=gen)
    return st


def test_shuffle_once_yields_the_stock_mini_batches():
    """Same permutation draw, same rows in the same order, every epoch; each mini-batch contiguous."""
    stock = _filled_storage()
    fast = copy.deepcopy(stock)
    fast.__class__ = ShuffleOnceStorage
    torch.manual_seed(3)
    want = list(stock.mini_batch_generator(num_mini_batches=4, num_epochs=2))
    torch.manual_seed(3)
    got = list(fast.mini_batch_generator(num_mini_batches=4, num_epochs=2))
    assert len(got) == len(want) == 8
    assert not torch.equal(want[0].actions, want[1].actions)  # a test that could tell mini-batches apart
    for w, g in zip(want, got, strict=True):
        assert torch.equal(g.observations["policy"], w.observations["policy"])
        for field in ("actions", "values", "advantages", "returns", "old_actions_log_prob"):
            assert torch.equal(getattr(g, field), getattr(w, field)), field
            assert getattr(g, field).is_contiguous(), field
        for gp, wp in zip(g.old_distribution_params, w.old_distribution_params, strict=True):
            assert torch.equal(gp, wp)


def test_fused_optimizer_keeps_class_params_and_defaults():
    net = torch.nn.Linear(3, 2)
    opt = torch.optim.Adam(net.parameters(), lr=3e-4, betas=(0.8, 0.9))
    fused = fused_optimizer(opt)
    assert type(fused) is torch.optim.Adam and fused.defaults["fused"]
    assert fused.param_groups[0]["lr"] == 3e-4 and fused.param_groups[0]["betas"] == (0.8, 0.9)
    assert fused.param_groups[0]["params"] == list(net.parameters())
    sgd = torch.optim.SGD(net.parameters(), lr=0.1)
    assert fused_optimizer(sgd) is sgd  # no fused kernel wanted there: unchanged


def test_update_threads_share_the_cores_among_torchrun_processes(monkeypatch):
    monkeypatch.setattr(fast_update, "available_cores", lambda: 16)
    monkeypatch.delenv("LOCAL_WORLD_SIZE", raising=False)
    assert fast_update.default_update_threads() == 16
    monkeypatch.setenv("LOCAL_WORLD_SIZE", "3")
    assert fast_update.default_update_threads() == 5
    monkeypatch.setenv("LOCAL_WORLD_SIZE", "32")
    assert fast_update.default_update_threads() == 1


@pytest.fixture(scope="module")
def rollout():
    """(env, agent config, a stock runner whose storage holds one 24-step rollout with returns)."""
    task = load_task("base", overrides={"scene": {"num_workers": 0}})
    env = LocomotionEnv(task, num_envs=8, seed=0, verbose=False)
    cfg = runner_config(task.data["agent"], seed=0)
    torch.manual_seed(0)
    stock = OnPolicyRunner(env, copy.deepcopy(cfg), log_dir=None)
    obs = env.get_observations()
    with torch.inference_mode():
        for _ in range(cfg["num_steps_per_env"]):
            obs, rewards, dones, extras = env.step(stock.alg.act(obs))
            stock.alg.process_env_step(obs, rewards, dones, extras)
        stock.alg.compute_returns(obs)
    yield env, cfg, stock
    env.close()


@pytest.mark.parametrize("threads", [0, 2])
def test_one_update_equals_rsl_rl_stock_update(rollout, threads):
    """From the same weights, rollout and seed: the same losses, learning rate and weights (float tolerance:
    fused Adam and threaded matrix products sum in another order)."""
    env, cfg, stock_runner = rollout
    torch.manual_seed(0)
    fast = OnPolicyRunner(env, copy.deepcopy(cfg), log_dir=None).alg
    stock = copy.deepcopy(stock_runner.alg, memo={id(env): env})  # the fixture's stays as it is
    with torch.inference_mode():
        fast.storage = copy.deepcopy(stock.storage)
    speed_up_update(fast, threads=threads)
    assert isinstance(fast.symmetry, ReusedForwardSymmetry) and isinstance(fast.storage, ShuffleOnceStorage)
    assert fast.optimizer.defaults["fused"]
    for a, b in zip(stock.actor.parameters(), fast.actor.parameters(), strict=True):
        assert torch.equal(a, b)

    torch.manual_seed(7)
    want = stock.update()
    torch.manual_seed(7)
    got = fast.update()
    assert set(got) == set(want) == {"value", "surrogate", "entropy", "symmetry"}
    assert want["symmetry"] > 0.0  # the logged mirror loss is there to compare
    for key in want:
        assert got[key] == pytest.approx(want[key], rel=1e-4, abs=1e-7), key
    assert fast.learning_rate == stock.learning_rate
    for part in ("actor", "critic"):  # weights, action std and the observation normaliser's statistics
        want_sd, got_sd = getattr(stock, part).state_dict(), getattr(fast, part).state_dict()
        for name, value in want_sd.items():
            torch.testing.assert_close(got_sd[name], value, rtol=1e-4, atol=1e-6, msg=f"{part} {name}")
    before = stock_runner.alg.critic.state_dict()["mlp.0.weight"]
    assert float((stock.critic.state_dict()["mlp.0.weight"] - before).abs().max()) > 1e-4  # weights did move


def test_mixed_precision_reaches_the_fast_update(rollout):
    """rsl-rl's ``use_mixed_precision`` (bf16 autocast; `make bench-ppo BENCH_PPO_ARGS="--variants fast fast_bf16"`)
    is honoured by the fast update: its losses match the stock bf16 update's and differ from the float32 update's."""
    env, cfg, stock_runner = rollout
    losses = {}
    for name, mixed, fast in (("fp32", False, False), ("stock_bf16", True, False), ("fast_bf16", True, True)):
        torch.manual_seed(0)
        alg = OnPolicyRunner(env, copy.deepcopy(cfg), log_dir=None).alg
        with torch.inference_mode():
            alg.storage = copy.deepcopy(stock_runner.alg.storage)
        if fast:
            speed_up_update(alg, threads=0)
        alg.use_mixed_precision = mixed
        torch.manual_seed(7)
        losses[name] = alg.update()
    for key in ("value", "surrogate", "entropy"):
        assert losses["fast_bf16"][key] == pytest.approx(losses["stock_bf16"][key], rel=1e-2, abs=1e-4), key
    assert losses["stock_bf16"]["value"] != losses["fp32"]["value"]  # bf16 rounding did take part
    # same magnitude, not the same numbers: bf16 keeps ~3 digits of the values, and the value loss is a
    # square of small differences of them (here 0.052 vs 0.040 after one update)
    assert losses["stock_bf16"]["value"] == pytest.approx(losses["fp32"]["value"], rel=0.5)

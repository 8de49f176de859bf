"""The episode schedule: its hash against a pure-Python one, uniformity, independence of other robots,
and the env end to end (two controllers, same seed -> bit-identical commands, push timers and noise
of every episode, whenever their robots fall)."""

from __future__ import annotations

from pathlib import Path

import torch

from dls_quadruped.core.hashing import hash32
from dls_quadruped.envs.config import load_task
from dls_quadruped.envs.env import LocomotionEnv
from dls_quadruped.envs.schedule import EpisodeSchedule
from dls_quadruped.eval.policy import load_policy

POLICY = Path(__file__).resolve().parents[2] / "docs" / "policies" / "base_actor.pt"


def _hash32(x: int) -> int:
    """The same hash in Python integers mod 2**32 (the cross-check of the int64 torch version)."""
    x &= 0xFFFFFFFF
    x ^= x >> 16
    x = (x * 0x7FEB352D) & 0xFFFFFFFF
    x ^= x >> 15
    x = (x * 0x1B873593) & 0xFFFFFFFF
    x ^= x >> 16
    x = (x * 0x5BD1E995) & 0xFFFFFFFF
    return x ^ (x >> 13)


def test_hash_matches_pure_python():
    values = torch.randint(0, 2**40, (2000,), generator=torch.Generator().manual_seed(1))
    values = torch.cat([values, torch.tensor([0, 1, 2**32 - 1, 2**32, 0x7FEB352D])])
    got = hash32(values).tolist()
    assert got == [_hash32(int(v)) for v in values]
    assert _hash32(0) == 0 and got[-4] != 0  # 0 is the hash's fixed point; 1 is not


def test_uniform_draws_are_uniform_and_in_range():
    s = EpisodeSchedule(seed=7, num_envs=1000)
    u = torch.cat([s.uniform(torch.arange(1000), (10,)) for _ in range(10)]).flatten()  # 100 000 values
    assert u.min() >= 0.0 and u.max() < 1.0
    assert abs(float(u.mean()) - 0.5) < 0.005 and abs(float(u.var()) - 1 / 12) < 0.002
    counts = torch.histc(u, bins=20, min=0.0, max=1.0)
    assert float(((counts - 5000) ** 2 / 5000).sum()) < 60  # chi^2, 19 dof: p(> 60) ~ 4e-6
    v = s.uniform(torch.arange(1000), (), -2.0, 3.0)
    assert v.min() >= -2.0 and v.max() < 3.0
    k = s.integers(torch.arange(1000), 2, 5)
    assert set(k.tolist()) == {2, 3, 4}


def test_a_draw_depends_only_on_its_own_episode():
    ids = torch.arange(3)
    a = EpisodeSchedule(seed=3, num_envs=3, episode_keys=torch.tensor([0, 1, 0]))
    a.start_episodes(ids)
    first = a.uniform(ids, (4,), stream="command")
    assert torch.equal(first[0], first[2]) and not torch.equal(first[0], first[1])  # shared key, shared draws
    # env 1 falls twice and draws a lot in between; env 0's next draws do not notice
    for _ in range(2):
        a.start_episodes(torch.tensor([1]))
        a.uniform(torch.tensor([1]), (50,), stream="command")
    second = a.uniform(ids, (4,), stream="command")
    b = EpisodeSchedule(seed=3, num_envs=3, episode_keys=torch.tensor([0, 1, 0]))
    b.start_episodes(ids)
    b.uniform(ids, (4,), stream="command")
    assert torch.equal(second[0], b.uniform(ids, (4,), stream="command")[0])
    # another stream, another seed or the next episode give other numbers
    assert not torch.equal(second[0], a.uniform(ids, (4,), stream="push_robot")[0])
    c = EpisodeSchedule(seed=4, num_envs=3, episode_keys=torch.tensor([0, 1, 0]))
    c.start_episodes(ids)
    assert not torch.equal(first[0], c.uniform(ids, (4,), stream="command")[0])
    a.start_episodes(torch.tensor([0]))
    assert not torch.equal(first[0], a.uniform(torch.tensor([0]), (4,), stream="command")[0])


def test_state_dict_round_trip_continues_the_stream():
    a = EpisodeSchedule(seed=5, num_envs=4)
    a.start_episodes(torch.arange(4))
    a.uniform(torch.arange(4), (2,), stream="x")
    b = EpisodeSchedule(seed=0, num_envs=4)
    b.load_state_dict(a.state_dict())
    assert torch.equal(a.uniform(torch.arange(4), (3,), stream="x"), b.uniform(torch.arange(4), (3,), stream="x"))


def test_bad_episode_keys_are_refused():
    import pytest

    with pytest.raises(ValueError, match="episode_keys must be 3 non-negative integers"):
        EpisodeSchedule(seed=0, num_envs=3, episode_keys=torch.tensor([0, 1]))
    with pytest.raises(ValueError, match="non-negative"):
        EpisodeSchedule(seed=0, num_envs=3, episode_keys=torch.tensor([0, -1, 2]))


def test_compile_set_after_the_first_draws_applies_from_the_next_draw():
    """The env sets ``compile`` once its scene is built, after the terrain has drawn: the draws made after that are
    compiled (no trace here: a dynamic function's first call runs eagerly), and the numbers are the eager ones."""
    s, eager = EpisodeSchedule(seed=2, num_envs=4), EpisodeSchedule(seed=2, num_envs=4)
    ids = torch.arange(4)
    for x in (s, eager):
        x.start_episodes(ids)
    assert torch.equal(s.uniform(ids, (2,), stream="x"), eager.uniform(ids, (2,), stream="x"))
    first = s._draw
    assert not first.compiled
    s.compile = True
    assert s._draw is not first and s._draw.compiled and s.compile
    assert torch.equal(s.uniform(ids, (2,), stream="x"), eager.uniform(ids, (2,), stream="x"))
    env = LocomotionEnv(load_task("base", overrides={"scene": {"backend": "cpu", "num_workers": 0,
                                                               "compile": True}}),
                        num_envs=2, seed=0, verbose=False)
    try:  # built without compiling (every first call eager), its schedule's draws compiled from now on
        assert env.schedule.compile and env.schedule._draw.compiled
    finally:
        env.close()


# ---------------------------------------------------------------------------- the env end to end
SMALL_ROUGH = {"scene": {"num_workers": 0},
               "terrain": { "num_rows": 3, "tile_size": 4.0, "border": 1.0, "platform": 1.0},
               # resample commands and push often, so both happen many times in 60 steps
               "commands": {"base_velocity": {"resampling_time_s": [0.2, 0.4]}},
               "events": {"push": {"interval_s": [0.1, 0.3], "params": {"velocity_range": [-0.05, 0.05]}}}}
STEPS = 60
COLLAPSE = torch.tensor([0.0] * 8 + [0.0] * 8 + [0.0, 0.0, -20.0] * 4)
"""Raw latent action with F_z clipped to 0 on every leg: the robot is not carried and falls."""


def _run(collapse: list[int]) -> dict:
    """Rough task, 4 robots walked by the base expert except ``collapse`` robots (not carried); per step
    and env: command, push timer, and whether the env was still in its first episode."""
    env = LocomotionEnv(load_task("rough", overrides=SMALL_ROUGH), num_envs=4, seed=11, verbose=False)
    try:
        policy = load_policy(POLICY, env)
        obs = env.get_observations()
        first = torch.ones(4, dtype=torch.bool)
        cmd, timer, first_ep, ended = [], [], [], torch.full((4,), STEPS)
        for k in range(STEPS):
            with torch.no_grad():
                act = policy(obs)
            act[collapse] = COLLAPSE
            obs, _, dones, _ = env.step(act)
            done = dones.bool()
            ended = torch.where(first & done, torch.full_like(ended, k), ended)
            first &= ~done
            cmd.append(env.command_manager.command.clone())
            timer.append(env.event_manager.timers["push"].clone())
            first_ep.append(first.clone())
        return {"cmd": torch.stack(cmd), "timer": torch.stack(timer), "first": torch.stack(first_ep), "ended": ended}
    finally:
        env.close()


def test_two_controllers_see_bit_identical_episodes_whatever_falls():
    a = _run(collapse=[])
    b = _run(collapse=[2, 3])
    # robots 2 and 3 fall under b, and earlier than under a: their resets draw from the schedule
    # while robots 0 and 1 are still in their first episode under both controllers
    fell_b = int(b["ended"][2:].max())
    assert (b["ended"][2:] < a["ended"][2:]).all() and fell_b < STEPS // 2
    assert (a["ended"][:2] > fell_b + 10).all() and (b["ended"][:2] > fell_b + 10).all()
    for e in range(4):  # every robot: commands and push timers identical, bit for bit, while both play episode 0
        both = a["first"][:, e] & b["first"][:, e]
        assert both.sum() > 5
        assert torch.equal(a["cmd"][both, e], b["cmd"][both, e])
        assert torch.equal(a["timer"][both, e], b["timer"][both, e])
    # the commands do change during the run (resampled), so the equality is not one of constants
    assert int((a["cmd"][1:] != a["cmd"][:-1]).any(dim=-1).sum()) >= 8  # resamples, over the four robots


def test_reset_with_seed_replays_the_schedule_and_keys_share_episodes():
    env = LocomotionEnv(load_task("rough", overrides=SMALL_ROUGH), num_envs=4, seed=2, verbose=False)
    try:
        def trace():
            out = []
            for _ in range(15):
                obs, _, _, _ = env.step(torch.zeros(4, 28))
                out.append(torch.cat([env.command_manager.command, obs["policy"]], dim=-1).clone())
            return torch.stack(out)

        obs0 = env.reset(seed=9)[0]["policy"].clone()
        t1 = trace()
        assert torch.equal(env.reset(seed=9)[0]["policy"], obs0)
        assert torch.equal(trace(), t1)  # the same episodes, noise included
        keys = torch.tensor([0, 1, 0, 1])
        obs = env.reset(seed=9, episode_keys=keys)[0]["policy"]
        assert torch.equal(obs[2], obs[0]) and torch.equal(obs[3], obs[1])  # same tile, pose, command, noise
        assert torch.equal(obs[0], obs0[0])
        t = trace()
        assert torch.equal(t[:, 2], t[:, 0]) and torch.equal(t[:, 3], t[:, 1])  # the same episodes played twice
        fresh = LocomotionEnv(load_task("rough", overrides=SMALL_ROUGH), num_envs=4, seed=9, verbose=False)
        try:  # reset(seed=9) leaves the env as a fresh one built with seed 9
            assert torch.equal(fresh.get_observations()["policy"], obs0)
        finally:
            fresh.close()
    finally:
        env.close()

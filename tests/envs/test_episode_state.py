"""The episodes in progress survive a checkpoint: an env loaded from ``state_dict()`` steps exactly as the
saved one goes on to (mid-episode, through resets), whatever the simulator's worker count."""

from __future__ import annotations

import io

import pytest
import torch

from dls_quadruped.envs.config import load_task
from dls_quadruped.envs.env import LocomotionEnv


def _env(workers: int) -> LocomotionEnv:
    task = load_task("rough", overrides={"scene": {"num_workers": workers}})  # pushes, wrenches, terrain
    return LocomotionEnv(task, num_envs=6, seed=3, verbose=False)


def _roundtrip(state: dict) -> dict:
    buf = io.BytesIO()
    torch.save(state, buf)
    return torch.load(io.BytesIO(buf.getvalue()), weights_only=False)


@pytest.mark.parametrize("workers_saved, workers_loaded", [(0, 0), pytest.param(2, 0, marks=pytest.mark.slow)])
def test_loaded_env_steps_as_the_saved_one_goes_on(workers_saved, workers_loaded):
    gen = torch.Generator().manual_seed(0)
    env = _env(workers_saved)
    actions = [torch.randn(env.num_envs, env.num_actions, generator=gen) for _ in range(60)]
    try:
        for a in actions[:30]:
            env.step(a)
        state = _roundtrip(env.state_dict())
        want = [(*(o[k].clone() for k in sorted(o.keys())), r.clone(), d.clone())
                for o, r, d, _ in map(env.step, actions[30:])]
    finally:
        env.close()
    assert sum(int(w[-1].sum()) for w in want) > 0  # robots were reset in between

    for drop_episodes in (False, True):
        env = _env(workers_loaded)
        try:
            saved = _roundtrip(state)
            if drop_episodes:  # the old checkpoint: every robot restarts its episode -> not the same run
                del saved["episodes"]
            env.load_state_dict(saved)
            got = [(*(o[k].clone() for k in sorted(o.keys())), r.clone(), d.clone())
                   for o, r, d, _ in map(env.step, actions[30:])]
        finally:
            env.close()
        same = all(torch.equal(x, y) for w, g in zip(want, got) for x, y in zip(w, g))
        assert same != drop_episodes


@pytest.mark.slow  # default suite under 10 min on 2 cores (make test-all runs it)
def test_episode_state_of_another_number_of_robots_falls_back_to_fresh_episodes():
    env = _env(0)
    state = _roundtrip(env.state_dict())
    env.close()
    other = LocomotionEnv(load_task("rough", overrides={"scene": {"num_workers": 0}}), num_envs=4, seed=3,
                          verbose=False)
    try:
        other.load_state_dict(state)  # levels cycled, every robot in a new episode (as before)
        assert bool((other.episode_length_buf == 0).all())
    finally:
        other.close()

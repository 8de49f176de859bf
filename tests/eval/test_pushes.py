"""The pushes scenario: the simple task's evaluation env plus one scheduled push event."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from dls_quadruped.eval.pushes import PUSH_INTERVAL_S, pushes_task
from dls_quadruped.eval.velocity_tracking import (
    TaskEvalOptions,
    flat_task,
    simple_commands,
)

OPTS = TaskEvalOptions(episodes=4, seed=0, num_workers=0, episode_length_s=6.0)


def test_pushes_task_is_the_flat_task_plus_one_push_event():
    cmd = simple_commands(4, 0)
    flat, pushed = flat_task(cmd, OPTS), pushes_task(cmd, OPTS, 1.5)
    assert set(pushed.data["events"]) == set(flat.data["events"]) | {"push"}
    push = pushed.data["events"]["push"]
    assert push["func"] == "push_robot" and push["mode"] == "interval"
    assert push["interval_s"] == list(PUSH_INTERVAL_S) and push["params"]["velocity_range"] == [-1.5, 1.5]
    for section in ("terrain", "observations", "commands", "rewards", "curriculum"):
        assert pushed.data[section] == flat.data[section], section


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf"), "1", True, None])
def test_a_bad_push_speed_is_refused_naming_what_is_allowed(bad):
    with pytest.raises(ValueError, match=r"push speed must be a finite number > 0 \[m/s\]"):
        pushes_task(simple_commands(4, 0), OPTS, bad)


def test_a_bad_push_interval_is_refused():
    with pytest.raises(ValueError, match="push interval"):
        pushes_task(simple_commands(4, 0), OPTS, 1.0, interval_s=(5.0, 4.0))


def test_the_pushes_change_the_base_velocity_in_the_closed_loop_env():
    """The base expert walking for 6 s: with pushes of up to 3 m/s the base's horizontal speed jumps by more
    than 0.5 m/s in one step at least once per robot (the first push comes within 4-6 s; a draw below 0.5 m/s
    on both axes has probability 1/36 per robot, none for these seeded episodes), and in the same episodes
    without pushes it never does."""
    from dls_quadruped.closed_loop.episodes import DEFAULT_POLICY, commands, make_env
    from dls_quadruped.eval.policy import load_policy

    cmds = commands(2, 0, None)
    jumps = {}
    for name, kw in (("pushes", {"push_speed": 3.0}), ("simple", {})):
        env = make_env(cmds, 6.0, 0, 0, scenario=name, **kw)
        try:
            policy = load_policy(DEFAULT_POLICY, env)
            obs = env.get_observations()
            prev = env.state.base_lin_vel_w[:, :2].clone()
            biggest = torch.zeros(env.num_envs)
            for _ in range(int(6.0 / env.step_dt) - 1):
                with torch.inference_mode():
                    obs = env.step(policy(obs))[0]
                v = env.state.base_lin_vel_w[:, :2]
                biggest = torch.maximum(biggest, (v - prev).norm(dim=-1))
                prev = v.clone()
            jumps[name] = biggest.numpy()
        finally:
            env.close()
    assert np.all(jumps["pushes"] > 0.5), jumps
    assert np.all(jumps["simple"] < 0.5), jumps


def test_make_env_refuses_a_push_speed_outside_the_pushes_scenario():
    from dls_quadruped.closed_loop.episodes import commands, make_env

    with pytest.raises(ValueError, match="push speed goes with the pushes scenario"):
        make_env(commands(2, 0, None), 1.0, 0, 0, scenario="simple", push_speed=1.0)
    with pytest.raises(ValueError, match="push speed goes with the pushes scenario"):
        make_env(commands(2, 0, None), 1.0, 0, 0, scenario="pushes")


def test_closed_loop_cli_needs_push_speed_with_pushes_only(one_line_error):
    from dls_quadruped.closed_loop.__main__ import main

    line = one_line_error(main, ["--scenario", "pushes", "--episodes", "2"])
    assert "--push-speed" in line and "needed by --scenario pushes" in line
    line = one_line_error(main, ["--push-speed", "1.0", "--episodes", "2"])
    assert "--push-speed" in line and "got --scenario simple" in line

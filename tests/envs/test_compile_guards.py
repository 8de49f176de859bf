"""Compiled env code and numpy: a numpy value read inside a compiled function becomes a graph input rebuilt on the
host every call, and under ``torch.inference_mode`` (how rsl-rl collects rollouts) dynamo's guard on it fails
("Guard failed on the same frame it was created ... dispatch key set mismatch"), which stopped the first PPO run
on a GPU. The terms' defaults and the constants they read are Python numbers; the slow test runs the compiled
managers under inference mode on the CPU, as training on a GPU does.
"""

from __future__ import annotations

import importlib
import inspect

import numpy as np
import pytest
import torch

MDP = ("observations", "rewards", "terminations", "events", "commands", "curriculum", "kernels")


def _numpy_in(value) -> bool:
    if isinstance(value, (np.generic, np.ndarray)):
        return True
    return isinstance(value, (tuple, list)) and any(_numpy_in(v) for v in value)


@pytest.mark.parametrize("module", MDP)
def test_no_term_default_is_a_numpy_value(module):
    mod = importlib.import_module(f"dls_quadruped.envs.mdp.{module}")
    found = [f"{name}({p.name}={p.default!r})" for name, f in vars(mod).items() if inspect.isfunction(f)
             for p in inspect.signature(f).parameters.values() if _numpy_in(p.default)]
    assert found == []


def test_constants_read_by_compiled_code_are_python_numbers():
    from dls_quadruped.envs.mdp import events, observations, rewards
    from dls_quadruped.robots.aliengo import constants as C

    tables = {**events._CONSTANTS, "JOINT_RANGES": rewards._JOINT_RANGES,
              "NOMINAL_JOINT_POS": observations._NOMINAL_JOINT_POS}
    assert not any(_numpy_in(v) for v in tables.values())
    # the same numbers: a Python float holds a float64 exactly
    assert np.array_equal(np.asarray(tables["JOINT_RANGES"]), C.JOINT_RANGES)
    assert np.array_equal(np.asarray(tables["THIGH_Y"]), C.LEG_Y_SIGN * C.THIGH_OFFSET_Y)


@pytest.mark.slow
def test_compiled_managers_run_under_inference_mode():
    """The env with ``scene.compile: true`` on the CPU backend, stepped under inference mode with resets (episodes
    of 0.3 s): every compiled function runs compiled (none fell back to eager) and nothing raises. Before the
    constants were Python numbers this raised dynamo's guard AssertionError on the first reward computation."""
    from dls_quadruped.envs.config import load_task
    from dls_quadruped.envs.env import LocomotionEnv
    from dls_quadruped.envs.mdp.events import _placement

    env = LocomotionEnv(load_task("base", overrides={"env": {"episode_length_s": 0.3},
                                                     "scene": {"backend": "cpu", "num_workers": 0, "compile": True}}),
                        num_envs=4, seed=0, verbose=False)
    try:
        g = torch.Generator().manual_seed(0)
        resets = 0
        with torch.inference_mode():
            for _ in range(20):
                _, _, done, _ = env.step(torch.randn(4, 28, generator=g))
                resets += int(done.sum())
        assert resets > 0
        fused = (env.reward_manager._compute, env.observation_manager._groups, env.termination_manager._compute,
                 env.action_manager._convert, env.fused(_placement), env.schedule._draw)
        assert all(f.compiled for f in fused)
        # a curriculum switching a weight on, or widening a command range, writes into tensors the compiled code
        # reads: no recompile
        from torch._dynamo.utils import counters

        graphs = counters["stats"]["unique_graphs"]
        env.reward_manager.weights["action_rate"] = -1.0
        env.command_manager.params["ang_vel_z"] = [-0.5, 0.5]  # as the speed curriculum widens a range
        with torch.inference_mode():
            for _ in range(3):
                env.step(torch.randn(4, 28, generator=g))
        assert counters["stats"]["unique_graphs"] == graphs
        assert env.command_manager._ranges["ang_vel_z"].tolist() == [-0.5, 0.5]
        assert env.reward_manager.step_reward[:, env.reward_manager.weights.index["action_rate"]].ne(0).any()
    finally:
        env.close()

"""Each manager owns its checkpoint state (``ManagerBase.state_dict`` / ``load_state_dict``), and the env's
``state_dict()`` is assembled from those parts in its fixed format."""

from __future__ import annotations

import pytest
import torch

from dls_quadruped.envs.config import load_task
from dls_quadruped.envs.env import LocomotionEnv
from dls_quadruped.envs.managers.base import ManagerBase

ENV_KEYS = ["curriculum_state", "curriculum_values", "reward_weights", "command_params", "terrain_levels",
            "common_step_counter", "schedule", "rng_cpu", "episodes"]
"""The keys of ``LocomotionEnv.state_dict()`` on the CPU, in order: what every saved checkpoint holds."""


def _env(num_envs: int = 3, seed: int = 0) -> LocomotionEnv:
    task = load_task("rough", overrides={"scene": {"num_workers": 0}})  # a terrain curriculum and several rows
    return LocomotionEnv(task, num_envs=num_envs, seed=seed, verbose=False)


@pytest.fixture(scope="module")
def envs():
    a, b = _env(), _env()
    yield a, b
    a.close()
    b.close()


def _managers(env: LocomotionEnv) -> dict[str, ManagerBase]:
    return {name: getattr(env, name) for name in ("scene", "action_manager", "command_manager", "reward_manager",
                                                  "termination_manager", "event_manager", "curriculum_manager",
                                                  "observation_manager")}


def test_every_manager_shares_the_lifecycle(envs):
    for name, manager in _managers(envs[0]).items():
        assert isinstance(manager, ManagerBase), name
        assert callable(manager.reset) and callable(manager.state_dict) and callable(manager.load_state_dict)
    # managers whose state ends with the episode carry nothing across a checkpoint
    for name in ("action_manager", "termination_manager", "event_manager", "observation_manager"):
        assert _managers(envs[0])[name].state_dict() == {}, name


def test_reward_weights_round_trip(envs):
    src, dst = (e.reward_manager for e in envs)
    name = next(iter(src.weights))
    src.weights[name] = 123.5
    state = src.state_dict()
    src.weights[name] = -1.0  # the saved part is a copy
    dst.load_state_dict(state)
    assert dst.weights[name] == 123.5 and set(dst.weights) == set(src.weights)


def test_command_params_round_trip_in_place(envs):
    src, dst = (e.command_manager for e in envs)
    held = dst.params
    assert held is dst.term.params  # the command term reads this very dict
    key = next(iter(src.params))
    src.params[key] = [0.25, 0.5] if isinstance(src.params[key], (list, tuple)) else 0.375
    state = src.state_dict()
    dst.load_state_dict(state)
    assert dst.params is held and dst.term.params == src.params
    state["params"][key] = "changed"  # loaded as a copy
    assert dst.params[key] != "changed"


def test_curriculum_state_round_trip(envs):
    src, dst = (e.curriculum_manager for e in envs)
    src.state["probe"] = {"enabled": True, "targets": {"a": 1.0}}
    src.values["probe"] = 0.75
    state = src.state_dict()
    dst.load_state_dict(state)
    assert dst.state["probe"] == {"enabled": True, "targets": {"a": 1.0}} and dst.values["probe"] == 0.75
    state["state"]["probe"]["enabled"] = False
    assert dst.state["probe"]["enabled"] is True
    del src.state["probe"], src.values["probe"]
    dst.load_state_dict(src.state_dict())
    assert "probe" not in dst.state  # the state is replaced, not merged (the values are: each term sets its own)
    del dst.values["probe"]


def test_terrain_levels_round_trip_and_cycle_over_another_count(envs):
    src, dst = (e.scene for e in envs)
    rows = src.terrain.num_rows
    levels = torch.tensor([rows - 1, 1, 0]) % rows
    src.update_levels(torch.arange(3), levels - src.terrain_levels)
    dst.load_state_dict(src.state_dict())
    assert torch.equal(dst.terrain_levels.cpu(), levels)
    assert torch.equal(dst.env_origins, dst.tile_origins[dst.terrain_levels, dst.terrain_types])
    dst.load_state_dict({"terrain_levels": torch.tensor([2, 0]) % rows})  # saved by 2 robots: cycled
    assert dst.terrain_levels.tolist() == [2 % rows, 0, 2 % rows]


def test_a_mismatched_part_is_refused_before_anything_is_written(envs):
    env = envs[1]
    state = env.state_dict()
    weights_before = dict(env.reward_manager.weights)
    state["reward_weights"] = {**state["reward_weights"], "fly": 1.0}
    with pytest.raises(ValueError, match=r"checkpoint reward terms .*'fly'.* != task's"):
        env.load_state_dict(state)
    state = env.state_dict()
    state["reward_weights"] = {k: 7.0 for k in state["reward_weights"]}
    state["command_params"] = {"bogus": 1}
    with pytest.raises(ValueError, match=r"checkpoint command parameters \['bogus'\] != task's"):
        env.load_state_dict(state)
    assert env.reward_manager.weights == weights_before  # the valid reward part was not loaded either


def test_env_state_dict_keeps_its_format_and_round_trips(envs):
    src, dst = envs
    for _ in range(2):
        src.step(torch.zeros(src.num_envs, src.num_actions))
    src.reward_manager.weights[next(iter(src.reward_manager.weights))] = 0.5
    state = src.state_dict()
    assert list(state) == ENV_KEYS
    assert state["reward_weights"] == src.reward_manager.weights
    assert state["terrain_levels"].device.type == "cpu" and state["terrain_levels"].dtype == torch.long
    dst.load_state_dict(state)
    again = dst.state_dict()
    for key in ("curriculum_state", "curriculum_values", "reward_weights", "command_params", "common_step_counter"):
        assert again[key] == state[key], key
    assert torch.equal(again["terrain_levels"], state["terrain_levels"])

"""The written agent schema (``envs/agent_config.py``) holds to the installed rsl-rl-lib: its extension and popped
keys agree with the classes' signatures, and every key rsl-rl's ``construct_algorithm`` and its extensions' resolvers
read from or write into the agent dict, recorded while they run, is one the schema knows."""

from __future__ import annotations

import copy
import inspect
from types import SimpleNamespace

import pytest
import torch
from tensordict import TensorDict

from dls_quadruped.envs.agent_config import (
    INJECTED,
    PROJECT_KEYS,
    RUNNER_KEYS,
    AlgorithmSchema,
    algorithm_schemas,
)


def _params(cls: type) -> set[str]:
    return set(list(inspect.signature(cls.__init__).parameters)[1:])


class _Recorded(dict):
    """A config mapping that notes, under ``prefix``, every key read from it (item, get, pop, in) in ``reads`` and
    every key written in ``writes``; its deep copies (rsl-rl's ``resolve_class``) record into the same sets."""

    def __init__(self, data: dict, prefix: str, reads: set, writes: set):
        super().__init__(data)
        self.prefix, self.reads, self.writes = prefix, reads, writes

    def __getitem__(self, key):
        self.reads.add(self.prefix + key)
        return super().__getitem__(key)

    def get(self, key, default=None):
        self.reads.add(self.prefix + key)
        return super().get(key, default)

    def pop(self, key, *default):
        self.reads.add(self.prefix + key)
        return super().pop(key, *default)

    def __contains__(self, key):
        self.reads.add(self.prefix + key)
        return super().__contains__(key)

    def __setitem__(self, key, value):
        self.writes.add(self.prefix + key)
        super().__setitem__(key, value)

    def __deepcopy__(self, memo):
        return _Recorded(copy.deepcopy(dict(self), memo), self.prefix, self.reads, self.writes)


def _allowed_top_level(schema: AlgorithmSchema) -> set[str]:
    return set(RUNNER_KEYS) | set(schema.models) | set(PROJECT_KEYS)


def test_the_schema_agrees_with_the_signatures() -> None:
    from rsl_rl.algorithms import PPO

    schemas = algorithm_schemas()
    assert PPO in schemas and next(iter(schemas)) is PPO  # the default without an algorithm is rsl-rl's PPO
    for alg, schema in schemas.items():
        params = _params(alg)
        assert INJECTED <= params, alg  # rsl-rl passes these to every algorithm
        assert not set(schema.popped) & params, alg  # popped before the call: not constructor arguments
        for cfg_name, (ext_cls, filled) in schema.extensions.items():
            assert cfg_name in params, (alg, cfg_name)  # the algorithm takes the extension's mapping
            assert filled < _params(ext_cls), (ext_cls, filled)  # rsl-rl fills in some, not all, parameters


@pytest.fixture
def ppo_inputs():
    """Two robots' observations (policy 5, critic 6 values) and an env stand-in with what
    ``PPO.construct_algorithm`` reads from it."""
    obs = TensorDict({"policy": torch.zeros(2, 5), "critic": torch.zeros(2, 6), "rnd": torch.zeros(2, 4)},
                     batch_size=[2])
    env = SimpleNamespace(num_envs=2, num_actions=3, unwrapped=SimpleNamespace(step_dt=0.02))
    return obs, env


def test_every_key_ppo_reads_is_in_the_schema(ppo_inputs) -> None:
    from rsl_rl.algorithms import PPO

    obs, env = ppo_inputs
    reads, writes = set(), set()
    model = {"class_name": "MLPModel", "hidden_dims": [8]}
    cfg = _Recorded({
        "algorithm": _Recorded({"class_name": "PPO"}, "algorithm.", reads, writes),
        "actor": {**model, "distribution_cfg": {"class_name": "GaussianDistribution"}}, "critic": model,
        "obs_groups": {"actor": ["policy"], "critic": ["critic"]}, "num_steps_per_env": 2, "multi_gpu": None,
    }, "", reads, writes)
    PPO.construct_algorithm(obs, env, cfg, "cpu")
    schema = algorithm_schemas()[PPO]
    top = {k for k in reads if "." not in k}
    assert top >= {"algorithm", "actor", "critic", "obs_groups", "num_steps_per_env", "multi_gpu"}  # it recorded
    assert top <= _allowed_top_level(schema), top - _allowed_top_level(schema)
    alg_keys = {k.removeprefix("algorithm.") for k in reads if k.startswith("algorithm.")}
    allowed_alg = {"class_name"} | (_params(PPO) - INJECTED) | set(schema.popped)
    assert alg_keys <= allowed_alg, alg_keys - allowed_alg
    assert set(schema.popped) <= alg_keys  # what the schema says rsl-rl pops, it still reads


def test_the_extension_resolvers_fill_in_what_the_schema_says(ppo_inputs) -> None:
    from rsl_rl.algorithms import PPO
    from rsl_rl.extensions import resolve_rnd_config, resolve_symmetry_config

    obs, env = ppo_inputs
    exts = algorithm_schemas()[PPO].extensions
    reads, writes = set(), set()
    sym = {"symmetry_cfg": _Recorded({"data_augmentation_func": "m:f"}, "", reads, writes)}
    resolve_symmetry_config(sym, env)
    rnd = {"rnd_cfg": _Recorded({"weight": 1.0}, "", reads, writes)}
    resolve_rnd_config(rnd, obs, {"rnd_state": ["rnd"]}, env)
    # the RND weight is rescaled by the step (read and written back), not filled in; the device is passed in the
    # call RandomNetworkDistillation(device=..., **rnd_cfg)
    assert writes - {"weight"} == set(exts["symmetry_cfg"][1]) | set(exts["rnd_cfg"][1]) - {"device"}
    assert "device" in _params(exts["rnd_cfg"][0])


"""Check a task's ``agent`` section against what rsl-rl-lib 5.x accepts, when the task loads.

rsl-rl-lib has no config classes: its runner reads a plain dict. What its classes take is read from their
signatures (``inspect.signature``); what its runner, logger and ``construct_algorithm`` read from the dict
around them is written here (:data:`RUNNER_KEYS`, :func:`algorithm_schemas`, ``tests/envs/test_agent_schema.py``
holds the schema to the installed rsl-rl). A typo fails with the file, the dotted key and the allowed keys
instead of deep inside rsl-rl three minutes later:

* top level: :data:`RUNNER_KEYS`, the model sections of the algorithm (``actor`` and ``critic`` for PPO) and
  ours (:data:`PROJECT_KEYS`);
* ``actor`` / ``critic`` (and their ``distribution_cfg``): ``class_name`` plus the constructor's keyword
  parameters with defaults (the others are passed by rsl-rl);
* ``algorithm``: ``class_name`` plus the algorithm's keyword parameters (less :data:`INJECTED`, which rsl-rl
  passes itself) plus what its ``construct_algorithm`` pops from it (:attr:`AlgorithmSchema.popped`);
* ``algorithm.<ext>_cfg``: the parameters of the extension class the algorithm builds from it
  (``Symmetry(**symmetry_cfg)``), less those rsl-rl fills in (``env``, ``device``, ...).

Values are type-checked against the constructors' annotations and the schema's types (``learning_rate: fast``
fails).
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from dls_quadruped.envs.config import TaskConfig
from dls_quadruped.envs.value_checks import type_hints, type_problem

PROJECT_KEYS: dict[str, Any] = {"max_iterations": int, "seed": int, "experiment_name": str}
"""Agent keys this project adds: PPO iterations of ``train``, the seed, a free-form name."""

INJECTED = {"device", "multi_gpu_cfg"}
"""Algorithm arguments rsl-rl passes itself (setting them in the task would clash)."""

POSITIVE_INTS = ("num_steps_per_env", "save_interval", "max_iterations", "num_learning_epochs", "num_mini_batches")
UNIT_INTERVAL = ("gamma", "lam")
POSITIVE = ("learning_rate", "clip_param")
NON_NEGATIVE = ("entropy_coef", "value_loss_coef")
SCHEDULES = ("adaptive", "fixed")
"""rsl-rl's PPO adapts the learning rate to ``desired_kl`` with ``adaptive``; any other string is silently fixed."""
STD_TYPES = ("scalar", "log")
CUDA_GRAPH_COMPILE_MODES = ("reduce-overhead", "max-autotune")
"""``torch_compile_mode`` values rsl-rl refuses once the env is built (CUDA graphs clash with its algorithms)."""

RUNNER_KEYS: dict[str, Any] = {
    "num_steps_per_env": int, "save_interval": int, "check_for_nan": bool, "obs_groups": dict[str, list[str]],
    "logger": str | dict, "run_name": str, "wandb_project": str, "neptune_project": str,
    "torch_compile_mode": str | None, "multi_gpu": dict | None, "algorithm": Any}
"""Top-level agent keys rsl-rl-lib 5.x's ``OnPolicyRunner``, its ``Logger`` and every algorithm's
``construct_algorithm`` read, with their types (``algorithm`` is checked on its own). ``multi_gpu`` is written by
the runner itself; a resolved task saved after the runner was built carries it."""


@dataclass(frozen=True)
class AlgorithmSchema:
    """What an rsl-rl algorithm's ``construct_algorithm`` reads from the agent section beyond the constructor's
    keywords.

    Attributes:
        models: the top-level sections it builds a model from (``class_name`` plus constructor keywords).
        popped: ``algorithm`` keys it takes out before calling the constructor, with their types.
        extensions: ``algorithm.<ext>_cfg`` -> (the extension class it builds from that mapping, the
            constructor's parameters rsl-rl fills in itself).
    """

    models: tuple[str, ...]
    popped: dict[str, Any] = field(default_factory=dict)
    extensions: dict[str, tuple[type, frozenset[str]]] = field(default_factory=dict)


def algorithm_schemas() -> dict[type, AlgorithmSchema]:
    """rsl-rl-lib 5.x's algorithms and their schemas; a subclass takes its nearest listed base's."""
    from rsl_rl.algorithms import PPO, Distillation
    from rsl_rl.extensions import RandomNetworkDistillation, Symmetry

    return {
        PPO: AlgorithmSchema(
            models=("actor", "critic"), popped={"share_cnn_encoders": bool},
            # RandomNetworkDistillation(device=..., **rnd_cfg) after resolve_rnd_config adds the state size and
            # the observation groups; Symmetry(**symmetry_cfg) after resolve_symmetry_config adds the env
            extensions={"rnd_cfg": (RandomNetworkDistillation, frozenset({"device", "num_states", "obs_groups"})),
                        "symmetry_cfg": (Symmetry, frozenset({"env"}))}),
        Distillation: AlgorithmSchema(models=("student", "teacher")),
    }


def _schema(task: TaskConfig, spec: Any, alg_cls: Callable | None) -> AlgorithmSchema:
    """The schema of ``alg_cls`` (None: no algorithm given, rsl-rl's PPO)."""
    schemas = algorithm_schemas()
    if alg_cls is None:
        return next(iter(schemas.values()))
    for base in getattr(alg_cls, "__mro__", ()):
        if base in schemas:
            return schemas[base]
    raise task.error("agent.algorithm.class_name", f"{spec['class_name']!r} is not an rsl-rl algorithm this "
                     f"project knows the agent keys of; allowed: {[c.__name__ for c in schemas]} or a subclass "
                     f"('module:Class')")


def _resolve(task: TaskConfig, key: str, spec: Any) -> Callable:
    from rsl_rl.utils import resolve_callable

    if not isinstance(spec, dict) or "class_name" not in spec:
        raise task.error(key, "must be a mapping with a 'class_name'")
    try:
        return resolve_callable(spec["class_name"])
    except (ImportError, AttributeError, ValueError, TypeError) as err:
        raise task.error(f"{key}.class_name", f"unknown class {spec['class_name']!r} ({err})") from None


def distribution_classes() -> list[str]:
    """The names of rsl-rl's action distributions (``rsl_rl.modules.distribution``)."""
    from rsl_rl.modules import distribution

    base = distribution.Distribution
    return sorted(n for n, c in vars(distribution).items()
                  if isinstance(c, type) and issubclass(c, base) and c is not base)


def _resolve_distribution(task: TaskConfig, key: str, spec: dict) -> Callable:
    """The distribution class of ``spec``; an unknown name or a class that is no distribution names the choices."""
    from rsl_rl.modules.distribution import Distribution

    allowed = f"allowed: {distribution_classes()} or 'module:Class' of a Distribution subclass"
    if "class_name" not in spec:
        raise task.error(key, f"must be a mapping with a 'class_name'; {allowed}")
    try:
        cls = _resolve(task, key, spec)
    except Exception:  # noqa: BLE001 - re-raised with the allowed names
        raise task.error(f"{key}.class_name", f"unknown distribution {spec['class_name']!r}; {allowed}") from None
    if not (isinstance(cls, type) and issubclass(cls, Distribution)):
        raise task.error(f"{key}.class_name", f"{spec['class_name']!r} is not an action distribution; {allowed}")
    return cls


def _check_keys(task: TaskConfig, key: str, spec: dict, allowed: dict[str, Any]) -> None:
    """Unknown keys and values that do not fit the annotations ``allowed`` maps them to."""
    for name, value in spec.items():
        if name not in allowed:
            raise task.error(f"{key}.{name}", f"unknown key; rsl-rl accepts: {sorted(allowed)}")
        problem = type_problem(value, allowed[name])
        if problem is None and name in POSITIVE_INTS and value < 1:
            problem = f"must be >= 1, got {value}"
        if problem is None and name in UNIT_INTERVAL and not 0.0 <= value <= 1.0:
            problem = f"must be in [0, 1], got {value}"
        if problem is None and name in POSITIVE and not value > 0.0:
            problem = f"must be > 0, got {value}"
        if problem is None and name in NON_NEGATIVE and not value >= 0.0:
            problem = f"must be >= 0 (0 switches the term off), got {value}"
        if problem is not None:
            raise task.error(f"{key}.{name}", problem)
        problem = _recipe_problem(name, value, spec)
        if problem is not None:
            raise task.error(f"{key}.{name}", problem)


def _pair(value: Any) -> tuple[float, float] | None:
    if isinstance(value, (list, tuple)) and len(value) == 2 and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
        return float(value[0]), float(value[1])
    return None


def _recipe_problem(name: str, value: Any, spec: dict) -> str | None:
    """Range checks of the PPO recipe options whose types already passed (None: fine).

    rsl-rl accepts these silently and trains something else: an unknown ``schedule`` is a fixed learning
    rate, ``std_range`` is a clamp (inverted, every std is its upper end), ``init_std`` outside it is
    clamped at the first sample.
    """
    if name == "torch_compile_mode" and value in CUDA_GRAPH_COMPILE_MODES:
        return (f"{value!r} uses CUDA graphs, which rsl-rl refuses; allowed: 'default', "
                f"'max-autotune-no-cudagraphs' or null (no compile)")
    if name == "desired_kl" and value is not None and not value > 0.0:
        return f"must be > 0 (or null with schedule: fixed), got {value}"
    if name == "schedule" and value not in SCHEDULES:
        return f"must be one of {list(SCHEDULES)}, got {value!r}"
    if name == "std_type" and value not in STD_TYPES:
        return f"must be one of {list(STD_TYPES)}, got {value!r}"
    if name == "std_range":
        pair = _pair(value)
        if pair is None:
            return f"must be [min, max], two numbers, got {value!r}"
        if not 0.0 < pair[0] < pair[1]:
            return f"must be [min, max] with 0 < min < max, got {list(value)}"
    if name == "init_std":
        if not value > 0.0:
            return f"must be > 0, got {value}"
        pair = _pair(spec.get("std_range"))
        if pair is not None and 0.0 < pair[0] < pair[1] and not pair[0] <= value <= pair[1]:
            return f"must lie in std_range {list(spec['std_range'])} (rsl-rl would clamp it), got {value}"
    if name == "action_range":
        pair = _pair(value)
        if pair is None or not pair[0] < pair[1]:
            return f"must be [min, max] with min < max, got {value!r}"
    return None


def _keyword_params(cls: Callable, with_default_only: bool, exclude: set[str]) -> dict[str, Any]:
    hints = type_hints(cls.__init__)
    params = list(inspect.signature(cls.__init__).parameters.values())[1:]  # drop self
    return {p.name: hints.get(p.name, Any) for p in params
            if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY) and p.name not in exclude
            and (p.default is not p.empty or not with_default_only)}


def _check_model(task: TaskConfig, key: str, spec: Any) -> None:
    cls = _resolve(task, key, spec)
    allowed = {"class_name": str, **_keyword_params(cls, True, set())}
    _check_keys(task, key, spec, allowed)
    if isinstance(spec.get("distribution_cfg"), dict):
        dist = _resolve_distribution(task, f"{key}.distribution_cfg", spec["distribution_cfg"])
        _check_keys(task, f"{key}.distribution_cfg", spec["distribution_cfg"],
                    {"class_name": str, **_keyword_params(dist, True, set())})


def _check_algorithm(task: TaskConfig, spec: Any, schema: AlgorithmSchema) -> None:
    cls = _resolve(task, "agent.algorithm", spec)
    allowed = {"class_name": str, **_keyword_params(cls, True, INJECTED), **schema.popped}
    _check_keys(task, "agent.algorithm", spec, allowed)
    for cfg_name, (ext_cls, filled) in schema.extensions.items():
        ext = spec.get(cfg_name)
        if isinstance(ext, dict):
            _check_keys(task, f"agent.algorithm.{cfg_name}", ext, _keyword_params(ext_cls, False, set(filled)))


def check_agent_section(task: TaskConfig) -> None:
    """Check ``task.data["agent"]`` (if present); raises ``ConfigError`` naming the file and dotted key."""
    agent = task.data.get("agent")
    if agent is None:
        return
    if not isinstance(agent, dict):
        raise task.error("agent", "must be a mapping (rsl-rl OnPolicyRunner config)")
    alg_cls = _resolve(task, "agent.algorithm", agent["algorithm"]) if "algorithm" in agent else None
    schema = _schema(task, agent.get("algorithm"), alg_cls)
    _check_keys(task, "agent", agent, RUNNER_KEYS | dict.fromkeys(schema.models, Any) | PROJECT_KEYS)
    for model in schema.models:
        if model in agent:
            _check_model(task, f"agent.{model}", agent[model])
    if "algorithm" in agent:
        _check_algorithm(task, agent["algorithm"], schema)

"""Check a task's ``agent`` section against what rsl-rl-lib accepts, when the task loads.

The allowed keys are read from rsl-rl itself, so an rsl-rl feature (e.g. the symmetry extension's
``algorithm.symmetry_cfg``) is accepted as soon as rsl-rl has it, and a typo fails with the file,
the dotted key and the allowed keys instead of deep inside rsl-rl three minutes later:

* top level: the keys the runner, its logger and the algorithm's ``construct_algorithm`` read from
  the train config (found in their source: ``cfg["key"]`` / ``cfg.get("key")``), plus ours
  (``PROJECT_KEYS``);
* ``actor`` / ``critic`` (and their ``distribution_cfg``): ``class_name`` plus the constructor's
  keyword parameters with defaults (the others are passed by rsl-rl);
* ``algorithm``: ``class_name`` plus the algorithm's keyword parameters (less ``INJECTED``, which
  rsl-rl passes itself) plus what ``construct_algorithm`` pops from it;
* ``algorithm.<ext>_cfg``: the parameters of the extension class the algorithm builds from it
  (``Symmetry(**symmetry_cfg)``), less those rsl-rl fills in (``env``, ``device``, ...).

Values are type-checked against the constructors' annotations (``learning_rate: fast`` fails).
Where rsl-rl's source cannot be read the key check is skipped rather than guessed.
"""

from __future__ import annotations

import inspect
import re
from collections.abc import Callable
from typing import Any

from dls_quadruped.envs.config import TaskConfig, type_hints, type_problem

PROJECT_KEYS: dict[str, Any] = {"max_iterations": int, "seed": int, "experiment_name": str}
"""Agent keys this project adds: PPO iterations of ``train``, the seed, a free-form name."""

INJECTED = {"device", "multi_gpu_cfg"}
"""Algorithm arguments rsl-rl passes itself (setting them in the task would clash)."""

POSITIVE_INTS = ("num_steps_per_env", "save_interval", "max_iterations", "num_learning_epochs", "num_mini_batches")
UNIT_INTERVAL = ("gamma", "lam")
POSITIVE = ("learning_rate", "clip_param")

_CFG_READ = re.compile(r"\bcfg(?:\[|\.get\()\s*[\"'](\w+)[\"']")
_POPPED = re.compile(r"alg_cfg\.pop\(\s*[\"'](\w+)[\"']")
_EXT_CALL = re.compile(r"(\w+)\(([^()]*)\*\*(\w+_cfg)\)")
_ASSIGNED = re.compile(r"\[\s*[\"'](\w+)[\"']\s*\]\s*=[^=]")


def _source(obj: Any) -> str:
    try:
        return inspect.getsource(obj)
    except (OSError, TypeError):
        return ""


def _resolve(task: TaskConfig, key: str, spec: Any) -> Callable:
    from rsl_rl.utils import resolve_callable

    if not isinstance(spec, dict) or "class_name" not in spec:
        raise task.error(key, "must be a mapping with a 'class_name'")
    try:
        return resolve_callable(spec["class_name"])
    except (ImportError, AttributeError, ValueError, TypeError) as err:
        raise task.error(f"{key}.class_name", f"unknown class {spec['class_name']!r} ({err})") from None


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
        if problem is not None:
            raise task.error(f"{key}.{name}", problem)


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
        dist = _resolve(task, f"{key}.distribution_cfg", spec["distribution_cfg"])
        _check_keys(task, f"{key}.distribution_cfg", spec["distribution_cfg"],
                    {"class_name": str, **_keyword_params(dist, True, set())})


def _extensions(alg_cls: Callable) -> dict[str, tuple[Callable, set[str]]]:
    """{``<ext>_cfg``: (extension class, keys rsl-rl fills in)} read from the algorithm's source."""
    module = inspect.getmodule(alg_cls)
    out = {}
    for cls_name, explicit, cfg_name in _EXT_CALL.findall(_source(alg_cls.__init__)):
        cls = getattr(module, cls_name, None)
        if cls is None:
            continue
        filled = set(re.findall(r"(\w+)\s*=", explicit))
        resolver = getattr(module, f"resolve_{cfg_name.removesuffix('_cfg')}_config", None)
        filled |= set(_ASSIGNED.findall(_source(resolver))) if resolver is not None else set()
        out[cfg_name] = (cls, filled)
    return out


def _check_algorithm(task: TaskConfig, spec: Any) -> None:
    cls = _resolve(task, "agent.algorithm", spec)
    popped = set(_POPPED.findall(_source(getattr(cls, "construct_algorithm", None))))
    allowed = {"class_name": str, **_keyword_params(cls, True, INJECTED), **dict.fromkeys(popped, Any)}
    _check_keys(task, "agent.algorithm", spec, allowed)
    for cfg_name, (ext_cls, filled) in _extensions(cls).items():
        ext = spec.get(cfg_name)
        if isinstance(ext, dict):
            _check_keys(task, f"agent.algorithm.{cfg_name}", ext, _keyword_params(ext_cls, False, filled))


def _top_level_keys(alg_cls: Callable | None) -> set[str]:
    from rsl_rl.runners import OnPolicyRunner
    from rsl_rl.utils.logger import Logger

    sources = [_source(OnPolicyRunner), _source(Logger)]
    if alg_cls is not None:
        sources.append(_source(getattr(alg_cls, "construct_algorithm", None)))
    return {k for src in sources for k in _CFG_READ.findall(src)}


def check_agent_section(task: TaskConfig) -> None:
    """Check ``task.data["agent"]`` (if present); raises ``ConfigError`` naming the file and dotted key."""
    agent = task.data.get("agent")
    if agent is None:
        return
    if not isinstance(agent, dict):
        raise task.error("agent", "must be a mapping (rsl-rl OnPolicyRunner config)")
    alg_cls = _resolve(task, "agent.algorithm", agent["algorithm"]) if "algorithm" in agent else None
    read = _top_level_keys(alg_cls)
    if read:  # rsl-rl's source is readable: check the top-level keys
        allowed = {k: Any for k in read} | PROJECT_KEYS | {
            "num_steps_per_env": int, "save_interval": int, "check_for_nan": bool, "obs_groups": dict[str, list[str]],
            "logger": str | dict, "run_name": str}
        _check_keys(task, "agent", agent, {k: v for k, v in allowed.items() if k in read or k in PROJECT_KEYS})
    for model in ("actor", "critic"):
        if model in agent:
            _check_model(task, f"agent.{model}", agent[model])
    if "algorithm" in agent:
        _check_algorithm(task, agent["algorithm"])

"""Shared manager machinery: the lifecycle every manager shares (:class:`ManagerBase`), and the resolution of
YAML term entries to functions with their parameters checked.

A term entry in a task file looks like::

    rewards:
      track_lin_vel_xy:            # term name (free text, used in logs)
        func: track_lin_vel_xy_sek # function in the manager's mdp module; defaults to the term name
        weight: 1.5                # manager-specific keys (weight, noise, mode, ...)
        params: {sigma: 0.5}       # keyword arguments of the function, checked against its signature

The function's first parameter is the env; every other parameter without a default must appear in
``params`` and every key of ``params`` must be a parameter name, or building the env fails with
an error naming the file, the key and the allowed values.

Values are checked too (``load_task`` runs the same checks, so a bad file fails before anything is
built): each parameter against the function's annotation (``sigma: float`` refuses ``"wide"``,
``true`` and NaN), ``[low, high]`` pairs must be ordered, and the conventions of
``PARAM_RULES`` hold (a kernel width ``sigma`` is > 0, scales and fractions are >= 0). Manager keys
follow ``KEY_CHECKS``: ``weight`` a finite number (not a bool), ``noise`` >= 0, ``time_out`` a
bool, ``resampling_time_s`` / ``interval_s`` ordered non-negative ``[low, high]`` seconds.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from dataclasses import dataclass, field
from types import ModuleType
from typing import Any

import torch

from dls_quadruped.envs.config import TaskConfig
from dls_quadruped.envs.value_checks import interval_problem, type_hints, type_problem


class ManagerBase:
    """The lifecycle every manager of ``LocomotionEnv`` shares.

    A manager is built from the task with the env (``Manager(task, env)``), resolves its terms there (a bad task
    fails at build time), and then:

    * ``reset(env_ids)``: the episodes of ``env_ids`` ended; clear their per-episode buffers and return the
      episode logs (``{"Episode_Reward/<term>": 0-dim tensor, ...}``; none by default);
    * ``state_dict()`` / ``load_state_dict(state)``: what outlives an episode and a checkpoint carries (reward
      weights, command ranges, curriculum state, terrain levels; nothing by default). ``check_state_dict``
      raises before anything is written, so the env checks every manager's part before loading any. The
      per-robot buffers of the episodes in progress are not in here: ``envs/episode_state.py`` finds them;
    * ``summary()``: the table printed when the env starts.

    A manager's torch work that runs every step is a method decorated with ``core.compile.fused_method``: compiled
    when :attr:`compile` (the env's) says so, eager otherwise, written once.

    Args:
        env: the ``LocomotionEnv`` being built (its ``num_envs``, ``device``, ``schedule``, earlier managers).
    """

    def __init__(self, env) -> None:
        self.env = env

    @property
    def compile(self) -> bool:
        """Whether the manager's ``fused_method`` functions run compiled: the env's ``compile`` (``scene.compile``
        resolved for the env's device; False for a stand-in env without one)."""
        return getattr(self.env, "compile", False)

    def reset(self, env_mask: torch.Tensor) -> dict[str, Any]:
        """Episode logs (0-dim tensors) of the envs of ``env_mask`` (B,) bool, whose episodes ended; their per-episode
        buffers are cleared (static shapes: masked fills, no host read)."""
        return {}

    def state_dict(self) -> dict[str, Any]:
        """What of this manager outlives an episode, as copies (a checkpoint's part)."""
        return {}

    def check_state_dict(self, state: dict[str, Any]) -> None:
        """Raise ``ValueError`` if ``state`` (:meth:`state_dict` output) does not fit this manager's task."""

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore :meth:`state_dict` output (checked first: nothing is written if it does not fit)."""
        self.check_state_dict(state)

    def summary(self) -> str:
        """The manager's terms as a table (empty for a manager without terms)."""
        return ""


@dataclass
class Term:
    """One resolved term.

    Attributes:
        name: term name (YAML key).
        func: the function ``func(env, **params)``.
        params: checked keyword arguments.
        extra: manager-specific settings (weight, noise, mode, ...), validated by the manager.
    """

    name: str
    func: Callable
    params: dict[str, Any]
    extra: dict[str, Any] = field(default_factory=dict)

    def __call__(self, env, *args) -> Any:
        return self.func(env, *args, **self.params)


def _number(value: Any) -> str | None:
    return type_problem(value, float)


def _non_negative(value: Any) -> str | None:
    return type_problem(value, float) or (f"must be >= 0, got {value}" if value < 0 else None)


def _positive(value: Any) -> str | None:
    return type_problem(value, float) or (f"must be > 0, got {value}" if not value > 0 else None)


def _seconds_interval(value: Any) -> str | None:
    problem = interval_problem(value, non_negative=True)
    if problem is None and not value[1] > 0:
        return f"must end after 0 s, got {list(value)}"
    return problem


def _optional_seconds_interval(value: Any) -> str | None:
    return None if value is None else _seconds_interval(value)


def _boolean(value: Any) -> str | None:
    return type_problem(value, bool)


KEY_CHECKS: dict[str, Callable[[Any], str | None]] = {
    "weight": _number,
    "noise": _non_negative,
    "time_out": _boolean,
    "resampling_time_s": _seconds_interval,
    "interval_s": _optional_seconds_interval,
}
"""Checks of the manager keys of a term entry (rewards ``weight``, observations ``noise``, ...)."""

PARAM_RULES: dict[str, Callable[[Any], str | None]] = {
    "sigma": _positive,  # a zero or negative kernel width zeroes or inverts a tracking reward
    "joint_scale": lambda v: interval_problem(v, non_negative=True),
    "scale_range": lambda v: interval_problem(v, non_negative=True),
    "friction_range": lambda v: interval_problem(v, non_negative=True),
    "standing_fraction": _non_negative,
    "max_speed": _non_negative,
    "alpha": _non_negative,
    "alpha_max": _non_negative,
}
"""Range conventions of term parameters, by parameter name (types come from the annotations)."""


def check_params(task: TaskConfig, key: str, func: Callable, params: dict[str, Any]) -> None:
    """Type-check ``params`` against ``func``'s annotations, order ``[low, high]`` pairs, apply ``PARAM_RULES``."""
    hints = type_hints(func)
    for name, value in params.items():
        annotation = hints.get(name, Any)
        problem = type_problem(value, annotation)
        if problem is None and annotation == tuple[float, float]:
            problem = interval_problem(value)
        if problem is None and name in PARAM_RULES:
            problem = PARAM_RULES[name](value)
        if problem is not None:
            raise task.error(f"{key}.params.{name}", problem)


def public_functions(module: ModuleType) -> dict[str, Callable]:
    """Term functions of an mdp module: public functions defined in it."""
    return {n: f for n, f in vars(module).items()
            if inspect.isfunction(f) and not n.startswith("_") and f.__module__ == module.__name__}


def resolve_terms(task: TaskConfig, section: str, module: ModuleType, extra_keys: dict[str, Any],
                  positional: tuple[str, ...] = ("env",), entries: dict | None = None,
                  key_prefix: str | None = None) -> list[Term]:
    """Resolve every entry of ``task.data[section]`` (or ``entries``) into a ``Term``.

    Args:
        task: the loaded task (for error messages).
        section: YAML section name (e.g. "rewards").
        module: mdp module holding the term functions.
        extra_keys: allowed manager-specific keys with their defaults (``...`` = required).
        positional: leading positional parameters every term function takes (not settable from YAML).
        entries: the mapping to resolve if not ``task.data[section]``.
        key_prefix: dotted key used in errors (defaults to ``section``).
    """
    prefix = key_prefix or section
    entries = task.section(section) if entries is None else entries
    registry = public_functions(module)
    terms = []
    for name, spec in entries.items():
        key = f"{prefix}.{name}"
        spec = {} if spec is None else spec
        if not isinstance(spec, dict):
            raise task.error(key, f"must be a mapping with keys {['func', 'params', *extra_keys]}")
        allowed_keys = {"func", "params", *extra_keys}
        unknown = sorted(set(spec) - allowed_keys)
        if unknown:
            raise task.error(f"{key}.{unknown[0]}", f"unknown key; allowed: {sorted(allowed_keys)}")
        if not isinstance(spec.get("params") or {}, dict):
            raise task.error(f"{key}.params", f"must be a mapping of parameter names to values, got {spec['params']!r}")
        func_name = spec.get("func", name)
        if not isinstance(func_name, str):
            raise task.error(f"{key}.func", f"must be a function name, got {func_name!r}")
        if func_name not in registry:
            raise task.error(f"{key}.func", f"unknown term function {func_name!r}; allowed: {sorted(registry)}")
        func = registry[func_name]
        params = dict(spec.get("params") or {})
        sig = inspect.signature(func)
        names = [p for p in sig.parameters if p not in positional]
        for p in params:
            if p not in names:
                raise task.error(f"{key}.params.{p}", f"unknown parameter of {func_name}; allowed: {names}")
        missing = [p for p in names if sig.parameters[p].default is inspect.Parameter.empty and p not in params]
        if missing:
            raise task.error(f"{key}.params", f"missing required parameter(s) {missing} of {func_name}")
        check_params(task, key, func, params)
        extra = {}
        for k, default in extra_keys.items():
            if k not in spec and default is ...:
                raise task.error(key, f"missing required key {k!r}")
            extra[k] = spec.get(k, default)
            if k in spec and k in KEY_CHECKS and (problem := KEY_CHECKS[k](spec[k])) is not None:
                raise task.error(f"{key}.{k}", problem)
        terms.append(Term(name, func, params, extra))
    return terms


def format_table(title: str, header: tuple[str, ...], rows: list[tuple]) -> str:
    """A plain-text table for the term summaries printed when the env starts."""
    cells = [tuple(str(c) for c in r) for r in rows]
    widths = [max(len(h), *(len(r[i]) for r in cells)) if cells else len(h) for i, h in enumerate(header)]
    line = "+" + "+".join("-" * (w + 2) for w in widths) + "+"
    out = [f"[{title}]", line, "| " + " | ".join(h.ljust(w) for h, w in zip(header, widths)) + " |", line]
    out += ["| " + " | ".join(c.ljust(w) for c, w in zip(r, widths)) + " |" for r in cells]
    out.append(line)
    return "\n".join(out)

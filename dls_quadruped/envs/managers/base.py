"""Shared manager machinery: resolve YAML term entries to functions and check their parameters.

A term entry in a task file looks like::

    rewards:
      track_lin_vel_xy:            # term name (free text, used in logs)
        func: track_lin_vel_xy_sek # function in the manager's mdp module; defaults to the term name
        weight: 1.5                # manager-specific keys (weight, noise, mode, ...)
        params: {sigma: 0.5}       # keyword arguments of the function, checked against its signature

The function's first parameter is the env; every other parameter without a default must appear in
``params`` and every key of ``params`` must be a parameter name, or building the env fails with
an error naming the file, the key and the allowed values.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from dataclasses import dataclass, field
from types import ModuleType
from typing import Any

from dls_quadruped.envs.config import TaskConfig


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
        func_name = spec.get("func", name)
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
        extra = {}
        for k, default in extra_keys.items():
            if k not in spec and default is ...:
                raise task.error(key, f"missing required key {k!r}")
            extra[k] = spec.get(k, default)
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

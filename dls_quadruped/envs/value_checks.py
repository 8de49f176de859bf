"""Checks of a task file's values: a YAML value against a type annotation or bounds, a section built into a dataclass.

The managers' term parameters (``managers/base.py``), the dataclass sections (``env``, ``scene``, ``terrain``,
``actions.latent``, distillation's settings) and the ``agent`` section (``agent_config.py``) are checked with these,
so every section names a wrong value the same way: ``must be a number, got str 'fast'``. The error itself, with the
file and dotted key, is ``TaskConfig.error``'s (``envs/config.py``).
"""

from __future__ import annotations

import dataclasses
import inspect
import math
import types
import typing
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from dls_quadruped.envs.config import TaskConfig


def type_hints(obj: Any) -> dict[str, Any]:
    """Resolved annotations of a function or class ({} where they cannot be resolved)."""
    try:
        return typing.get_type_hints(obj)
    except (NameError, AttributeError, TypeError):  # an unresolvable forward reference: skip the type checks
        return {}


def type_problem(value: Any, annotation: Any) -> str | None:
    """Why ``value`` (from YAML) does not fit ``annotation``, or None if it does.

    Understood: bool, int (not bool), float (int or float, not bool, finite), str, None, dict,
    ``X | Y``, ``tuple[X, Y]``, ``tuple[X, ...]``, ``list[X]``. Other annotations accept anything
    (a YAML value is never a tensor, so a ``torch.Tensor | float`` parameter checks the float).
    """
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if annotation is typing.Any or annotation is inspect.Parameter.empty:
        return None
    if origin in (typing.Union, types.UnionType):
        basic = [a for a in args if a in _BASIC or typing.get_origin(a) in (tuple, list, dict)]
        if len(basic) < len(args) and not basic:
            return None
        if any(type_problem(value, a) is None for a in basic):
            return None
        return "must be " + " or ".join(_describe(a) for a in basic) + f", got {_show(value)}"
    if annotation is type(None):
        return None if value is None else f"must be null, got {_show(value)}"
    if annotation is bool:
        return None if isinstance(value, bool) else f"must be true or false, got {_show(value)}"
    if annotation is int:
        ok = isinstance(value, int) and not isinstance(value, bool)
        return None if ok else f"must be an integer, got {_show(value)}"
    if annotation is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return f"must be a number, got {_show(value)}"
        return None if math.isfinite(value) else f"must be finite, got {value}"
    if annotation is str:
        return None if isinstance(value, str) else f"must be a string, got {_show(value)}"
    if annotation is dict or origin is dict:
        return None if isinstance(value, dict) else f"must be a mapping, got {_show(value)}"
    if origin in (tuple, list):
        if not isinstance(value, (list, tuple)):
            return f"must be a list ({_describe(annotation)}), got {_show(value)}"
        if origin is tuple and args and args[-1] is not Ellipsis:
            if len(value) != len(args):
                return f"must be a list of {len(args)} ({_describe(annotation)}), got {len(value)} values"
            items = list(zip(value, args))
        else:
            items = [(v, args[0]) for v in value] if args else []
        for i, (v, a) in enumerate(items):
            problem = type_problem(v, a)
            if problem is not None:
                return f"[{i}] {problem}"
        return None
    return None


_BASIC = (bool, int, float, str, type(None), dict)


def _describe(annotation: Any) -> str:
    names = {bool: "true/false", int: "an integer", float: "a number", str: "a string", type(None): "null",
             dict: "a mapping"}
    if annotation in names:
        return names[annotation]
    return str(annotation).replace("typing.", "")


def _show(value: Any) -> str:
    return f"{type(value).__name__} {value!r}"


def interval_problem(value: Any, non_negative: bool = False) -> str | None:
    """Why a ``[low, high]`` YAML value is not an ordered pair of finite numbers (>= 0 if asked)."""
    problem = type_problem(value, tuple[float, float])
    if problem is not None:
        return problem
    lo, hi = value
    if lo > hi:
        return f"must be ordered [low, high], got {list(value)}"
    if non_negative and lo < 0:
        return f"must be >= 0, got {list(value)}"
    return None


def bound_problem(value: Any, meta: typing.Mapping) -> str | None:
    """Check a number against ``min`` (>=) / ``gt`` (>) bounds in dataclass field metadata."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        if "min" in meta and value < meta["min"]:
            return f"must be >= {meta['min']}, got {value}"
        if "gt" in meta and not value > meta["gt"]:
            return f"must be > {meta['gt']}, got {value}"
    return None


def dataclass_from_dict(cls: type, values: dict, task: TaskConfig, key: str):
    """Build a (frozen) dataclass from a YAML mapping; lists become tuples.

    Unknown keys, values that do not fit the field's annotation (``type_problem``) and numbers
    outside the field's ``metadata`` bounds (``min``, ``gt``) fail with the file and dotted key.
    """
    fields = {f.name: f for f in dataclasses.fields(cls) if not f.name.startswith("_")}
    allowed = list(fields)
    if not isinstance(values, dict):
        raise task.error(key, f"must be a mapping with keys from {allowed}")
    unknown = sorted(set(values) - set(allowed))
    if unknown:
        raise task.error(f"{key}.{unknown[0]}", f"unknown key; allowed: {allowed}")
    hints = type_hints(cls)
    for name, value in values.items():
        problem = type_problem(value, hints.get(name, typing.Any)) or bound_problem(value, fields[name].metadata)
        if problem is not None:
            raise task.error(f"{key}.{name}", problem)

    def tup(v):
        return tuple(tup(x) for x in v) if isinstance(v, list) else v

    try:
        return cls(**{k: tup(v) for k, v in values.items()})
    except (TypeError, ValueError) as err:
        raise task.error(key, str(err)) from err

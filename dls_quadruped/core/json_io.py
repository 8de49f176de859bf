"""Strict JSON output: results files are always valid JSON (no ``NaN``/``Infinity`` tokens).

``json.dumps`` writes ``NaN`` by default, which most JSON readers reject. ``write_json`` replaces
every non-finite float by ``null``, lists the dotted paths it replaced under ``"non_finite"`` (so a
missing value is visible, not silent) and serialises with ``allow_nan=False``.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any


def finite_or_null(obj: Any, path: str = "", replaced: list[str] | None = None) -> Any:
    """A copy of ``obj`` (dicts, lists, tuples, numbers, numpy scalars) with non-finite floats as None."""
    if hasattr(obj, "item") and callable(obj.item) and getattr(obj, "shape", None) == ():
        obj = obj.item()  # numpy / torch scalar
    elif hasattr(obj, "tolist") and callable(obj.tolist):
        obj = obj.tolist()
    if isinstance(obj, float) and not math.isfinite(obj):
        if replaced is not None:
            replaced.append(path or "<root>")
        return None
    if isinstance(obj, dict):
        return {k: finite_or_null(v, f"{path}.{k}" if path else str(k), replaced) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_or_null(v, f"{path}[{i}]", replaced) for i, v in enumerate(obj)]
    return obj


def dumps(obj: Any, indent: int | None = 2) -> str:
    """Strict JSON text of ``obj``; non-finite floats become null and are listed under ``non_finite``."""
    replaced: list[str] = []
    clean = finite_or_null(obj, "", replaced)
    if replaced and isinstance(clean, dict):
        clean["non_finite"] = replaced
    return json.dumps(clean, indent=indent, allow_nan=False)


def write_json(obj: Any, path: Path, indent: int | None = 2) -> str:
    """Write ``dumps(obj)`` atomically (tmp file + rename); returns the text."""
    text = dumps(obj, indent)
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    os.replace(tmp, path)
    return text

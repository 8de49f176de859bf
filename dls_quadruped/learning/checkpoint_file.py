"""Read a checkpoint file without running code from it.

``torch.load(weights_only=False)`` unpickles anything, and unpickling calls whatever function the file names:
a checkpoint one did not make (``train --init-from``, the shipped ``docs/policies/*_networks.pt``) could run any
code. :func:`load` unpickles with ``weights_only=True``: tensors, numbers, strings, ``dict``/``list``/``tuple``/
``OrderedDict`` (torch's own allow-list) and :data:`SAFE_GLOBALS`, the other types this project's checkpoints hold:

- numpy arrays, dtypes and dtype classes: numpy's global generator state in a training checkpoint
  (``resume_state.capture``), evaluation returns in a distillation checkpoint (``DistillTrainer.state_dict``);
- numpy scalars (a metric that stayed an ``np.float64``), ``bytes`` (an empty one pickles as a call of ``bytes``).

Every one of them builds data and calls nothing else (an object array's items are unpickled by the same
restricted unpickler).
"""

from __future__ import annotations

import pickle
import re
from pathlib import Path
from typing import Any

import numpy as np
import torch

try:  # numpy >= 2 pickles arrays through numpy._core
    from numpy._core import multiarray as _multiarray
except ImportError:  # pragma: no cover -- numpy 1.26
    from numpy.core import multiarray as _multiarray

SAFE_GLOBALS: tuple = (np.ndarray, np.dtype, *(getattr(np.dtypes, name) for name in np.dtypes.__all__),
                       _multiarray._reconstruct, _multiarray.scalar, bytes)
"""What a checkpoint may name besides torch's own allow-list (``np.dtypes``: the class of each dtype, whose state
an array's dtype restores)."""

_GLOBAL = re.compile(r"GLOBAL (\S+)")


class UnsafeCheckpoint(ValueError):
    """A checkpoint names a function or class outside :data:`SAFE_GLOBALS`: unpickling it could run code."""


def load(path: str | Path) -> Any:
    """``torch.load(path)`` on the CPU with ``weights_only=True`` and :data:`SAFE_GLOBALS`.

    Raises:
        UnsafeCheckpoint: the file names another global (one line: which one, and why it is refused).
        Exception: whatever ``torch.load`` raises for an unreadable file (truncated, not a checkpoint).
    """
    with torch.serialization.safe_globals(list(SAFE_GLOBALS)):
        try:
            return torch.load(path, map_location="cpu", weights_only=True)
        except pickle.UnpicklingError as err:
            names = _refused_globals(path, str(err))
            if not names:
                raise
            raise UnsafeCheckpoint(
                f"refused: it names {', '.join(names)}, which a checkpoint of tensors, numbers, strings, containers "
                "and numpy arrays never does; unpickling it could run code") from None


def _refused_globals(path: str | Path, message: str) -> list[str]:
    """The globals of ``path`` outside both allow-lists (torch's scan of the file; else the one torch's message
    names, e.g. ``GLOBAL posix.system``)."""
    allowed = {f"{g.__module__}.{g.__qualname__}" for g in SAFE_GLOBALS}
    try:
        names = torch.serialization.get_unsafe_globals_in_checkpoint(path)
    except Exception:  # noqa: BLE001 -- not a zip checkpoint: fall back on the message
        names = _GLOBAL.findall(message)
    return [name for name in names if name not in allowed]

"""``constant_cache``: memoise a function that builds read-only constant tensors (bases, shift matrices).

A plain ``functools.lru_cache`` keeps whatever tensor the first call made; made inside
``torch.inference_mode()`` (the closed loop runs in it) that is an *inference tensor*, and any later
caller that records autograd (a test, a training step) fails with "Inference tensors cannot be saved
for backward". The builder here always runs with inference mode off, so the cached tensor is a
normal one that every caller can use.
"""

from __future__ import annotations

import functools

import torch


def constant_cache(fn):
    """``lru_cache(maxsize=64)`` of ``fn``, whose result is built outside inference mode."""

    @functools.lru_cache(maxsize=64)
    @functools.wraps(fn)
    def build(*args, **kwargs):
        with torch.inference_mode(False):
            return fn(*args, **kwargs)

    return build


@constant_cache
def constant_tensor(values: tuple, dtype: torch.dtype, device: torch.device | str) -> torch.Tensor:
    """``torch.tensor(values, dtype=dtype, device=device)`` built once per arguments (``values`` a tuple, nested
    for more dimensions): a read-only constant that a function called every step would otherwise upload from the
    host every call (``core/sync_probe.py``)."""
    return torch.tensor(values, dtype=dtype, device=device)

"""A 32-bit integer hash in pure torch: the root of the project's counter-based random numbers.

Used by the MPC sampler's Gaussian noise (``mpc/rng.py``, mirrored bit for bit by the C++ kernel) and
by the env's episode schedule (``envs/schedule.py``): both draw numbers as a pure function of
(seed, counter), so they are deterministic, fusable by ``torch.compile`` and the same on any device.
"""

from __future__ import annotations

import torch

_MASK32 = 0xFFFFFFFF


def hash32(x: torch.Tensor) -> torch.Tensor:
    """Integer hash of int64 values, result in [0, 2^32) (int64).

    A three-round xor-shift-multiply avalanche (the structure of the "lowbias32" family) with
    multipliers < 2^31, so every product of a 32-bit value fits in int64.
    """
    x = x & _MASK32
    x = x ^ (x >> 16)
    x = (x * 0x7FEB352D) & _MASK32
    x = x ^ (x >> 15)
    x = (x * 0x1B873593) & _MASK32
    x = x ^ (x >> 16)
    x = (x * 0x5BD1E995) & _MASK32
    return x ^ (x >> 13)

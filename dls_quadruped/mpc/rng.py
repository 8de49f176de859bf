"""Counter-based Gaussian noise for the sampler: normal = f(seed, counter), pure torch.

Why not ``torch.randn``: on this CPU, torch's generator draws ~0.2-0.4 G normals/s on one
thread, i.e. 1.5-2.5 ms for the 480 000 numbers of one M = 10 000 solve (half the time budget),
and a randn inside a torch.compile'd graph is slower still (~13 ms measured). A counter-based
generator is a pure elementwise function of (seed, counter), so inductor fuses it into the
rollout kernel (no noise tensor is ever written), every path (fast, reference, re-drawing the
best sample) gets the same numbers, and it runs unchanged on CUDA.

Construction: two 32-bit integer hashes (``core.hashing.hash32``) per counter give two uniforms; Box-Muller turns them
into two independent standard normals (cosine and sine branch). The seed itself comes from a
``torch.Generator``, so solves are deterministic under a seed.
"""

from __future__ import annotations

import math

import torch

from dls_quadruped.core.hashing import hash32

_TWO_PI = 2.0 * math.pi


def normal_pair(seed: torch.Tensor, counter: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Two independent standard normals per counter (Box-Muller's cosine and sine branches).

    Args:
        seed: () int64 tensor (or python int) in [0, 2^31).
        counter: (...) int64 non-negative counters, < 2^31; distinct counters give independent pairs.

    Returns:
        two (...) float32 tensors ~ N(0, 1).
    """
    key = hash32(seed + 0x2545F491)
    h1 = hash32((counter * 2) ^ key)
    h2 = hash32((counter * 2 + 1) ^ key)
    u1 = (h1.to(torch.float32) + 1.0) * (1.0 / 4294967297.0)  # (0, 1]: log is finite
    angle = h2.to(torch.float32) * (_TWO_PI / 4294967296.0)
    radius = torch.sqrt(-2.0 * torch.log(u1))
    return radius * torch.cos(angle), radius * torch.sin(angle)


def normals(seed: torch.Tensor, counter0: torch.Tensor, dim: int) -> torch.Tensor:
    """A row of ``dim`` (even) normals per leading index: entries 2p, 2p + 1 use counter counter0 + p.

    Args:
        seed: () int64.
        counter0: (...) int64 first counter of each row.
        dim: even row length.

    Returns:
        (..., dim) float32.
    """
    pairs = counter0[..., None] + torch.arange(dim // 2, device=counter0.device)
    z_cos, z_sin = normal_pair(seed, pairs)
    return torch.stack([z_cos, z_sin], dim=-1).flatten(-2)

"""Arbitration between warm-start groups: temporal coherence of the winning group.

With several warm starts in one solve (thesis 7.4, Algorithm 2) the plain argmin's group can switch up to
10 times per second, and every switch changes the gait the robot is asked to follow. Two mechanisms, both
:class:`~dls_quadruped.mpc.config.SamplerConfig` values, combinable, off by default:

* **switching cost** ``s = switching_cost`` (cost units of eq. 3.2.1): every sample whose group is not the
  robot's previous winning group has ``s`` added to its cost before the argmin. The robot leaves its group
  only when another group's best sample beats its own group's best by more than ``s``.
* **running group cost** ``beta = group_cost_smoothing`` in [0, 1): the groups are compared by an
  exponential moving average of their best cost over the past solves instead of this solve's; with
  ``s > 0`` this is a hysteresis on the averages (a switch needs an average lower by more than ``s``).
  ``beta = 0`` is this solve's cost, which makes the second mechanism the first one.

Per robot and solve (``c``: the previous winning group, -1 after a reset, the first solve or a fallback):

    J_g   = min over the samples m of group g of J_m       (float32, the kernel's; j_g its first minimum)
    A_g   = (1 - beta) J_g + beta A_g^prev                 (float64; A_g = J_g without a finite A_g^prev
                                                            or when J_g is not finite)
    S_g   = A_g + s [g != c and c >= 0]
    w     = c if S_c <= min_g S_g else the first argmin_g S_g      (a switch needs a strictly lower score)
    winner: sample j_w; its reported cost is its own J_{j_w}, without the switching cost

If every score is +inf (every sample diverged) the winner is the plain argmin. Only the choice of the winner
changes: costs, the winner's decoding and the fallbacks are those of the plain solve. Both solve paths (torch
and fused C++) call :func:`select` on the same (B, M) cost matrix, so they agree bit for bit.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass
class Memory:
    """Per-robot state of the arbitration between solves (``SamplingMPC`` keeps one; ``reset`` clears rows).

    Attributes:
        winner: (B,) long, the previous winning group (-1: none).
        average: (B, G) float64, the running group costs A_g (NaN: none).
    """

    winner: torch.Tensor
    average: torch.Tensor

    @classmethod
    def empty(cls, b: int, g: int, device: torch.device | str = "cpu") -> Memory:
        """No memory for B robots and G groups."""
        return cls(torch.full((b,), -1, dtype=torch.long, device=device),
                   torch.full((b, g), float("nan"), dtype=torch.float64, device=device))

    def forget(self, robots: torch.Tensor) -> None:
        """Clear the rows of ``robots`` ((K,) indices or (B,) bool; a mask by ``masked_fill_``, no host read)."""
        if robots.dtype == torch.bool:
            self.winner.masked_fill_(robots, -1)
            self.average.masked_fill_(robots[:, None], float("nan"))
            return
        self.winner[robots] = -1
        self.average[robots] = float("nan")


def group_bests(costs: torch.Tensor, counts: tuple[int, ...]) -> tuple[torch.Tensor, torch.Tensor]:
    """Best sample of every group.

    Args:
        costs: (B, M) sample costs (never NaN: the kernels map NaN to +inf).
        counts: samples per group; the groups are contiguous, in order (``samples.group_layout``).

    Returns:
        (B, G) float32 best cost J_g, (B, G) long index m of its first minimum.
    """
    best, index, start = [], [], 0
    for count in counts:  # G is 2 or 3: one reduction per group, no loop over samples
        value, arg = costs[:, start:start + count].min(dim=1)
        best.append(value)
        index.append(arg + start)
        start += count
    return torch.stack(best, dim=1), torch.stack(index, dim=1)


def select(costs: torch.Tensor, counts: tuple[int, ...], switching_cost: float, smoothing: float,
           memory: Memory | None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The winner of every robot under the switching cost and the running group cost (module docstring).

    Args:
        costs: (B, M) sample costs J_m (eq. 3.2.1).
        counts: samples per group (contiguous groups).
        switching_cost: s >= 0, added to the samples outside the previous winner's group.
        smoothing: beta in [0, 1), weight of the previous running group cost.
        memory: the previous solve's; None = no memory (first solve).

    Returns:
        best_cost (B,) float32 (the winner's own cost), best_index (B,) long, average (B, G) float64 (the
        new A_g, for the next solve's memory).
    """
    b, g = costs.shape[0], len(counts)
    j_g, j_idx = group_bests(costs, counts)
    if memory is None:
        memory = Memory.empty(b, g, costs.device)
    prev, a_prev = memory.winner, memory.average
    j64 = j_g.double()
    blend = (1.0 - smoothing) * j64 + smoothing * a_prev
    average = torch.where(torch.isfinite(a_prev) & torch.isfinite(j64), blend, j64)
    groups = torch.arange(g, device=costs.device)
    penalised = (groups[None, :] != prev[:, None]) & (prev[:, None] >= 0)
    score = average + switching_cost * penalised.double()
    best_score, w = score.min(dim=1)
    stay_score = score.gather(1, prev.clamp(min=0)[:, None])[:, 0]
    w = torch.where((prev >= 0) & (stay_score <= best_score), prev, w)
    _, plain_group = j_g.min(dim=1)  # = costs.min(dim=1): the first minimum lies in the first such group
    w = torch.where(torch.isfinite(best_score), w, plain_group)
    best_index = j_idx.gather(1, w[:, None])[:, 0]
    best_cost = j_g.gather(1, w[:, None])[:, 0]
    return best_cost, best_index, average

"""Each robot's first minimum over its M sample costs, on the device (Warp), no host read, no atomics.

A tree of :data:`FAN_IN`-way reductions: level 1 has ceil(M / 32) threads per robot, thread t keeping the minimum of
samples t, t + T, t + 2T, ... (T threads: neighbouring threads read neighbouring costs), level 2 reduces those
partials the same way, until at most 32 are left, which the last stage (:func:`argmin_final`, in the winners'
decode kernel or :func:`argmin_rows`) scans. Every comparison keeps the lower cost and, on a tie, the lower sample
index, so the answer is the first minimum of the row: what ``torch.min(dim=1)`` and the ``cpp`` kernel's
``mpc_solve`` (a strict ``<`` scan) return. Costs are never NaN (the rollout writes +inf).

Launches per solve: ``len(plan(M))``: 1 for M <= 1 024, 2 up to 32 768, 3 up to 10^6 (plus the last stage inside
the decode kernel).
"""

from __future__ import annotations

import torch
import warp as wp

FAN_IN = 32
"""Entries each thread of a level reduces."""


def plan(m: int) -> tuple[int, ...]:
    """Threads per robot of each reduction level for M = ``m`` costs (empty: the last stage scans them all)."""
    widths, n = [], m
    while n > FAN_IN:
        n = -(-n // FAN_IN)
        widths.append(n)
    return tuple(widths)


_F2 = wp.array2d(dtype=wp.float32)
_I2 = wp.array2d(dtype=wp.int32)


@wp.func
def _first_min(cost: _F2, index: _I2, first: int, b: int, start: int, stop: int, step: int):
    """(lowest cost, its sample index) over entries ``start:stop:step`` of row b, ties to the lower index; ``first``
    as in :func:`argmin_reduce`."""
    best = wp.float32(wp.inf)
    arg = wp.int32(-1)
    for j in range(start, stop, step):
        c = cost[b, j]
        i = j
        if first == 0:
            i = wp.int32(index[b, j])
        if arg < 0 or c < best or (c == best and i < arg):
            best = c
            arg = i
    return best, arg


@wp.kernel(enable_backward=False)
def argmin_reduce(cost_in: _F2, index_in: _I2, first: int, n_out: int, cost_out: _F2, index_out: _I2):
    """Thread (b, t): the first minimum of robot b's entries t, t + n_out, ... of its row of ``cost_in`` (``first``
    = 1: the (B, M) costs themselves, an entry's index its column; else partials with their sample index)."""
    b, t = wp.tid()
    best, arg = _first_min(cost_in, index_in, first, b, t, cost_in.shape[1], n_out)
    cost_out[b, t] = best
    index_out[b, t] = arg


@wp.func
def argmin_final(cost: _F2, index: _I2, first: int, n: int, b: int) -> int:
    """Robot b's first minimum from the ``n`` (<= :data:`FAN_IN`) entries of its row (``first`` as in
    :func:`argmin_reduce`)."""
    _best, arg = _first_min(cost, index, first, b, 0, n, 1)
    return arg


@wp.kernel(enable_backward=False)
def argmin_rows(cost: _F2, index: _I2, first: int, n: int, costs: _F2, best_cost: wp.array(dtype=wp.float32),
                best_index: wp.array(dtype=wp.int64)):
    """Thread b: robot b's first minimum (:func:`argmin_final`) and its cost in the (B, M) ``costs``."""
    b = wp.tid()
    arg = argmin_final(cost, index, first, n, b)
    best_index[b] = wp.int64(arg)
    best_cost[b] = costs[b, arg]


class ArgminTree:
    """The reduction levels' buffers for B robots x M costs on one device, and their launches.

    After :meth:`launch`, :attr:`last` = (costs, indices, first, n): what :func:`argmin_final` reads."""

    def __init__(self, b: int, m: int, device: torch.device) -> None:
        self.b, self.m, self.widths = b, m, plan(m)
        self.levels = [(torch.empty(b, w, dtype=torch.float32, device=device),
                        torch.empty(b, w, dtype=torch.int32, device=device)) for w in self.widths]
        self._wp = [(wp.from_torch(c), wp.from_torch(i)) for c, i in self.levels]
        self._dummy = wp.from_torch(torch.zeros(1, 1, dtype=torch.int32, device=device))

    def launch(self, costs: wp.array, device: str, stream=None) -> tuple:
        """Launch the levels on the (B, M) ``costs``; returns :attr:`last`."""
        src, index, first, n = costs, self._dummy, 1, self.m
        for width, (c, i) in zip(self.widths, self._wp, strict=True):
            wp.launch(argmin_reduce, dim=(self.b, width), inputs=[src, index, first, width, c, i], device=device,
                      stream=stream)
            src, index, first, n = c, i, 0, width
        self.last = (src, index, first, n)
        return self.last


def warp_argmin(costs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(B,) first minimum and its (B,) int64 index of each row of ``costs`` (B, M) float32 (never NaN), with the
    device kernels: ``torch.min(costs, dim=1)``'s answer."""
    from dls_quadruped.mpc.warp_kernel import init, wp_device

    init()
    b, m = costs.shape
    dev = wp_device(costs.device)
    costs = costs.contiguous()
    tree = ArgminTree(b, m, costs.device)
    best_cost = torch.empty(b, dtype=torch.float32, device=costs.device)
    best_index = torch.empty(b, dtype=torch.int64, device=costs.device)
    stream = wp.stream_from_torch(torch.cuda.current_stream(costs.device)) if costs.is_cuda else None
    table = wp.from_torch(costs)
    last = tree.launch(table, dev, stream)
    wp.launch(argmin_rows, dim=b, inputs=[*last, table, wp.from_torch(best_cost), wp.from_torch(best_index)],
              device=dev, stream=stream)
    return best_cost, best_index

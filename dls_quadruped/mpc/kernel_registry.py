"""The MPC's rollout + cost kernels by name: ``SamplerConfig.kernel`` -> the function that costs every sample.

A kernel maps one solve's inputs to the (B, M) rollout costs of all samples, ``costs(inp: KernelInputs,
cfg: SamplerConfig, model: SRBDModel) -> Tensor[(B, M)]``; the four built in have identical semantics
(``mpc/kernel.py``)::

    KERNEL_REGISTRY.get("cpp")(inp, cfg, model)    # (B, M) costs
    KERNEL_REGISTRY.get("gpu")                     # ValueError: unknown MPC kernel 'gpu'; allowed: fast (...), ...

A built-in entry names its function as ``"module:function"`` and imports it when called, so ``mpc/config.py``,
which checks a name here, imports no kernel (the kernels import the config). A new kernel registers its
function with ``KERNEL_REGISTRY.register``.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import TYPE_CHECKING

from dls_quadruped.core.registry import Registry

if TYPE_CHECKING:
    import torch

    from dls_quadruped.mpc.config import SamplerConfig
    from dls_quadruped.mpc.kernel import KernelInputs
    from dls_quadruped.mpc.srbd import SRBDModel

CostKernel = Callable[["KernelInputs", "SamplerConfig", "SRBDModel"], "torch.Tensor"]

KERNEL_REGISTRY: Registry[CostKernel] = Registry("MPC kernel")
"""The cost kernels by name, in the order ``--kernel`` lists them."""


def lazy_kernel(target: str) -> CostKernel:
    """The kernel ``"module:function"``, looked up at every call (after the module's first import, a dict lookup;
    a test that patches the function is seen)."""
    module, name = target.split(":")

    def costs(inp: KernelInputs, cfg: SamplerConfig, model: SRBDModel) -> torch.Tensor:
        return getattr(importlib.import_module(module), name)(inp, cfg, model)

    costs.__name__ = costs.__qualname__ = name
    return costs


KERNEL_REGISTRY.register("fast", lazy_kernel("dls_quadruped.mpc.kernel:fast_costs"),
                         "torch.compile of the per-sample maths, CPU or CUDA")
KERNEL_REGISTRY.register("reference", lazy_kernel("dls_quadruped.mpc.kernel:reference_costs"),
                         "eager batched torch, the correctness anchor")
KERNEL_REGISTRY.register("cpp", lazy_kernel("dls_quadruped.mpc.kernel:cpp_costs"),
                         "hand-written C++/OpenMP built at first use, the CPU default; warp on CUDA (SamplingMPC)")
KERNEL_REGISTRY.register("warp", lazy_kernel("dls_quadruped.mpc.warp_kernel:warp_costs"),
                         "one Warp kernel, a thread per sample; CUDA or Warp's CPU device; the solve without host "
                         "reads")

"""What the MPC benchmarks share (``bench/mpc.py``, ``bench/mpc_builds.py``, ``bench/mpc_path.py``): the solve
they time, the machine they report and the docs sections they rewrite."""

from __future__ import annotations

import os
import platform

import torch

from dls_quadruped.core.machine import cpu_model
from dls_quadruped.mpc import Refs, SRBDState

SECTION = "## MPC solve time"
"""The docs section of the solve times per kernel (``bench/mpc.py``)."""
BUILDS_SECTION = "## MPC C++ kernel builds"
"""The docs section of the C++ kernel builds (``bench/mpc_builds.py``); the solve path's section follows it."""


def machine_info() -> dict:
    """CPU model, threads, torch version, CUDA device, load average."""
    info = {"cpu": cpu_model(), "cpu_count": os.cpu_count(), "torch_threads": torch.get_num_threads(),
            "torch": torch.__version__, "python": platform.python_version(),
            "load_avg_1_5_15": list(os.getloadavg()) if hasattr(os, "getloadavg") else None}
    if torch.cuda.is_available():
        info["cuda_device"] = torch.cuda.get_device_name(0)
    return info


def solve_problem(device: str) -> tuple[SRBDState, Refs, torch.Tensor]:
    """The timed solve's inputs on ``device``, B = 1: the SRBD state (CoM 0.32 m high at 0.3 m/s, a little
    roll, pitch and roll rate, feet under the hips), the references (0.5 m/s at 0.33 m) and the trot's phase (1, 4)."""
    feet = torch.tensor([[0.24, 0.134, 0.0265], [0.24, -0.134, 0.0265], [-0.24, 0.134, 0.0265],
                         [-0.24, -0.134, 0.0265]])
    state = SRBDState(torch.tensor([[0.0, 0.0, 0.32]]), torch.tensor([[0.3, 0.0, 0.0]]),
                      torch.tensor([[0.02, -0.01, 0.0]]), torch.tensor([[0.1, 0.0, 0.0]]),
                      feet[None].clone()).to(device)
    refs = Refs(torch.tensor([0.33]), torch.tensor([[0.5, 0.0]]), torch.tensor([0.0]), feet[None].clone()).to(device)
    phase = torch.tensor([[0.1, 0.6, 0.6, 0.1]], device=device)
    return state, refs, phase


def section_span(text: str, heading: str) -> tuple[int, int]:
    """Start of ``heading`` in ``text`` and the start of the next '## ' section (or the end of the text)."""
    start = text.index(heading)
    nxt = text.find("\n## ", start + len(heading))
    return start, (nxt + 1 if nxt >= 0 else len(text))

"""Exported networks on disk: ``torch.export`` programs (``.pt2``) written, programs and TorchScript read.

A network is exported as a ``torch.export`` program with a free batch size (``torch.export.save``, one
``.pt2`` archive; metadata rides along as the archive's extra files). Load one in any Python with

    program = torch.export.load("policy.pt2")
    actions = program.module()(obs)          # obs (B, D) float32 -> (B, A)

TorchScript (``torch.jit``) is deprecated from torch 2.13, so nothing here writes it; the committed
policies (``docs/policies/*.pt``) and the exports of earlier runs are TorchScript archives and still
load, through :func:`load_module`, the one place that reads them.

:func:`file_kind` tells a program, a TorchScript archive and a ``torch.save`` checkpoint apart by
their records, so a renamed file loads as what it is.
"""

from __future__ import annotations

import copy
import os
import warnings
import zipfile
from pathlib import Path

import torch
from torch import nn

PROGRAM_SUFFIX = ".pt2"
"""The usual name of a program (``torch.export.load`` opens a path only under it; here files are opened
first, so a program under any name loads)."""


def file_kind(path: str | Path) -> str | None:
    """What ``path`` holds: ``"program"`` (``torch.export.save``), ``"torchscript"`` (``torch.jit.save``),
    ``"checkpoint"`` (``torch.save``), or None (not a PyTorch zip archive, e.g. a legacy pickle or junk)."""
    try:
        with zipfile.ZipFile(path) as archive:
            # every record sits under one top folder: <name>/archive_format, <name>/code/..., <name>/data.pkl
            records = {name.split("/", 1)[-1] for name in archive.namelist()}
    except (zipfile.BadZipFile, OSError):
        return None
    if "archive_format" in records:
        return "program"
    if "constants.pkl" in records or any(r.startswith("code/") for r in records):
        return "torchscript"
    return "checkpoint" if "data.pkl" in records else None


class ExportedModule(nn.Module):
    """A loaded ``torch.export`` program behind the module interface of the TorchScript it replaces:
    ``forward``, and ``state_dict`` under the exported module's own names.

    A wrong observation width raises a ``RuntimeError`` naming both widths (as TorchScript's shape
    errors do; the program's own guard raises an ``AssertionError``).

    Args:
        program: the loaded program; its one input is (B, ``input_size``) with a free batch size.
    """

    def __init__(self, program: torch.export.ExportedProgram):
        super().__init__()
        self.graph = program.module()
        inputs = program.graph_signature.user_inputs
        (obs,) = [n for n in program.graph.nodes if n.op == "placeholder" and n.name in inputs]
        self.input_size = int(obs.meta["val"].shape[-1])
        """D, the observation width the program was exported for."""

    def train(self, mode: bool = True) -> ExportedModule:
        # the program was traced in eval mode and has no train-mode behaviour; torch.export's module
        # refuses train() and eval(), so the flag is kept here only
        self.training = mode
        return self

    def state_dict(self, *args, **kwargs):
        return self.graph.state_dict(*args, **kwargs)

    def forward(self, obs: torch.Tensor):
        """(B, D) observations -> the program's output(s)."""
        if obs.dim() != 2 or obs.shape[-1] != self.input_size:
            raise RuntimeError(f"the exported network takes (batch, {self.input_size}) observations, "
                               f"got {tuple(obs.shape)}")
        return self.graph(obs)


def save_program(module: nn.Module, input_size: int, path: str | Path,
                 extra_files: dict[str, str] | None = None) -> Path:
    """Export ``module`` (in eval mode, on the CPU) for (B, ``input_size``) float32 inputs with a free
    batch size and write it to ``path`` (a ``.pt2`` archive by name, written atomically: tmp + rename).

    Args:
        module: ``forward(obs (B, input_size)) -> Tensor or tuple of Tensors``; a copy is exported, so it
            stays on its device and in its mode.
        extra_files: {name: text} stored in the archive (read back by :func:`load_module`).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    module = copy.deepcopy(module).to("cpu").eval()
    # batch 2, not 1: torch.export turns a size-1 example dimension into a constant
    example = torch.zeros(2, int(input_size))
    program = torch.export.export(module, (example,), dynamic_shapes=({0: torch.export.Dim("batch", min=1)},))
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as fh:  # a buffer: torch.export.save takes a path only when it ends in .pt2
        torch.export.save(program, fh, extra_files=extra_files)
    os.replace(tmp, path)
    return path


def load_module(path: str | Path, device: str | torch.device = "cpu",
                extra_files: dict[str, str] | None = None) -> nn.Module:
    """An exported network, in eval mode on ``device``: a program (:class:`ExportedModule`) or a
    TorchScript module.

    Args:
        extra_files: {name: ""} filled in place with the archive's extra files of those names
            (an absent one stays "").

    Raises:
        ValueError: ``path`` is neither a program nor a TorchScript archive (e.g. a training checkpoint).
    """
    path = Path(path)
    kind = file_kind(path)
    if kind == "program":
        with open(path, "rb") as fh:  # a buffer: torch.export.load takes a path only when it ends in .pt2
            program = torch.export.load(fh, extra_files=extra_files)
        if torch.device(device).type != "cpu":
            from torch.export.passes import move_to_device_pass

            program = move_to_device_pass(program, device)
        return ExportedModule(program).eval()
    if kind == "torchscript":
        with warnings.catch_warnings():
            # TorchScript is deprecated from torch 2.13, but the committed policies and earlier runs'
            # exports are TorchScript archives, and torch.jit.load is the only reader of them
            warnings.filterwarnings("ignore", message=r"`torch\.jit\.load` is deprecated", category=DeprecationWarning)
            module = torch.jit.load(str(path), map_location=device, _extra_files=extra_files or {})
        return module.eval()
    raise ValueError(f"{path} is {'a training checkpoint' if kind == 'checkpoint' else 'not a PyTorch archive'}, "
                     "not an exported network (a .pt2 program or a TorchScript .pt)")

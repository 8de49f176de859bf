"""The torch devices this machine can run on, checked where a device is chosen, before anything is built."""

from __future__ import annotations

import torch


def checked_device(device: str | torch.device) -> torch.device:
    """``device`` ("cpu", "cuda", "cuda:1", ...) as a ``torch.device`` this torch build and machine have.

    Raises:
        ValueError: one line: a misspelt device, another kind than cpu/cuda, or a CUDA device on a build
            without CUDA, with no GPU visible or with fewer GPUs than the index.
    """
    text = str(device)
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError):
        raise ValueError(f"unknown device {text!r}; use cpu, cuda or cuda:<index>") from None
    if dev.type == "cuda":
        if not torch.cuda.is_available():
            why = "this torch build has no CUDA" if not torch.backends.cuda.is_built() else "no CUDA GPU is visible"
            raise ValueError(f"{text}: {why}; use cpu")
        if dev.index is not None and dev.index >= torch.cuda.device_count():
            raise ValueError(f"{text}: only {torch.cuda.device_count()} CUDA device(s) visible")
    elif dev.type != "cpu":
        raise ValueError(f"unsupported device {text!r}; use cpu, cuda or cuda:<index>")
    return dev

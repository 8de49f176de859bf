"""The CPU model for bench scripts: :func:`dls_quadruped.core.machine.cpu_model`, which code below ``bench/``
imports."""

from dls_quadruped.core.machine import cpu_model

__all__ = ["cpu_model"]

"""Horizon student (thesis 5.2.1): the expert actor's MLP with an encoded-horizon output.

The student reads the expert's 259-value observation and outputs the encoded horizon
``(f_0, d_0) + enc_p + enc_F`` (``mpc.encodings``, Table 13 dimension) in the policy's raw action
units (the action manager's normalised units, ``control.latent_action``). The network itself
learns the *label* space, where each spline curvature parameter (theta_-1 and theta_2, about 10x
the variance of the on-curve points, 7.2.4) is divided by 10; ``Student.forward`` multiplies it
back. Reused from rsl-rl-lib: ``MLP`` and ``EmpiricalNormalization`` (the same modules the expert
actor is made of).

Export: a ``torch.export`` program (``student.pt2``, ``learning/policy_file.py``) of
``obs (B, 259) -> (encoded (B, D), first action (B, 28))``; the encoding (p, F, H, dt, dims, label
scale) is stored inside the archive (``distill_meta.json``) and next to it (``<name>.json``).
:func:`load_student` reads it, or a TorchScript student (the committed ones), as a module with
``forward(obs) -> encoded`` and ``first_action(obs) -> (B, 28)``.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import torch
from rsl_rl.modules import MLP, EmpiricalNormalization
from torch import nn

from dls_quadruped.learning.policy_file import ExportedModule, load_module, save_program
from dls_quadruped.mpc.config import EncodingConfig
from dls_quadruped.mpc.encodings import (
    ACTION_DIM,
    F_SCALARS,
    P_SCALARS,
    SPLINE_PARAMS,
    block_slices,
    encode,
    encoded_dim,
)

CURVATURE_SCALE = 10.0
"""Spline curvature parameters are learnt divided by this (thesis 7.2.4)."""
META_NAME = "distill_meta.json"


def label_scale(cfg: EncodingConfig) -> torch.Tensor:
    """(D,) factor from the encoded horizon to the label space: 1/10 on every theta_-1 and theta_2
    of a spline block, 1 elsewhere."""
    scale = torch.ones(encoded_dim(cfg))
    sl = block_slices(cfg)
    for name, kind in (("p", cfg.p), ("F", cfg.F)):
        if kind == "spline":
            # (n, 4), scalar-major [theta_-1, theta_0, theta_1, theta_2]
            block = scale[sl[name]].view(-1, SPLINE_PARAMS)
            block[:, 0] = 1.0 / CURVATURE_SCALE
            block[:, 3] = 1.0 / CURVATURE_SCALE
    return scale


def first_action_index(cfg: EncodingConfig) -> torch.Tensor:
    """(28,) positions in the encoded vector of the horizon's first action.

    f_0, d_0 are stored as is; discrete and first blocks start with step 0; a spline's value at
    step 0 is theta_0 (x_0 = 0, where the Hermite cubic equals theta_0, eq. A.1.19).
    """
    sl = block_slices(cfg)
    idx = list(range(8))
    for name, kind, n in (("p", cfg.p, P_SCALARS), ("F", cfg.F, F_SCALARS)):
        start = sl[name].start
        if kind == "spline":
            idx += [start + SPLINE_PARAMS * j + 1 for j in range(n)]
        else:  # discrete (step-major: step 0 first) and first
            idx += [start + j for j in range(n)]
    return torch.tensor(idx, dtype=torch.long)


def encode_labels(actions: torch.Tensor, cfg: EncodingConfig) -> torch.Tensor:
    """Label of a window: (..., H, 28) raw expert actions -> (..., D) encoded, curvature / 10."""
    enc = encode(actions, cfg)
    return enc * label_scale(cfg).to(enc)


class Student(nn.Module):
    """Observation normaliser + MLP; ``net`` gives label-space outputs, ``forward`` the encoded horizon.

    Args:
        obs_dim: observation size (259).
        cfg: encoding; sets the output size D.
        hidden_dims, activation: the expert actor's (e.g. [512, 256, 128], "elu").
    """

    def __init__(self, obs_dim: int, cfg: EncodingConfig, hidden_dims: list[int] | tuple[int, ...],
                 activation: str = "elu"):
        super().__init__()
        self.obs_dim = int(obs_dim)
        self.out_dim = encoded_dim(cfg)
        self.obs_normalizer = EmpiricalNormalization(self.obs_dim)
        self.mlp = MLP(self.obs_dim, self.out_dim, list(hidden_dims), activation)
        self.register_buffer("output_scale", 1.0 / label_scale(cfg))  # x10 on the curvature parameters
        self.register_buffer("first_index", first_action_index(cfg))

    def net(self, obs: torch.Tensor) -> torch.Tensor:
        """(B, obs_dim) -> (B, D) label space (what the MSE compares)."""
        return self.mlp(self.obs_normalizer(obs))

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        """(B, obs_dim) -> (B, D) encoded horizon in raw action units (decode with ``mpc.encodings.decode``)."""
        return self.net(obs) * self.output_scale

    def first_action(self, obs: torch.Tensor) -> torch.Tensor:
        """(B, obs_dim) -> (B, 28) decoded first raw action of the horizon (what the env is given)."""
        return self.forward(obs).index_select(-1, self.first_index)


def metadata(cfg: EncodingConfig, dt: float, obs_dim: int, extra: dict | None = None) -> dict:
    """What a consumer needs to decode the student's output."""
    sl = block_slices(cfg)
    return {
        "encoding": {"p": cfg.p, "F": cfg.F, "horizon": cfg.horizon, "dt": float(dt),
                     "constrained_fit": cfg.constrained_fit},
        "obs_dim": int(obs_dim), "action_dim": ACTION_DIM, "output_dim": encoded_dim(cfg),
        "slices": {k: [s.start, s.stop] for k, s in sl.items()},
        "units": "raw (normalised) action units of the action manager; decode with mpc.encodings.decode",
        "curvature_scale": CURVATURE_SCALE,
        **(extra or {}),
    }


class _BothOutputs(nn.Module):
    """The exported graph: one pass, both outputs (a program has one entry point)."""

    def __init__(self, student: Student):
        super().__init__()
        self.student = student

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        encoded = self.student(obs)
        return encoded, encoded.index_select(-1, self.student.first_index)


class ExportedStudent(nn.Module):
    """A loaded student program with the interface of :class:`Student`: ``forward(obs) -> (B, D)``
    encoded horizon, ``first_action(obs) -> (B, 28)``."""

    def __init__(self, program: ExportedModule):
        super().__init__()
        self.program = program

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.program(obs)[0]

    def first_action(self, obs: torch.Tensor) -> torch.Tensor:
        return self.program(obs)[1]


def export_student(student: Student, meta: dict, path: Path) -> Path:
    """``torch.export`` program at ``path`` (``.pt2``) with ``meta`` inside and as
    ``path.with_suffix('.json')``, both written atomically (tmp + rename)."""
    path = Path(path)
    text = json.dumps(meta, indent=2, sort_keys=True)
    save_program(_BothOutputs(student), student.obs_dim, path, extra_files={META_NAME: text})
    side = path.with_suffix(".json")
    tmp_side = side.with_name(side.name + ".tmp")
    tmp_side.write_text(text + "\n")
    os.replace(tmp_side, side)
    return path


def load_student(path: str | Path, device: str = "cpu") -> tuple[nn.Module, dict]:
    """An exported student (a program, or TorchScript) and its metadata.

    Raises:
        FileNotFoundError: no file. ValueError: not a student export (no metadata inside).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"student {path} not found")
    extra = {META_NAME: ""}
    try:
        module = load_module(path, device=device, extra_files=extra)
    except (RuntimeError, ValueError) as err:
        raise ValueError(f"{path} is not an exported student: {str(err).splitlines()[0]}") from None
    if not extra[META_NAME]:
        raise ValueError(f"{path} has no {META_NAME}: not a distilled student export")
    if isinstance(module, ExportedModule):
        module = ExportedStudent(module)
    return module.eval(), json.loads(extra[META_NAME])

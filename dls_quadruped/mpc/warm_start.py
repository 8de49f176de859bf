"""Warm starts for the sampling MPC (thesis 3.2, 7.3): naive (shifted previous solution) and external.

Any encoded action (B, D) is a valid warm start. Its F block holds force **offsets from gravity
compensation** (``samples.forces_from_offsets``: F = c (dF + m g / sum c e_z), zero in swing), so an
all-zero F block is the feed-forward posture. These helpers build the common ones:

* :func:`naive` - previous best sample with its swing-step force offsets zeroed, shifted by one MPC
  period (:func:`shifted_force_offsets`, ``encodings.shift_encoded``);
* :func:`from_latent_action` - a single latent action (e.g. the RL policy's, in physical units)
  held over the horizon and encoded, i.e. what a non-horizon policy can offer;
* :func:`from_horizon` - a horizon of latent actions in physical units (e.g. a student policy's
  decoded output), forces turned into offsets with the contact sequence its own (f_0, d_0) imply;
* :func:`from_student` - a distilled student's encoded output (raw action units, Table 5) mapped
  entry by entry to the MPC's encoding in physical units (:func:`student_to_mpc_map`), after
  :func:`check_student_encoding` has matched its encoding, horizon and dt to the MPC's;
  :func:`student_horizon` decodes it to physical actions per step (its own contact sequence);
* :func:`nominal_trot` - the feed-forward default: trot at 1.5 Hz, duty 0.6, feet under the
  hips, zero force offsets (weight shared by the stance legs of every step).
"""

from __future__ import annotations

import torch

from dls_quadruped.control import gait
from dls_quadruped.control.latent_action import scale_vector
from dls_quadruped.core.torch_cache import constant_cache
from dls_quadruped.mpc.config import SamplerConfig
from dls_quadruped.mpc.encodings import (
    ACTION_DIM,
    F_SLICE,
    SPLINE_PARAMS,
    block_slices,
    decode_parts,
    encode,
    encoded_dim,
    held_shift_matrix,
    shift_encoded,
)
from dls_quadruped.mpc.samples import forces_from_offsets, offsets_from_forces


def shifted_force_offsets(encoded: torch.Tensor, contact: torch.Tensor, cfg: SamplerConfig,
                          steps: float) -> torch.Tensor:
    """The F block of the naive warm start: offsets per step, zeroed where the leg swings, shifted, re-encoded.

    Per step k the decoded offsets ``dF(k)`` are multiplied by the stance flags ``c(k)`` of the solution
    (a leg's force costs nothing while it swings: left alone, those parameters would random-walk from
    solve to solve), moved ``steps`` steps forward in time (linear interpolation, the last value held:
    a cubic is not extrapolated beyond the horizon, where nothing ever costed it) and encoded again:
    exact for ``discrete``, the step-0 value for ``first``, a least-squares spline (exact at step 0 with
    ``constrained_fit``) for ``spline``.

    Args:
        encoded: (B, D); contact: (B, N, 4) bool, the contact sequence the solution was costed with.

    Returns:
        (B, D_F) the new F block.
    """
    enc = cfg.encoding
    offset_h = decode_parts(encoded, enc)[3]  # (B, N, 4, 3)
    masked = (offset_h * contact.to(offset_h.dtype).unsqueeze(-1)).flatten(-2)  # (B, N, 12)
    shifted = held_shift_matrix(enc.horizon, steps, masked.dtype, masked.device) @ masked
    horizon = torch.zeros(*encoded.shape[:-1], enc.horizon, ACTION_DIM, dtype=encoded.dtype, device=encoded.device)
    horizon[..., F_SLICE] = shifted
    return encode(horizon, enc)[..., block_slices(enc)["F"]]


def naive(previous_best: torch.Tensor, cfg: SamplerConfig, contact: torch.Tensor | None = None) -> torch.Tensor:
    """The naive warm start: the previous solution (B, D) shifted by mpc_period / dt horizon steps -> (B, D).

    With its contact sequence ``contact`` (B, N, 4) (``MPCResult.contact_horizon``), the force offsets
    are zeroed in swing steps and shifted with the tail held (:func:`shifted_force_offsets`); without it,
    the plain time shift of ``encodings.shift_encoded``. f, d and p: ``shift_encoded``.
    """
    steps = cfg.mpc_period / cfg.dt
    out = shift_encoded(previous_best, cfg.encoding, steps)
    if contact is not None:
        out[..., block_slices(cfg.encoding)["F"]] = shifted_force_offsets(previous_best, contact, cfg, steps)
    return out


def from_horizon(actions: torch.Tensor, cfg: SamplerConfig, phase: torch.Tensor) -> torch.Tensor:
    """Encode a horizon of latent actions in physical units (frame H) -> (B, D).

    Forces become offsets from gravity compensation with the contact sequence that the horizon's own
    (f_0, d_0) imply from ``phase``; legs in swing get a zero offset.

    Args:
        actions: (B, N, 28) physical units; phase: (B, 4) gait phase at step 0.
    """
    if actions.dim() != 3 or tuple(actions.shape[1:]) != (cfg.horizon, ACTION_DIM):
        raise ValueError(f"actions must have shape (B, {cfg.horizon}, {ACTION_DIM}), got {tuple(actions.shape)}")
    if tuple(phase.shape) != (actions.shape[0], 4):
        raise ValueError(f"phase must have shape ({actions.shape[0]}, 4), got {tuple(phase.shape)}")
    _, contact = gait.contact_sequence(phase.to(actions), actions[:, 0, 0:4], actions[:, 0, 4:8], cfg.dt, cfg.horizon)
    offsets = offsets_from_forces(actions[..., F_SLICE].unflatten(-1, (4, 3)), contact, cfg.action)
    return encode(torch.cat([actions[..., :F_SLICE.start], offsets.flatten(-2)], dim=-1), cfg.encoding)


def from_latent_action(action: torch.Tensor, cfg: SamplerConfig, phase: torch.Tensor) -> torch.Tensor:
    """Hold one latent action (B, 28) (physical units) over the horizon and encode it -> (B, D)."""
    if action.dim() != 2 or action.shape[-1] != ACTION_DIM:
        raise ValueError(f"action must have shape (B, {ACTION_DIM}), got {tuple(action.shape)}")
    return from_horizon(action[:, None, :].expand(-1, cfg.horizon, ACTION_DIM), cfg, phase)


def nominal_trot(batch: int, cfg: SamplerConfig, freq: float = 1.5, duty: float = 0.6) -> torch.Tensor:
    """Feed-forward trot warm start (B, D): f, d constant, p = 0, force offsets 0 (F = m g / stance legs)."""
    action = torch.zeros(batch, cfg.horizon, ACTION_DIM)
    action[..., 0:4] = freq
    action[..., 4:8] = duty
    return encode(action, cfg.encoding)


def check_student_encoding(meta: dict, cfg: SamplerConfig) -> None:
    """Raise ``ValueError`` unless a student's metadata (``learning.student.metadata``) encodes the
    MPC's horizon: same p and F encodings, horizon H = N, spacing dt, constrained fit and output size."""
    enc = meta.get("encoding") if isinstance(meta, dict) else None
    if not isinstance(enc, dict):  # ValueError, not TypeError: callers catch ValueError (closed_loop/controllers.py)
        raise ValueError(f"student metadata has no 'encoding' section (a distilled student export's "  # noqa: TRY004
                         f"distill_meta.json has one), got {meta!r:.200}")
    want = {"p": cfg.encoding_p, "F": cfg.encoding_F, "horizon": cfg.horizon, "dt": cfg.dt,
            "constrained_fit": cfg.constrained_fit}
    wrong = [f"{k} = {enc.get(k)!r} (MPC: {v!r})" for k, v in want.items()
             if (abs(float(enc.get(k, float("nan"))) - v) > 1e-9 if k == "dt" else enc.get(k) != v)]
    if meta.get("output_dim", encoded_dim(cfg.encoding)) != encoded_dim(cfg.encoding):
        wrong.append(f"output_dim = {meta.get('output_dim')} (MPC: {encoded_dim(cfg.encoding)})")
    if wrong:
        raise ValueError("the student's encoding does not match the MPC config: " + ", ".join(wrong)
                         + "; distill a student for this encoding (make distill ENCODING=... HORIZON=... DT=...) "
                           "or configure the MPC like the student")


@constant_cache  # a constant per arguments (callers only read it): built once, not per env step
def student_to_mpc_map(cfg: SamplerConfig, dtype: torch.dtype = torch.float32,
                       device: torch.device | str = "cpu") -> tuple[torch.Tensor, torch.Tensor]:
    """(scale, shift), each (D,): the MPC encoding = shift + scale * the student's encoded output.

    Every encoding is linear in the values it encodes, so Table 5's value = shift + scale * raw
    carries over parameter by parameter: f and d get their scale and shift; each p parameter the
    foothold scale; each F parameter its force scale (x, y: 0.025 m g; z: 0.1 m g) and **no shift**,
    because the F_z shift m g / (stance legs) is exactly the gravity compensation that the MPC's
    offsets are taken from (``samples.forces_from_offsets``). A spline's four parameters share their
    scalar's scale (a scaled cubic is the cubic of the scaled parameters); a discrete block repeats the
    28-vector's scales per step.
    """
    enc = cfg.encoding
    scale28 = scale_vector(cfg.action, torch.float64, torch.device("cpu"))
    sl = block_slices(enc)
    scale = torch.zeros(encoded_dim(enc), dtype=torch.float64)
    shift = torch.zeros_like(scale)
    scale[sl["f"]], shift[sl["f"]] = scale28[0:4], cfg.action.freq_shift
    scale[sl["d"]], shift[sl["d"]] = scale28[4:8], cfg.action.duty_shift
    for name, kind, part in (("p", enc.p, scale28[8:16]), ("F", enc.F, scale28[F_SLICE])):
        if kind == "discrete":
            scale[sl[name]] = part.repeat(enc.horizon)
        elif kind == "spline":
            scale[sl[name]] = part.repeat_interleave(SPLINE_PARAMS)
        else:
            scale[sl[name]] = part
    return scale.to(dtype=dtype, device=device), shift.to(dtype=dtype, device=device)


def from_student(output: torch.Tensor, cfg: SamplerConfig) -> torch.Tensor:
    """A student's encoded output (B, D) in raw action units -> the MPC warm start (B, D), physical
    units, F block as offsets from gravity compensation (see :func:`student_to_mpc_map`).

    Raises:
        ValueError: wrong shape. Non-finite rows are passed through (the caller decides the fallback).
    """
    dim = encoded_dim(cfg.encoding)
    if output.dim() != 2 or output.shape[1] != dim:
        raise ValueError(f"student output must have shape (B, {dim}) for the MPC's encoding "
                         f"{cfg.encoding_p}-{cfg.encoding_F} H={cfg.horizon}, got {tuple(output.shape)}")
    scale, shift = student_to_mpc_map(cfg, output.dtype, output.device)
    return shift + scale * output


def student_horizon(output: torch.Tensor, cfg: SamplerConfig, phase: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Decode a student's output to the horizon it stands for, physical units, frame H.

    Returns:
        actions: (B, N, 28) [f, d, p, F] per step with F = stance flag x (offset + m g / stance legs of
            that step), before the Table 1 clip; contact: (B, N, 4) bool, the contact sequence its own
            (f_0, d_0) imply from ``phase`` (B, 4).
    """
    encoded = from_student(output, cfg)
    f, d, p_h, offset_h = decode_parts(encoded, cfg.encoding)
    _, contact = gait.contact_sequence(phase.to(encoded), f, d, cfg.dt, cfg.horizon)
    F_h = forces_from_offsets(offset_h, contact, cfg.action)
    n = cfg.horizon
    actions = torch.cat([f[:, None].expand(-1, n, 4), d[:, None].expand(-1, n, 4), p_h.flatten(-2),
                         F_h.flatten(-2)], dim=-1)
    return actions, contact


def check_shares(shares: tuple[float, ...], students: int) -> None:
    """Raise ``ValueError`` unless ``shares`` has one positive finite share per student, summing to 1."""
    import math

    values = tuple(shares)
    if len(values) != students:
        raise ValueError(f"shares: one per student ({students}), got {len(values)}: {list(values)}")
    bad = [v for v in values if not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0.0]
    if bad:
        raise ValueError(f"shares must be positive finite numbers, got {list(values)}")
    if abs(sum(values) - 1.0) > 1e-6:
        raise ValueError(f"shares must sum to 1, got {list(values)} (sum {sum(values):.6g})")

"""What a sampling-MPC solve accepts: its argument checks, and the torch path's cleaning of the per-robot inputs.

:func:`validate` raises on arguments no solve can use (wrong types or shapes, bad proportions, M < G, a non-finite
warm start, a phase outside [0, 1)); :func:`clean` turns the per-robot inputs into what the kernel may see: a robot
with a non-finite entry in any of them (``solve_glue.INPUT_WIDTHS``: state, phase, base position and yaw, terrain
heights, references) is flagged, and its non-finite entries (the whole state row for the state) become 0. The fused
CPU solve does the same cleaning in C++ (``solve_glue.FusedSolve.costs``); the device solve keeps per-robot flags
(``warp_solve``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch

from dls_quadruped.mpc import solve_glue
from dls_quadruped.mpc.config import SamplerConfig
from dls_quadruped.mpc.cost import Refs
from dls_quadruped.mpc.solution import check_phase, check_tensor
from dls_quadruped.mpc.srbd import SRBDModel, SRBDState, rotation_from_euler

Frame = tuple[torch.Tensor | None, torch.Tensor | None, torch.Tensor | None]
"""``(base_xy_w (B, 2) [m], base_yaw (B,) [rad], terrain_z_w (B, 4) [m])``, each None for its default."""


def validate(cfg: SamplerConfig, dim: int, device: torch.device, state: SRBDState, refs: Refs,
             warm_starts: Sequence[torch.Tensor], proportions: Sequence[float] | None, phase: torch.Tensor,
             read_data: bool = True, frame: Frame = (None, None, None)) -> tuple[torch.Tensor, tuple[float, ...]]:
    """The solve's argument checks (``read_data=False``: only those that read no tensor data).

    Args:
        cfg: the sampler's configuration; ``dim``: its encoded action dimension D.
        device: where the warm starts go.
        state, refs, warm_starts, proportions, phase, frame: :meth:`SamplingMPC.solve`'s arguments.
        read_data: also check that the warm starts are finite and the phase lies in [0, 1).

    Returns:
        (B, G, D) float32 warm starts on ``device``, the G proportions.

    Raises:
        ValueError: naming the argument, what it was and what is allowed.
    """
    if not isinstance(state, SRBDState):
        raise ValueError(f"state must be an SRBDState, got {type(state).__name__}")  # noqa: TRY004
    state.validate()
    b = state.batch_size
    refs.validate(b)
    check_tensor("phase", phase, (b, 4))
    for name, value, shape in zip(("base_xy_w", "base_yaw", "terrain_z_w"), frame, ((b, 2), (b,), (b, 4)),
                                  strict=True):
        if value is not None:
            check_tensor(name, value, shape)
    if read_data:
        check_phase(phase)
    encoding = f"encoding p={cfg.encoding_p!r}, F={cfg.encoding_F!r}"
    if isinstance(warm_starts, torch.Tensor) or len(warm_starts) == 0:
        raise ValueError(f"warm_starts must be a non-empty list of (B, D) or (D,) encoded actions (D = {dim} for "
                         f"{encoding})")
    num_ws = len(warm_starts)
    rows = []
    for g, ws in enumerate(warm_starts):
        if not isinstance(ws, torch.Tensor) or tuple(ws.shape) not in ((b, dim), (dim,)):
            raise ValueError(f"warm_starts[{g}] must have shape (B, D) = ({b}, {dim}) or ({dim},) for {encoding}, "
                             f"H={cfg.horizon}; got {tuple(getattr(ws, 'shape', ()))}")
        if read_data and not solve_glue.all_finite(ws):
            raise ValueError(f"warm_starts[{g}] contains NaN/inf; every entry must be finite")
        rows.append(ws.to(device, torch.float32).expand(b, dim))
    if cfg.num_samples < num_ws:
        raise ValueError(f"num_samples (M = {cfg.num_samples}) must be >= the number of warm starts "
                         f"({num_ws}): each warm start needs at least its own sample")
    if proportions is None:
        if num_ws != 1:
            raise ValueError(f"proportions must be given (one per warm start, summing to 1) for {num_ws} warm "
                             "starts")
        props = (1.0,)
    else:
        props = tuple(float(p) for p in proportions)
        if len(props) != num_ws:
            raise ValueError(f"proportions must have one entry per warm start ({num_ws}), got {len(props)}")
        if any(not (p >= 0.0) for p in props) or not math.isclose(sum(props), 1.0, abs_tol=1e-6):
            raise ValueError(f"proportions must be >= 0 and sum to 1, got {props} (sum {sum(props)})")
    return torch.stack(rows, dim=1), props


def clean(state: SRBDState, refs: Refs, phase: torch.Tensor, frame: Frame, model: SRBDModel,
          device: torch.device) -> tuple[torch.Tensor, dict[str, torch.Tensor], Refs, dict[str, torch.Tensor]]:
    """The per-robot inputs with their non-finite entries zeroed, and which robots had any (module doc).

    Args:
        state, refs, phase: the solve's (B robots), validated.
        frame: the solve's; a missing base position is the one the state's CoM and ``model.com_offset_b`` give,
            a missing yaw the state's, missing terrain heights 0.
        model: the sampler's SRBD model.
        device: where the solve runs.

    Returns:
        x0 (B, 24) the state vector, ``{"phase", "base_xy_w", "base_yaw", "terrain_z_w"}`` float32 on ``device``,
        the references, and (B,) bool flags per input in ``solve_glue.INPUT_WIDTHS`` order (True: not finite).
    """
    b = state.batch_size
    state, refs = state.to(device), refs.to(device)
    bad_inputs: dict[str, torch.Tensor] = {"state": ~state.finite_mask()}
    x0 = torch.where(~bad_inputs["state"][:, None], state.as_vector(), torch.zeros(()).to(device))
    safe_state = SRBDState.from_vector(x0)
    base_xy_w, base_yaw, terrain_z_w = frame
    if base_yaw is None:
        base_yaw = safe_state.euler[:, 2]
    if base_xy_w is None:
        rot = rotation_from_euler(safe_state.euler)
        c_b = torch.tensor(model.com_offset_b, dtype=torch.float32, device=device)
        base_xy_w = (safe_state.com_pos_w - rot @ c_b)[:, :2]
    if terrain_z_w is None:
        terrain_z_w = torch.zeros(b, 4, device=device)
    for name, value, shape in (("base_xy_w", base_xy_w, (b, 2)), ("base_yaw", base_yaw, (b,)),
                               ("terrain_z_w", terrain_z_w, (b, 4))):
        check_tensor(name, value, shape)
    inputs = {"phase": phase, "base_xy_w": base_xy_w, "base_yaw": base_yaw, "terrain_z_w": terrain_z_w,
              "refs.com_height_w": refs.com_height_w, "refs.lin_vel_w": refs.lin_vel_w,
              "refs.yaw_rate": refs.yaw_rate, "refs.foothold_w": refs.foothold_w}
    out = {}
    for name, value in inputs.items():
        value = value.to(device, torch.float32)
        bad_inputs[name] = ~torch.isfinite(value).reshape(b, -1).all(dim=1)
        out[name] = torch.where(torch.isfinite(value), value, torch.zeros((), device=device))
    refs = Refs(out.pop("refs.com_height_w"), out.pop("refs.lin_vel_w"), out.pop("refs.yaw_rate"),
                out.pop("refs.foothold_w"))
    return x0, out, refs, bad_inputs

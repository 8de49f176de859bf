"""Encodings of a horizon of latent actions (thesis 5.1, Appendix A, Table 13).

A horizon is H latent actions, each the 28-vector [f(4), d(4), p_xy(4x2), F_xyz(4x3)] of
:mod:`dls_quadruped.control.latent_action` (frame H, physical units), spaced dt apart.
The encoded flat vector is

    [ f_0 (4) | d_0 (4) | p block | F block ]

where the p block (n = 8 scalars p_x, p_y leg-major) and the F block (n = 12 scalars) are each

* ``discrete``: all H values, step-major, (H, n) flattened            -> H n entries;
* ``first``:    the value at step 0, (n,)                              -> n entries;
* ``spline``:   4 cubic Hermite parameters per scalar, scalar-major,
                (n, 4) flattened as [theta_-1, theta_0, theta_1, theta_2] -> 4 n entries.

Spline grid: sample k of the horizon sits at x_k = k / (H - 1) on [0, 1] (x_0 = 0: theta_0 is the
value at step 0; x_{H-1} = 1: theta_1 is the value at the last step). The spline is
eq. A.1.19: s(x) = a x^3 + b x^2 + c x + d with (a, b, c, d) = C theta (eqs. A.2.2-A.2.5).
Fits are least squares via the normal equations (A.2.9), optionally exact at x_0 (A.3).
"""

from __future__ import annotations

import torch

from dls_quadruped.core.torch_cache import constant_cache
from dls_quadruped.mpc.config import EncodingConfig

ACTION_DIM = 28
GAIT_DIM = 8
P_SCALARS = 8
F_SCALARS = 12
P_SLICE = slice(8, 16)
F_SLICE = slice(16, 28)
SPLINE_PARAMS = 4

HERMITE_TO_POLY = (
    (-0.5, 1.5, -1.5, 0.5),  # a (A.2.2)
    (1.0, -2.5, 2.0, -0.5),  # b (A.2.3)
    (-0.5, 0.0, 0.5, 0.0),  # c (A.2.4)
    (0.0, 1.0, 0.0, 0.0),  # d (A.2.5)
)
"""C with (a, b, c, d)^T = C (theta_-1, theta_0, theta_1, theta_2)^T."""


def block_dim(kind: str, scalars: int, horizon: int) -> int:
    """Entries of one encoded block."""
    return {"discrete": horizon * scalars, "first": scalars, "spline": SPLINE_PARAMS * scalars}[kind]


def encoded_dim(cfg: EncodingConfig) -> int:
    """Length D of the encoded vector, e.g. 108 for discrete-discrete H = 5 (Table 13)."""
    return GAIT_DIM + block_dim(cfg.p, P_SCALARS, cfg.horizon) + block_dim(cfg.F, F_SCALARS, cfg.horizon)


def block_slices(cfg: EncodingConfig) -> dict[str, slice]:
    """Where f, d, the p block and the F block sit in the encoded vector."""
    dp = block_dim(cfg.p, P_SCALARS, cfg.horizon)
    df = block_dim(cfg.F, F_SCALARS, cfg.horizon)
    return {"f": slice(0, 4), "d": slice(4, 8), "p": slice(8, 8 + dp), "F": slice(8 + dp, 8 + dp + df)}


def spline_grid(horizon: int, dtype: torch.dtype = torch.float32, device: torch.device | str = "cpu") -> torch.Tensor:
    """(H,) sample positions x_k = k / (H - 1) on [0, 1]."""
    return torch.linspace(0.0, 1.0, horizon, dtype=dtype, device=device)


@constant_cache  # a constant per arguments (callers only read it): built once, not per solve
def spline_basis(horizon: int, dtype: torch.dtype = torch.float32, device: torch.device | str = "cpu") -> torch.Tensor:
    """(H, 4) matrix Phi with s(x_k) = sum_j Phi[k, j] theta_j, i.e. Phi = [x^3 x^2 x 1] C."""
    x = spline_grid(horizon, torch.float64, device)
    design = torch.stack([x**3, x**2, x, torch.ones_like(x)], dim=-1)  # (H, 4), eq. A.2.8's X
    return (design @ torch.tensor(HERMITE_TO_POLY, dtype=torch.float64, device=device)).to(dtype)


def fit_spline(values: torch.Tensor, constrained: bool) -> torch.Tensor:
    """Least-squares Hermite parameters of each scalar sequence.

    Args:
        values: (..., H, n) sequences sampled on the grid x_k = k / (H - 1), H >= 4.
        constrained: if True, theta_0 = y_0 exactly (A.3) and the other three are least squares.

    Returns:
        (..., n, 4) parameters [theta_-1, theta_0, theta_1, theta_2] per scalar.
    """
    horizon = values.shape[-2]
    if horizon < SPLINE_PARAMS:
        raise ValueError(f"fit_spline needs a horizon H >= 4 to fit 4 parameters, got H = {horizon}")
    basis = spline_basis(horizon, torch.float64, values.device)  # fit in float64: X^T X is ill-conditioned-ish
    y = values.to(torch.float64).transpose(-1, -2).unsqueeze(-1)  # (..., n, H, 1)
    fit = _fit_matrix(horizon, constrained, values.device)
    if not constrained:
        return (fit @ y).squeeze(-1).to(values.dtype)  # eq. A.2.9
    y0 = y[..., :1, :]  # (..., n, 1, 1)
    y_free = y - basis[:, 1:2] * y0  # remove theta_0 = y_0's contribution (A.3's y')
    theta_free = (fit @ y_free).squeeze(-1)  # eq. A.3.2
    theta = torch.cat([theta_free[..., :1], y0[..., 0, :], theta_free[..., 1:]], dim=-1)
    return theta.to(values.dtype)


@constant_cache  # a constant per arguments (callers only read it): built once, not per solve
def _fit_matrix(horizon: int, constrained: bool, device: torch.device | str) -> torch.Tensor:
    """float64 least-squares operator of :func:`fit_spline`: (X^T X)^-1 X^T (4, H) of eq. A.2.9, or of the three
    free columns (3, H) of eq. A.3.2. A constant per horizon: a fit is one matmul, with no linear solve whose error
    check would read the device (``torch.linalg.solve`` on CUDA waits for its status)."""
    basis = spline_basis(horizon, torch.float64, device)
    design = basis if not constrained else basis[:, [0, 2, 3]]  # the columns of theta_-1, theta_1, theta_2
    return torch.linalg.solve(design.T @ design, design.T)


def _encode_block(seq: torch.Tensor, kind: str, constrained: bool) -> torch.Tensor:
    """seq: (..., H, n) -> flat block."""
    if kind == "discrete":
        return seq.flatten(-2)
    if kind == "first":
        return seq[..., 0, :]
    return fit_spline(seq, constrained).flatten(-2)


def _decode_block(block: torch.Tensor, kind: str, scalars: int, horizon: int) -> torch.Tensor:
    """flat block -> (..., H, n)."""
    lead = block.shape[:-1]
    if kind == "discrete":
        return block.unflatten(-1, (horizon, scalars))
    if kind == "first":
        return block.unsqueeze(-2).expand(*lead, horizon, scalars)
    theta = block.unflatten(-1, (scalars, SPLINE_PARAMS))  # (..., n, 4)
    return (theta @ spline_basis(horizon, block.dtype, block.device).T).transpose(-1, -2)  # (..., H, n)


def encode(actions: torch.Tensor, cfg: EncodingConfig) -> torch.Tensor:
    """Encode a horizon of latent actions.

    Args:
        actions: (..., H, 28) with H = cfg.horizon, physical units, frame H.

    Returns:
        (..., D) with D = :func:`encoded_dim`.
    """
    if actions.dim() < 2 or tuple(actions.shape[-2:]) != (cfg.horizon, ACTION_DIM):
        raise ValueError(f"actions must have shape (..., H={cfg.horizon}, {ACTION_DIM}), got {tuple(actions.shape)}")
    gait = actions[..., 0, :GAIT_DIM]  # (f_0, d_0)
    p = _encode_block(actions[..., P_SLICE], cfg.p, cfg.constrained_fit)
    F = _encode_block(actions[..., F_SLICE], cfg.F, cfg.constrained_fit)
    return torch.cat([gait, p, F], dim=-1)


def decode_parts(encoded: torch.Tensor, cfg: EncodingConfig) -> tuple[torch.Tensor, ...]:
    """Decode into its parts.

    Args:
        encoded: (..., D).

    Returns:
        f, d: (..., 4); p_h: (..., H, 4, 2) [m]; F_h: (..., H, 4, 3) [N].
    """
    dim = encoded_dim(cfg)
    if encoded.shape[-1:] != (dim,):
        raise ValueError(
            f"encoded action must have shape (..., {dim}) for encoding p={cfg.p!r}, F={cfg.F!r}, "
            f"H={cfg.horizon}; got {tuple(encoded.shape)}"
        )
    sl = block_slices(cfg)
    p = _decode_block(encoded[..., sl["p"]], cfg.p, P_SCALARS, cfg.horizon)
    F = _decode_block(encoded[..., sl["F"]], cfg.F, F_SCALARS, cfg.horizon)
    return encoded[..., sl["f"]], encoded[..., sl["d"]], p.unflatten(-1, (4, 2)), F.unflatten(-1, (4, 3))


def decode(encoded: torch.Tensor, cfg: EncodingConfig) -> torch.Tensor:
    """Decode to a horizon of latent actions (..., H, 28); f and d are held over the horizon."""
    f, d, p, F = decode_parts(encoded, cfg)
    lead = encoded.shape[:-1]
    gait = torch.cat([f, d], dim=-1).unsqueeze(-2).expand(*lead, cfg.horizon, GAIT_DIM)
    return torch.cat([gait, p.flatten(-2), F.flatten(-2)], dim=-1)


@constant_cache  # a constant per arguments (callers only read it): built once, not per solve
def held_shift_matrix(horizon: int, steps: float, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """(H, H) S with new_k = sum_j S[k, j] old_j = old at time k + steps (linear interp., held at the end)."""
    t = (torch.arange(horizon, dtype=torch.float64) + steps).clamp(0.0, horizon - 1)
    lo = t.floor().long().clamp(max=horizon - 1)
    hi = (lo + 1).clamp(max=horizon - 1)
    w = t - lo
    mat = torch.zeros(horizon, horizon, dtype=torch.float64)
    mat[torch.arange(horizon), lo] += 1 - w
    mat[torch.arange(horizon), hi] += w
    return mat.to(dtype=dtype, device=device)


@constant_cache  # a constant per arguments (callers only read it): built once, not per solve
def _shift_matrix_spline(horizon: int, steps: float, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """(4, 4) T with theta' = T theta and s'(x) = s(x + steps / (H - 1)) (exact for a cubic)."""
    delta = steps / (horizon - 1)
    to_poly = torch.tensor(HERMITE_TO_POLY, dtype=torch.float64)
    # (a, b, c, d) of s(x + delta): Taylor shift of the cubic.
    shift = torch.tensor([
        [1.0, 0.0, 0.0, 0.0],
        [3 * delta, 1.0, 0.0, 0.0],
        [3 * delta**2, 2 * delta, 1.0, 0.0],
        [delta**3, delta**2, delta, 1.0],
    ], dtype=torch.float64)
    return (torch.linalg.inv(to_poly) @ shift @ to_poly).to(dtype=dtype, device=device)


def shift_encoded(encoded: torch.Tensor, cfg: EncodingConfig, steps: float) -> torch.Tensor:
    """Shift an encoded horizon forward in time by ``steps`` horizon steps (naive warm start).

    discrete: value at k becomes the value at k + steps (linear interpolation for a fractional
    shift; the last value is held, so steps = 1 drops the first and repeats the last).
    spline: exact re-parameterisation s'(x) = s(x + steps / (H - 1)) (the tail extrapolates the
    cubic). first and the gait (f_0, d_0): unchanged.

    Args:
        encoded: (..., D).
        steps: shift in horizon steps (MPC period / dt, e.g. 0.5 at 100 Hz with dt = 0.02 s).
    """
    sl = block_slices(cfg)
    out = encoded.clone()
    for name, kind, scalars in (("p", cfg.p, P_SCALARS), ("F", cfg.F, F_SCALARS)):
        block = encoded[..., sl[name]]
        if kind == "discrete":
            mat = held_shift_matrix(cfg.horizon, steps, encoded.dtype, encoded.device)
            new = (mat @ block.unflatten(-1, (cfg.horizon, scalars))).flatten(-2)
        elif kind == "spline":
            mat = _shift_matrix_spline(cfg.horizon, steps, encoded.dtype, encoded.device)
            new = (block.unflatten(-1, (scalars, SPLINE_PARAMS)) @ mat.T).flatten(-2)
        else:
            new = block
        out[..., sl[name]] = new
    return out

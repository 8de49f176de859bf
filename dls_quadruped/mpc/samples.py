"""Drawing, clipping and decoding the sampler's candidate actions (Algorithm 2, lines 2-6).

Pure, batched, eager torch. The reference kernel uses these functions directly; the fast kernel
(:mod:`dls_quadruped.mpc.kernel`) re-states them in a fusion-friendly form and a test checks
the two agree; the controller uses them to re-draw and decode the winning sample.

Sample m of robot b, encoded entry j, is ``ws[b, group[m], j] + perturb[m] sigma_j z_j`` with z the
counter-based normals of :mod:`dls_quadruped.mpc.rng` (pair counter ``(b M + m) D / 2 + j // 2``); ``perturb`` is 0 for
the first sample of every warm-start group (the warm start itself) and 1 otherwise.

Forces are encoded as **offsets from gravity compensation** (the shift of Table 5 in newtons): the F
block decodes to per-step offsets ``dF_i(k)`` (frame H) and the force of leg i at step k is

    F_i(k) = c_i(k) (dF_i(k) + (0, 0, m g / max(sum_j c_j(k), 1)))

with c the sample's own contact sequence, then clipped (Table 1, friction cone). A leg in swing gets
exactly zero force whatever its parameters, and an all-zero F block is the feed-forward posture
(weight shared by the stance legs of each step, also when two or four legs are down).
"""

from __future__ import annotations

import math

import torch

from dls_quadruped.control import gait
from dls_quadruped.control.action_config import LatentActionConfig
from dls_quadruped.core.torch_cache import constant_tensor
from dls_quadruped.mpc.config import SamplerConfig
from dls_quadruped.mpc.encodings import P_SCALARS, block_dim, decode_parts, encoded_dim
from dls_quadruped.mpc.rng import normals


def sigma_vector(cfg: SamplerConfig) -> tuple[float, ...]:
    """Per encoded entry noise std: sigma_f, sigma_d, sigma_p (whole p block), sigma_F (whole F block)."""
    enc = cfg.encoding
    return ((cfg.sigma_f,) * 4 + (cfg.sigma_d,) * 4 + (cfg.sigma_p,) * block_dim(enc.p, P_SCALARS, enc.horizon)
            + (cfg.sigma_F,) * block_dim(enc.F, 12, enc.horizon))


def encoded_bounds(cfg: SamplerConfig) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Box limits (lo, hi) per encoded entry (Table 1): f, d, and p when it is not a spline.

    Spline parameters are not points of the curve, so their limits are applied after decoding
    (:func:`clip_horizon`); forces are always clipped after decoding (the friction cone is not a box).
    """
    act, enc = cfg.action, cfg.encoding
    inf = math.inf
    lo = [act.freq_range[0]] * 4 + [act.duty_range[0]] * 4
    hi = [act.freq_range[1]] * 4 + [act.duty_range[1]] * 4
    n_p = block_dim(enc.p, P_SCALARS, enc.horizon)
    if enc.p == "spline":
        lo += [-inf] * n_p
        hi += [inf] * n_p
    else:  # (x, y) pairs, leg-major, repeated per step for discrete
        lo += [act.foothold_x_range[0], act.foothold_y_range[0]] * (n_p // 2)
        hi += [act.foothold_x_range[1], act.foothold_y_range[1]] * (n_p // 2)
    n_f = block_dim(enc.F, 12, enc.horizon)
    return tuple(lo + [-inf] * n_f), tuple(hi + [inf] * n_f)


def group_layout(num_samples: int,
                 proportions: tuple[float, ...]) -> tuple[torch.Tensor, torch.Tensor, tuple[int, ...]]:
    """Split M samples into warm-start groups (largest-remainder rounding, at least 1 each).

    Returns:
        group: (M,) long, warm-start index of each sample;
        perturb: (M,) float32, 0 for the first sample of each group (the warm start itself), else 1;
        counts: samples per group.
    """
    raw = [p * num_samples for p in proportions]
    counts = [max(1, math.floor(r)) for r in raw]
    order = sorted(range(len(raw)), key=lambda g: raw[g] - math.floor(raw[g]), reverse=True)
    i = 0
    while sum(counts) < num_samples:
        counts[order[i % len(order)]] += 1
        i += 1
    while sum(counts) > num_samples:  # only when the "at least 1" rule over-allocated
        g = max(range(len(counts)), key=lambda k: counts[k])
        counts[g] -= 1
    group = torch.repeat_interleave(torch.arange(len(counts)), torch.tensor(counts))
    starts = torch.tensor([0] + counts[:-1]).cumsum(0)
    perturb = torch.ones(num_samples)
    perturb[starts] = 0.0
    return group, perturb, tuple(counts)


def sample_encoded(
    seed: torch.Tensor, warm_starts: torch.Tensor, group: torch.Tensor, perturb: torch.Tensor,
    sample_idx: torch.Tensor, cfg: SamplerConfig,
) -> torch.Tensor:
    """Draw (or re-draw) samples and clip them to the encoded box limits.

    Args:
        seed: () int64.
        warm_starts: (B, G, D) encoded warm starts.
        group, perturb: (M,) from :func:`group_layout`.
        sample_idx: (B, K) long, which samples (0 <= m < M) to produce.
        cfg: sampler config.

    Returns:
        (B, K, D) encoded samples.
    """
    b, _, dim = warm_starts.shape
    m_total = group.shape[0]
    device, dtype = warm_starts.device, warm_starts.dtype
    rows = torch.arange(b, device=device)[:, None]
    center = warm_starts[rows, group[sample_idx]]  # (B, K, D)
    counter0 = (rows * m_total + sample_idx) * (dim // 2)  # first noise-pair counter of each sample
    sigma = constant_tensor(tuple(sigma_vector(cfg)), dtype, device)
    noise = normals(seed, counter0, dim)
    samples = center + perturb[sample_idx][..., None] * sigma * noise
    lo, hi = (constant_tensor(tuple(v), dtype, device) for v in encoded_bounds(cfg))
    return torch.minimum(torch.maximum(samples, lo), hi)


def forces_from_offsets(offset_h: torch.Tensor, contact: torch.Tensor, act: LatentActionConfig) -> torch.Tensor:
    """F = c (dF + (0, 0, m g / max(sum_j c_j, 1))) per step (see the module doc), not yet clipped.

    Args:
        offset_h: (..., 4, 3) [N] decoded force offsets, frame H.
        contact: (..., 4) bool stance flags of the same step(s).

    Returns:
        (..., 4, 3) [N] forces, frame H; zero for legs in swing.
    """
    c = contact.to(offset_h.dtype)
    shift_z = act.weight / c.sum(dim=-1, keepdim=True).clamp_min(1.0)  # (..., 1) m g / number of stance legs
    return torch.stack([c * offset_h[..., 0], c * offset_h[..., 1], c * (offset_h[..., 2] + shift_z)], dim=-1)


def offsets_from_forces(F_h: torch.Tensor, contact: torch.Tensor, act: LatentActionConfig) -> torch.Tensor:
    """Inverse of :func:`forces_from_offsets` on stance legs; legs in swing get a zero offset.

    Args:
        F_h: (..., 4, 3) [N] forces in physical units, frame H; contact: (..., 4) bool.
    """
    c = contact.to(F_h.dtype)
    shift_z = act.weight / c.sum(dim=-1, keepdim=True).clamp_min(1.0)
    return torch.stack([c * F_h[..., 0], c * F_h[..., 1], c * (F_h[..., 2] - shift_z)], dim=-1)


def clip_horizon(p_h: torch.Tensor, F_h: torch.Tensor, act: LatentActionConfig) -> tuple[torch.Tensor, torch.Tensor]:
    """Table 1 limits on decoded values: p box, F_z in range, ||F_xy|| <= mu F_z (radial scaling).

    Args:
        p_h: (..., 4, 2) [m]; F_h: (..., 4, 3) [N]; frame H.
    """
    p_x = p_h[..., 0].clamp(*act.foothold_x_range)
    p_y = p_h[..., 1].clamp(*act.foothold_y_range)
    f_z = F_h[..., 2].clamp(act.force_z_range_frac[0] * act.weight, act.force_z_range_frac[1] * act.weight)
    norm_xy = torch.sqrt(F_h[..., 0] ** 2 + F_h[..., 1] ** 2)
    limit = act.mu * f_z
    factor = torch.where(norm_xy > limit, limit / norm_xy.clamp_min(1e-12), 1.0)
    F = torch.stack([F_h[..., 0] * factor, F_h[..., 1] * factor, f_z], dim=-1)
    return torch.stack([p_x, p_y], dim=-1), F


def horizontal_to_world(
    p_h: torch.Tensor, F_h: torch.Tensor, base_xy_w: torch.Tensor, base_yaw: torch.Tensor, terrain_z_w: torch.Tensor,
    act: LatentActionConfig,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Touch-down targets and forces in the world frame (same map as latent_action.to_world).

    target_xy = base_xy + Rz(yaw) (nominal_xy + p_h); target_z = terrain_z + foot radius; F_w = Rz(yaw) F_h.

    Args:
        p_h: (B, ..., 4, 2); F_h: (B, ..., 4, 3); base_xy_w: (B, 2); base_yaw: (B,); terrain_z_w: (B, 4)
            ground height under each leg's nominal foothold (used for every sample and step).
    """
    extra = p_h.dim() - 3  # dims between B and the leg dim
    shape = (-1,) + (1,) * extra
    c, s = torch.cos(base_yaw).view(*shape, 1), torch.sin(base_yaw).view(*shape, 1)
    nominal = constant_tensor(tuple(map(tuple, act.nominal_foothold_b)), p_h.dtype, p_h.device)
    q = nominal + p_h
    x = base_xy_w[:, 0].view(*shape, 1) + c * q[..., 0] - s * q[..., 1]
    y = base_xy_w[:, 1].view(*shape, 1) + s * q[..., 0] + c * q[..., 1]
    z = (terrain_z_w + act.foot_radius).view(terrain_z_w.shape[0], *((1,) * extra), 4).expand_as(x)
    F_w = torch.stack([c * F_h[..., 0] - s * F_h[..., 1], s * F_h[..., 0] + c * F_h[..., 1], F_h[..., 2]], dim=-1)
    return torch.stack([x, y, z], dim=-1), F_w


def decode_samples(
    samples: torch.Tensor, phase: torch.Tensor, base_xy_w: torch.Tensor, base_yaw: torch.Tensor,
    terrain_z_w: torch.Tensor, cfg: SamplerConfig,
) -> dict[str, torch.Tensor]:
    """Encoded samples -> clipped horizon in both frames and the contact sequence.

    Args:
        samples: (B, K, D); phase: (B, 4) current gait phase.

    Returns:
        dict with f, d (B, K, 4); p_h (B, K, N, 4, 2); F_h (B, K, N, 4, 3) physical forces (offsets plus
        gravity compensation, zero in swing, clipped); foot_target_w, force_w (B, K, N, 4, 3); contact
        (B, K, N, 4) bool.
    """
    assert samples.shape[-1] == encoded_dim(cfg.encoding)
    f, d, p_h, offset_h = decode_parts(samples, cfg.encoding)
    _, contact = gait.contact_sequence(phase[:, None, :], f, d, cfg.dt, cfg.horizon)
    p_h, F_h = clip_horizon(p_h, forces_from_offsets(offset_h, contact, cfg.action), cfg.action)
    foot_target_w, force_w = horizontal_to_world(p_h, F_h, base_xy_w, base_yaw, terrain_z_w, cfg.action)
    return {"f": f, "d": d, "p_h": p_h, "F_h": F_h, "foot_target_w": foot_target_w, "force_w": force_w,
            "contact": contact}


__all__ = [
    "clip_horizon",
    "decode_samples",
    "encoded_bounds",
    "forces_from_offsets",
    "group_layout",
    "horizontal_to_world",
    "offsets_from_forces",
    "sample_encoded",
    "sigma_vector",
]

"""Sample costs of one solve: the plain eager ``reference`` kernel and the fused ``fast`` kernel.

Both map the same inputs (:class:`KernelInputs`) to the (B, M) rollout costs of all samples:
draw -> clip -> decode -> contact sequence -> forces from offsets (gravity compensation per step, zero
in swing: :func:`samples.forces_from_offsets`) -> frames -> SRBD rollout -> cost (Algorithm 2).

* ``reference``: the straightforward batched formulation (tensors (B, M, N, 4, 3), cross products,
  matmuls, a Python loop over the N steps only), built from :mod:`samples`, :mod:`srbd`, :mod:`cost`.
* ``fast``: the same maths written per scalar on (B, M) tensors - legs, coordinates and the N steps
  unrolled in Python, spline bases, limits, inertia and weights baked in as constants, the yaw trig
  of the horizontal frame computed once - so that torch.compile (inductor: fused C++/OpenMP on CPU,
  Triton on CUDA) emits one elementwise loop over samples with the noise generated in registers and
  no intermediate tensors. If compilation fails it runs the same function eagerly, with a warning.
* ``cpp``: the same per-sample maths in hand-written C++ (:mod:`cpp_kernel`, ``rollout_kernel.cpp``),
  built at first use; CPU only. On another device, or if it cannot be built, ``fast`` runs instead.
"""

from __future__ import annotations

import dataclasses
import functools
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import torch

from dls_quadruped.mpc import cpp_kernel
from dls_quadruped.mpc.config import SamplerConfig
from dls_quadruped.mpc.cost import Refs, rollout_cost_reference
from dls_quadruped.mpc.encodings import (
    P_SCALARS,
    SPLINE_PARAMS,
    block_slices,
    encoded_dim,
    spline_basis,
)
from dls_quadruped.mpc.rng import normal_pair
from dls_quadruped.mpc.samples import (
    decode_samples,
    encoded_bounds,
    sample_encoded,
    sigma_vector,
)
from dls_quadruped.mpc.srbd import SRBDModel


@dataclass
class KernelInputs:
    """Everything one solve needs, on one device (B robots, G warm starts, M samples).

    Attributes:
        seed: () int64 noise seed.
        warm_starts: (B, G, D) encoded warm starts.
        group: (M,) long warm-start group of each sample; perturb: (M,) float 0/1.
        x0: (B, 24) SRBD state vector.
        phase: (B, 4) gait phase at step 0.
        base_xy_w: (B, 2) [m], base_yaw: (B,) [rad]: the horizontal frame.
        terrain_z_w: (B, 4) [m] ground height under the nominal footholds.
        refs: cost references.
    """

    seed: torch.Tensor
    warm_starts: torch.Tensor
    group: torch.Tensor
    perturb: torch.Tensor
    x0: torch.Tensor
    phase: torch.Tensor
    base_xy_w: torch.Tensor
    base_yaw: torch.Tensor
    terrain_z_w: torch.Tensor
    refs: Refs


def reference_costs(inp: KernelInputs, cfg: SamplerConfig, model: SRBDModel) -> torch.Tensor:
    """(B, M) costs, straightforward eager torch (the in-run reference)."""
    b, m = inp.x0.shape[0], inp.group.shape[0]
    idx = torch.arange(m, device=inp.x0.device).expand(b, m)
    samples = sample_encoded(inp.seed, inp.warm_starts, inp.group, inp.perturb, idx, cfg)
    dec = decode_samples(samples, inp.phase, inp.base_xy_w, inp.base_yaw, inp.terrain_z_w, cfg)
    return rollout_cost_reference(inp.x0, dec["contact"], dec["foot_target_w"], dec["force_w"], inp.refs, model,
                                  cfg.weights, cfg.dt)


def _build_fused(cfg: SamplerConfig, model: SRBDModel) -> Callable[..., torch.Tensor]:
    """The fused cost function for one (config, model); pure torch, compiles or runs eagerly."""
    enc, act, w = cfg.encoding, cfg.action, cfg.weights
    n_steps, dt, dim = cfg.horizon, cfg.dt, encoded_dim(cfg.encoding)
    sl = block_slices(enc)
    sigma = sigma_vector(cfg)
    lo, hi = encoded_bounds(cfg)
    basis = spline_basis(n_steps, torch.float64).tolist()  # (N, 4) python floats
    nominal = act.nominal_foothold_b
    fz_lo, fz_hi = (frac * act.weight for frac in act.force_z_range_frac)
    px_lo, px_hi = act.foothold_x_range
    py_lo, py_hi = act.foothold_y_range
    mu, mass, grav = act.mu, model.mass, model.gravity
    weight = act.weight  # gravity compensation of the force offsets (Table 5 shift)
    inertia = torch.tensor(model.inertia_b, dtype=torch.float64)
    I = inertia.tolist()
    Ii = torch.linalg.inv(inertia).tolist()

    def block_values(P: list, kind: str, start: int, scalars: int, scalar: int) -> list:
        """Per-step decoded value of one scalar of a block, as a list over the N steps."""
        if kind == "first":
            return [P[start + scalar]] * n_steps
        if kind == "discrete":
            return [P[start + k * scalars + scalar] for k in range(n_steps)]
        th = [P[start + scalar * SPLINE_PARAMS + j] for j in range(SPLINE_PARAMS)]
        return [basis[k][0] * th[0] + basis[k][1] * th[1] + basis[k][2] * th[2] + basis[k][3] * th[3]
                for k in range(n_steps)]

    def fused(seed, offset, m_total, warm_starts, group, perturb, x0, phase, base_xy_w, base_yaw, terrain_z_w,
              com_height_w, lin_vel_w, yaw_rate, foothold_w):
        # group/perturb: (C,) the chunk of samples offset .. offset + C - 1 out of m_total
        b, m = x0.shape[0], group.shape[0]
        device = x0.device
        rows = torch.arange(b, device=device)[:, None]
        counter0 = (rows * m_total + offset + torch.arange(m, device=device)[None, :]) * (dim // 2)  # (B, C)
        # warm start of each sample by a select chain over the G groups (G is static): a gather
        # warm_starts[rows, group] would be scalarised lane by lane in inductor's vector code
        is_group = [group[None, :] == g for g in range(1, warm_starts.shape[1])]
        pert = perturb[None, :]
        P = []  # encoded entries, each (B, M)
        for j in range(dim):
            v = warm_starts[:, 0, j:j + 1].expand(b, m)
            for g, mask in enumerate(is_group, start=1):
                v = torch.where(mask, warm_starts[:, g, j:j + 1], v)
            if j % 2 == 0 and (sigma[j] > 0.0 or sigma[j + 1] > 0.0):
                z_pair = normal_pair(seed, counter0 + j // 2)
            if sigma[j] > 0.0:
                v = v + pert * (sigma[j] * z_pair[j % 2])
            if lo[j] > -float("inf"):
                v = torch.clamp(v, lo[j], hi[j])
            P.append(v)
        cyaw, syaw = torch.cos(base_yaw)[:, None], torch.sin(base_yaw)[:, None]  # frame H, once
        bx, by = base_xy_w[:, 0:1], base_xy_w[:, 1:2]

        # contact flags c[k][i] (same closed form as gait.contact_sequence)
        c = [[None] * 4 for _ in range(n_steps)]
        for i in range(4):
            fdt = P[i] * dt
            for k in range(n_steps):
                c[k][i] = (torch.remainder(phase[:, i:i + 1] + k * fdt, 1.0) < P[4 + i]).to(x0.dtype)

        # touch-down targets (world) and their R cost per step
        tgt = [[None] * 4 for _ in range(n_steps)]
        r_cost = [None] * n_steps
        for i in range(4):
            pxs = block_values(P, enc.p, sl["p"].start, P_SCALARS, 2 * i)
            pys = block_values(P, enc.p, sl["p"].start, P_SCALARS, 2 * i + 1)
            tz = terrain_z_w[:, i:i + 1] + act.foot_radius
            for k in range(n_steps):
                if enc.p == "first" and k > 0:
                    tgt[k][i] = tgt[0][i]
                    continue
                qx = torch.clamp(pxs[k], px_lo, px_hi) + nominal[i][0]
                qy = torch.clamp(pys[k], py_lo, py_hi) + nominal[i][1]
                tgt[k][i] = (bx + cyaw * qx - syaw * qy, by + syaw * qx + cyaw * qy, tz)
        for k in range(n_steps):
            if enc.p == "first" and k > 0:
                r_cost[k] = r_cost[0]
                continue
            acc = 0.0
            for i in range(4):
                ex = tgt[k][i][0] - foothold_w[:, i, 0:1]
                ey = tgt[k][i][1] - foothold_w[:, i, 1:2]
                acc = acc + w.foothold_xy * (ex * ex + ey * ey)
            r_cost[k] = acc

        # forces (world): offsets + m g / (stance legs of the step), zero in swing (samples.forces_from_offsets),
        # clipped to Table 1 and the friction cone
        shift = [weight / torch.clamp(c[k][0] + c[k][1] + c[k][2] + c[k][3], min=1.0) for k in range(n_steps)]
        frc = [[None] * 4 for _ in range(n_steps)]
        for i in range(4):
            fxs, fys, fzs = (block_values(P, enc.F, sl["F"].start, 12, 3 * i + a) for a in range(3))
            for k in range(n_steps):
                ci = c[k][i]
                fz = torch.clamp(ci * (fzs[k] + shift[k]), fz_lo, fz_hi)
                fxr, fyr = ci * fxs[k], ci * fys[k]
                nxy = torch.sqrt(fxr * fxr + fyr * fyr)
                lim = mu * fz
                scale = torch.where(nxy > lim, lim / torch.clamp(nxy, min=1e-12), 1.0)
                fx, fy = fxr * scale, fyr * scale
                frc[k][i] = (cyaw * fx - syaw * fy, syaw * fx + cyaw * fy, fz)

        # rollout (explicit Euler) and state cost
        px, py, pz, vx, vy, vz, ro, pi, ya, wx, wy, wz = (x0[:, j:j + 1] for j in range(12))
        feet = [tuple(x0[:, 12 + 3 * i + a:13 + 3 * i + a] for a in range(3)) for i in range(4)]
        h_ref, vx_ref, vy_ref, wz_ref = com_height_w[:, None], lin_vel_w[:, 0:1], lin_vel_w[:, 1:2], yaw_rate[:, None]
        total = 0.0
        for k in range(n_steps):
            sfx = sfy = sfz = 0.0
            tx = ty = tz = 0.0
            new_feet = []
            for i in range(4):
                ci = c[k][i]
                fx, fy, fz = (ci * frc[k][i][a] for a in range(3))
                rx, ry, rz = feet[i][0] - px, feet[i][1] - py, feet[i][2] - pz
                sfx, sfy, sfz = sfx + fx, sfy + fy, sfz + fz
                tx, ty, tz = tx + ry * fz - rz * fy, ty + rz * fx - rx * fz, tz + rx * fy - ry * fx
                new_feet.append(tuple(feet[i][a] + (1.0 - ci) * (tgt[k][i][a] - feet[i][a]) for a in range(3)))
            cr, sr, cp, sp = torch.cos(ro), torch.sin(ro), torch.cos(pi), torch.sin(pi)
            cy, sy = torch.cos(ya), torch.sin(ya)
            # R = Rz Ry Rx; torque_b = R^T torque_w (columns of R dotted with torque_w)
            r00, r10, r20 = cy * cp, sy * cp, -sp
            r01, r11, r21 = cy * sp * sr - sy * cr, sy * sp * sr + cy * cr, cp * sr
            r02, r12, r22 = cy * sp * cr + sy * sr, sy * sp * cr - cy * sr, cp * cr
            tbx = r00 * tx + r10 * ty + r20 * tz
            tby = r01 * tx + r11 * ty + r21 * tz
            tbz = r02 * tx + r12 * ty + r22 * tz
            iwx = I[0][0] * wx + I[0][1] * wy + I[0][2] * wz
            iwy = I[1][0] * wx + I[1][1] * wy + I[1][2] * wz
            iwz = I[2][0] * wx + I[2][1] * wy + I[2][2] * wz
            hx, hy, hz = tbx - (wy * iwz - wz * iwy), tby - (wz * iwx - wx * iwz), tbz - (wx * iwy - wy * iwx)
            dwx = Ii[0][0] * hx + Ii[0][1] * hy + Ii[0][2] * hz
            dwy = Ii[1][0] * hx + Ii[1][1] * hy + Ii[1][2] * hz
            dwz = Ii[2][0] * hx + Ii[2][1] * hy + Ii[2][2] * hz
            tp = sp / cp  # eq. C.2.3
            dro = wx + sr * tp * wy + cr * tp * wz
            dpi = cr * wy - sr * wz
            dya = (sr * wy + cr * wz) / cp
            px, py, pz = px + dt * vx, py + dt * vy, pz + dt * vz
            vx, vy, vz = vx + dt * (sfx / mass), vy + dt * (sfy / mass), vz + dt * (sfz / mass - grav)
            ro, pi, ya = ro + dt * dro, pi + dt * dpi, ya + dt * dya
            wx, wy, wz = wx + dt * dwx, wy + dt * dwy, wz + dt * dwz
            feet = new_feet
            ez, evx, evy, ewz = pz - h_ref, vx - vx_ref, vy - vy_ref, wz - wz_ref
            total = total + (w.z * ez * ez + w.vx * evx * evx + w.vy * evy * evy + w.vz * vz * vz
                             + w.roll * ro * ro + w.pitch * pi * pi + w.roll_rate * wx * wx
                             + w.pitch_rate * wy * wy + w.yaw_rate * ewz * ewz + r_cost[k])
        total = total + torch.zeros_like(P[0])  # (B, M) even if nothing depends on the samples
        return torch.where(torch.isnan(total), torch.full_like(total, float("inf")), total)

    return fused


@functools.lru_cache(maxsize=64)
def _fast_fn(cfg: SamplerConfig, model: SRBDModel, compiled: bool) -> Callable[..., torch.Tensor]:
    fused = _build_fused(cfg, model)
    if not compiled:
        return fused
    return torch.compile(fused, dynamic=False, fullgraph=True, options=_INDUCTOR_OPTIONS)


# Realise shared intermediates early so the unrolled graph is not re-inlined into every use.
# Chosen from a handful of trials on the 2-core dev machine (defaults, one giant fused loop via a
# large max_fusion_size, dynamic M); the timings there are dominated by core contention, so
# re-tune on a quiet machine.
_INDUCTOR_OPTIONS = {"realize_opcount_threshold": 4, "realize_reads_threshold": 2}
CHUNK = 4096
"""Samples per compiled-kernel call on the CPU. Static shapes vectorise and parallelise better than a dynamic M
(measured), and a fixed chunk makes one compilation serve every M (the last chunk is padded)."""
CUDA_CHUNK_MAX = 1 << 17
"""On CUDA, M runs as one chunk of the next power of two >= M (at least :data:`CHUNK`, one compilation per size),
up to this: 4 096-sample calls left an H100 mostly idle (M = 100 000: 25 calls, 88 ms of kernel)."""


def chunk_size(m: int, device: torch.device, compiled: bool = True) -> int:
    """Samples per kernel call for M = ``m`` on ``device`` (the last chunk is padded to it)."""
    if not compiled:
        return min(CHUNK, m)
    if device.type == "cuda":
        return min(CUDA_CHUNK_MAX, max(CHUNK, 1 << (m - 1).bit_length()))
    return CHUNK

_COMPILE_FAILED: set[tuple] = set()


def fast_costs(inp: KernelInputs, cfg: SamplerConfig, model: SRBDModel, compiled: bool = True) -> torch.Tensor:
    """(B, M) costs with the fused kernel (compiled unless ``compiled=False`` or compilation failed).

    The samples are processed in chunks of :data:`CHUNK` by the same compiled function (the noise
    counters use the global sample index, so chunking does not change any number).
    """
    m = inp.group.shape[0]
    dev = inp.x0.device
    chunk = chunk_size(m, dev, compiled)
    num_chunks = -(-m // chunk)
    pad = num_chunks * chunk - m
    group, perturb = inp.group, inp.perturb
    if pad:
        group = torch.cat([group, group.new_zeros(pad)])
        perturb = torch.cat([perturb, perturb.new_ones(pad)])
    # built on the device (fill, arange) rather than uploaded: no host-to-device copy per call or per chunk
    m_total = torch.full((), m, dtype=torch.int64, device=dev)
    offsets = torch.arange(num_chunks, dtype=torch.int64, device=dev) * chunk
    rest = (inp.warm_starts, inp.x0, inp.phase, inp.base_xy_w, inp.base_yaw, inp.terrain_z_w, inp.refs.com_height_w,
            inp.refs.lin_vel_w, inp.refs.yaw_rate, inp.refs.foothold_w)
    # M is not a constant of the kernel: one compiled function per everything-but-M
    cfg = dataclasses.replace(cfg, num_samples=1, kernel="fast")
    key = (cfg, model, inp.x0.device.type)
    fn = None
    if compiled and key not in _COMPILE_FAILED:
        fn = _fast_fn(cfg, model, True)
    out = []
    for c in range(num_chunks):
        args = (inp.seed, offsets[c], m_total, inp.warm_starts, group[c * chunk:(c + 1) * chunk],
                perturb[c * chunk:(c + 1) * chunk], *rest[1:])
        if fn is not None:
            try:
                out.append(fn(*args))
                continue
            except Exception as err:  # noqa: BLE001 - inductor/compiler missing or broken: stay correct, just slower
                _COMPILE_FAILED.add(key)
                fn = None
                warnings.warn(f"torch.compile of the MPC kernel failed ({type(err).__name__}: {err}); "
                              f"falling back to the eager fused kernel", RuntimeWarning, stacklevel=2)
        out.append(_fast_fn(cfg, model, False)(*args))
    return torch.cat(out, dim=1)[:, :m]


def cpp_costs(inp: KernelInputs, cfg: SamplerConfig, model: SRBDModel) -> torch.Tensor:
    """(B, M) costs with the C++ kernel on CPU tensors (threads: ``torch.get_num_threads()``).

    Falls back to :func:`fast_costs` on a non-CPU device, or (after one ``RuntimeWarning``) when the
    C++ library cannot be built.
    """
    lib = cpp_kernel.load() if inp.x0.device.type == "cpu" else None
    if lib is None:
        return fast_costs(inp, cfg, model)
    return cpp_kernel.cpp_costs(inp, cfg, model, lib)

"""The ``warp`` kernel: the sampling MPC's rollouts in one Warp kernel, one thread per sample, CPU or CUDA.

Same inputs, semantics and float32 maths as ``rollout_kernel.cpp`` (the ``cpp`` kernel), read line by line: the
thread of (robot b, sample m) draws its D encoded entries from the counter hash (pair counter (b M + m) D / 2 +
j / 2, the seed read from a device array), perturbs and box-clips them around its warm start, then runs the N
steps in registers -- decode (the per-step table of <= 4 weighted encoded entries per decoded scalar,
``cpp_kernel.decode_tables``), contacts, forces from gravity-compensation offsets, Table 1 limits, frame H ->
world, explicit-Euler SRBD and the quadratic cost -- and writes its cost (NaN -> +inf). The encoded sample lives
in a per-thread vector of D entries (D rounded up to a bucket of :data:`BUCKETS`: one compiled module per
bucket, not per encoding).

The per-robot argmin runs on the device too (``warp_argmin.py``).

:func:`warp_costs` is the kernel registry's ``warp`` entry ((B, M) costs of a ``KernelInputs`` on its torch
device: ``cpu`` runs on Warp's CPU device, ``cuda:k`` on that GPU); ``warp_solve.py`` drives the same kernels in
the solve without host synchronisation.
"""

from __future__ import annotations

import functools

import torch
import warp as wp

from dls_quadruped.mpc import cpp_kernel
from dls_quadruped.mpc.config import SamplerConfig
from dls_quadruped.mpc.encodings import encoded_dim
from dls_quadruped.mpc.srbd import SRBDModel
from dls_quadruped.mpc.warp_math import clampf, normal_pair, seed_key, sincos_f

BUCKETS = (64, 128, 256, 512)
"""Lengths of the per-thread sample vector: a kernel is compiled per bucket (D <= bucket)."""
_INITIALISED = False
_ENABLE_BACKWARD = False  # no gradients: halves the generated code and Warp's compile time


def bucket(dim: int) -> int:
    """The sample-vector length that holds D = ``dim`` entries; ValueError past the largest."""
    for size in BUCKETS:
        if dim <= size:
            return size
    raise ValueError(f"the warp MPC kernel holds at most {BUCKETS[-1]} encoded entries per sample, got D = {dim}")


def init() -> None:
    """``wp.init()`` once, quietly (Warp prints its device table otherwise)."""
    global _INITIALISED
    if not _INITIALISED:
        wp.config.quiet = True
        wp.init()  # a no-op if Warp is already initialised
        _INITIALISED = True


def wp_device(device: torch.device) -> str:
    """Warp's name of a torch device: ``cpu`` or ``cuda:k``."""
    if device.type == "cpu":
        return "cpu"
    if device.type == "cuda":
        return f"cuda:{device.index if device.index is not None else torch.cuda.current_device()}"
    raise ValueError(f"the warp MPC kernel runs on cpu or cuda devices, got {device}")


@functools.lru_cache(maxsize=len(BUCKETS))
def rollout_kernel(size: int):
    """The rollout + cost kernel whose samples hold up to ``size`` encoded entries (one of :data:`BUCKETS`)."""
    vec_d = wp.types.vector(length=size, dtype=wp.float32)
    vec20 = wp.types.vector(length=20, dtype=wp.float32)
    vec12 = wp.types.vector(length=12, dtype=wp.float32)

    @wp.kernel(enable_backward=_ENABLE_BACKWARD, module="unique")
    def rollout(m_total: int, n_steps: int, g_total: int, dim: int, seed: wp.array(dtype=wp.int64),
                prm: wp.array(dtype=wp.float32), sigma: wp.array(dtype=wp.float32), lo: wp.array(dtype=wp.float32),
                hi: wp.array(dtype=wp.float32), dec_idx: wp.array(dtype=wp.int32), dec_w: wp.array(dtype=wp.float32),
                warm: wp.array(dtype=wp.float32), group: wp.array(dtype=wp.int64), perturb: wp.array(dtype=wp.float32),
                x0: wp.array(dtype=wp.float32), phase: wp.array(dtype=wp.float32), base_xy: wp.array(dtype=wp.float32),
                base_yaw: wp.array(dtype=wp.float32), terrain_z: wp.array(dtype=wp.float32),
                h_ref: wp.array(dtype=wp.float32), vel_ref: wp.array(dtype=wp.float32),
                wz_ref: wp.array(dtype=wp.float32), foothold: wp.array(dtype=wp.float32),
                costs: wp.array2d(dtype=wp.float32)):
        b, m = wp.tid()
        key = seed_key(seed[0])
        dt, mass, grav = prm[0], prm[1], prm[2]
        mu, fz_lo, fz_hi = prm[21], prm[22], prm[23]
        px_lo, px_hi, py_lo, py_hi = prm[24], prm[25], prm[26], prm[27]
        foot_r, weight = prm[36], prm[47]
        # ---- draw and box-clip the encoded sample (samples.sample_encoded)
        pm = perturb[m]
        wb = (b * g_total + wp.int32(group[m])) * dim
        half_d = wp.uint32(dim // 2)
        row = wp.uint32(b) * wp.uint32(m_total) + wp.uint32(m)
        P = vec_d()
        for j in range(0, dim, 2):
            z = normal_pair(row * half_d + wp.uint32(j // 2), key)
            P[j] = clampf(warm[wb + j] + pm * (sigma[j] * z[0]), lo[j], hi[j])
            P[j + 1] = clampf(warm[wb + j + 1] + pm * (sigma[j + 1] * z[1]), lo[j + 1], hi[j + 1])
        # ---- rollout state
        xb = b * 24
        px, py, pz = float(x0[xb + 0]), float(x0[xb + 1]), float(x0[xb + 2])
        vx, vy, vz = float(x0[xb + 3]), float(x0[xb + 4]), float(x0[xb + 5])
        ro, pi, ya = float(x0[xb + 6]), float(x0[xb + 7]), float(x0[xb + 8])
        wx, wy, wz = float(x0[xb + 9]), float(x0[xb + 10]), float(x0[xb + 11])
        feet = vec12()
        for a in range(12):
            feet[a] = x0[xb + 12 + a]
        total = wp.float32(0.0)  # a dynamic variable: a plain literal is a constant to Warp
        yaw_sc = wp.vec2(wp.sin(base_yaw[b]), wp.cos(base_yaw[b]))  # std::sin / std::cos of the frame's yaw
        syaw, cyaw = yaw_sc[0], yaw_sc[1]
        bx, by = base_xy[2 * b], base_xy[2 * b + 1]
        hr, vxr, vyr, wzr = h_ref[b], vel_ref[2 * b], vel_ref[2 * b + 1], wz_ref[b]
        for k in range(n_steps):
            dv = vec20()  # decoded p_h (0..7) and F_h (8..19) of step k
            for s in range(20):
                t = (k * 20 + s) * 4
                dv[s] = (dec_w[t] * P[dec_idx[t]] + dec_w[t + 1] * P[dec_idx[t + 1]]
                         + dec_w[t + 2] * P[dec_idx[t + 2]] + dec_w[t + 3] * P[dec_idx[t + 3]])
            cv = wp.vec4()  # contacts of step k (gait.contact_sequence: (phase0 + k f dt) mod 1 < d)
            for i in range(4):
                ang = phase[b * 4 + i] + float(k) * (P[i] * dt)
                tr = wp.int32(ang)
                fl = float(tr - wp.where(float(tr) > ang, 1, 0))
                cv[i] = wp.where((ang - fl) < P[4 + i], 1.0, 0.0)
            nst = cv[0] + cv[1] + cv[2] + cv[3]
            shift = weight / (nst + wp.where(nst < 0.5, 1.0, 0.0))
            sfx, sfy, sfz = wp.float32(0.0), wp.float32(0.0), wp.float32(0.0)
            tx, ty, tzq, rcost = wp.float32(0.0), wp.float32(0.0), wp.float32(0.0), wp.float32(0.0)
            nf = vec12()
            for i in range(4):
                c = cv[i]
                qx = clampf(dv[2 * i], px_lo, px_hi) + prm[28 + 2 * i]
                qy = clampf(dv[2 * i + 1], py_lo, py_hi) + prm[29 + 2 * i]
                fz = clampf(c * (dv[10 + 3 * i] + shift), fz_lo, fz_hi)
                fxr, fyr = c * dv[8 + 3 * i], c * dv[9 + 3 * i]
                nxy = wp.sqrt(fxr * fxr + fyr * fyr)
                lim = mu * fz
                big = wp.where(nxy > lim, nxy, lim)
                scale = lim / wp.where(big > 1e-12, big, 1e-12)
                fxh, fyh = fxr * scale, fyr * scale
                tgx = bx + cyaw * qx - syaw * qy
                tgy = by + syaw * qx + cyaw * qy
                tgz = terrain_z[b * 4 + i] + foot_r
                ex = tgx - foothold[b * 12 + 3 * i]
                ey = tgy - foothold[b * 12 + 3 * i + 1]
                rcost += ex * ex + ey * ey
                fx = c * (cyaw * fxh - syaw * fyh)
                fy = c * (syaw * fxh + cyaw * fyh)
                fzc = c * fz
                rx, ry, rz = feet[3 * i] - px, feet[3 * i + 1] - py, feet[3 * i + 2] - pz
                sfx += fx
                sfy += fy
                sfz += fzc
                tx += ry * fzc - rz * fy
                ty += rz * fx - rx * fzc
                tzq += rx * fy - ry * fx
                nf[3 * i] = c * feet[3 * i] + (1.0 - c) * tgx
                nf[3 * i + 1] = c * feet[3 * i + 1] + (1.0 - c) * tgy
                nf[3 * i + 2] = c * feet[3 * i + 2] + (1.0 - c) * tgz
            sc_r, sc_p, sc_y = sincos_f(ro), sincos_f(pi), sincos_f(ya)
            sr, cr, sp, cp, sy, cy = sc_r[0], sc_r[1], sc_p[0], sc_p[1], sc_y[0], sc_y[1]
            r00, r10, r20 = cy * cp, sy * cp, -sp  # R = Rz Ry Rx; torque_b = R^T torque_w
            r01, r11, r21 = cy * sp * sr - sy * cr, sy * sp * sr + cy * cr, cp * sr
            r02, r12, r22 = cy * sp * cr + sy * sr, sy * sp * cr - cy * sr, cp * cr
            tbx = r00 * tx + r10 * ty + r20 * tzq
            tby = r01 * tx + r11 * ty + r21 * tzq
            tbz = r02 * tx + r12 * ty + r22 * tzq
            iwx = prm[3] * wx + prm[4] * wy + prm[5] * wz
            iwy = prm[6] * wx + prm[7] * wy + prm[8] * wz
            iwz = prm[9] * wx + prm[10] * wy + prm[11] * wz
            hx = tbx - (wy * iwz - wz * iwy)
            hy = tby - (wz * iwx - wx * iwz)
            hz = tbz - (wx * iwy - wy * iwx)
            dwx = prm[12] * hx + prm[13] * hy + prm[14] * hz
            dwy = prm[15] * hx + prm[16] * hy + prm[17] * hz
            dwz = prm[18] * hx + prm[19] * hy + prm[20] * hz
            tp = sp / cp  # eq. C.2.3
            dro = wx + sr * tp * wy + cr * tp * wz
            dpi = cr * wy - sr * wz
            dya = (sr * wy + cr * wz) / cp
            px += dt * vx
            py += dt * vy
            pz += dt * vz
            vx += dt * (sfx / mass)
            vy += dt * (sfy / mass)
            vz += dt * (sfz / mass - grav)
            ro += dt * dro
            pi += dt * dpi
            ya += dt * dya
            wx, wy, wz = wx + dt * dwx, wy + dt * dwy, wz + dt * dwz
            feet = nf
            ez, evx, evy, ewz = pz - hr, vx - vxr, vy - vyr, wz - wzr
            total += (prm[37] * ez * ez + prm[38] * evx * evx + prm[39] * evy * evy + prm[40] * vz * vz
                      + prm[41] * ro * ro + prm[42] * pi * pi + prm[43] * wx * wx + prm[44] * wy * wy
                      + prm[45] * ewz * ewz + prm[46] * rcost)
        costs[b, m] = wp.where(wp.isnan(total), wp.inf, total)  # NaN cost = +inf

    return rollout


@functools.lru_cache(maxsize=64)
def device_constants(cfg: SamplerConfig, model: SRBDModel, device: str) -> tuple[torch.Tensor, ...]:
    """``cpp_kernel.constants`` (params, sigma, lo, hi, decode indices and weights) on ``device``, built once."""
    return tuple(t.to(device).reshape(-1) for t in cpp_kernel.constants(cfg, model))


def launch_rollout(cfg: SamplerConfig, b: int, m: int, g: int, dev: str, seed: wp.array, consts: list,
                   arrays: list, costs: wp.array, stream=None) -> None:
    """Launch the rollout kernel over (B, M) on Warp device ``dev``; ``consts``: :func:`device_constants` as Warp
    arrays; ``arrays``: warm starts (B G D), group (M,), perturb (M,), x0 (B 24), phase (B 4), base_xy (B 2),
    base_yaw (B,), terrain_z (B 4), height, velocity and yaw-rate references (B,), (B 2), (B,), footholds (B 12),
    all flat float32 (group int64)."""
    dim = encoded_dim(cfg.encoding)
    kern = rollout_kernel(bucket(dim))
    wp.launch(kern, dim=(b, m), inputs=[m, cfg.horizon, g, dim, seed, *consts, *arrays, costs], device=dev,
              stream=stream)


def _flat(t: torch.Tensor, device: torch.device, dtype: torch.dtype = torch.float32) -> torch.Tensor:
    return t.detach().to(device, dtype).contiguous().reshape(-1)


def warp_costs(inp, cfg: SamplerConfig, model: SRBDModel) -> torch.Tensor:
    """(B, M) costs of :class:`dls_quadruped.mpc.kernel.KernelInputs` ``inp`` with the Warp kernel, on the device
    of ``inp.x0`` (Warp's CPU device for ``cpu``)."""
    init()
    device = inp.x0.device
    dev = wp_device(device)
    b, m = inp.x0.shape[0], inp.group.shape[0]
    g = inp.warm_starts.shape[1]
    r = inp.refs
    tensors = [_flat(inp.warm_starts, device), _flat(inp.group, device, torch.int64), _flat(inp.perturb, device),
               _flat(inp.x0, device), _flat(inp.phase, device), _flat(inp.base_xy_w, device),
               _flat(inp.base_yaw, device), _flat(inp.terrain_z_w, device), _flat(r.com_height_w, device),
               _flat(r.lin_vel_w, device), _flat(r.yaw_rate, device), _flat(r.foothold_w, device)]
    seed = _flat(torch.as_tensor(inp.seed), device, torch.int64)
    costs = torch.empty(b, m, dtype=torch.float32, device=device)
    consts = [wp.from_torch(t) for t in device_constants(cfg, model, str(device))]
    stream = wp.stream_from_torch(torch.cuda.current_stream(device)) if device.type == "cuda" else None
    launch_rollout(cfg, b, m, g, dev, wp.from_torch(seed), consts, [wp.from_torch(t) for t in tensors],
                   wp.from_torch(costs), stream)
    return costs


"""The device solve's small kernels around the rollout: input cleaning and the winners' decoding (Warp, B threads).

* :func:`clean_kernel`: per robot, non-finite inputs -> 0 and one flag per input (``warp_solve.FLAGS``; the state's
  whole row, a phase outside [0, 1] flagged too), the default frame (base x, y = CoM - R c_b, yaw = the state's)
  when none is given; thread 0 advances the solve counter and derives this solve's noise seed from it, so that no
  seed goes through the host;
* :func:`decode_kernel` (one module per sample-vector bucket): the argmin's last stage (``warp_argmin.argmin_final``),
  the winner re-drawn exactly as the rollout drew it, its horizon decoded (contacts, forces from offsets, Table 1
  limits, frame H -> world: ``samples.decode_samples``), its input cost per step, the initial cost, and the last
  guard: a robot with a flagged input or a non-finite action keeps its previous action fields (they are still in
  the output buffers; without a previous solve: warm start 0, sample 0, decoded) with +inf costs and index -1,
  as ``SamplingMPC.fall_back`` returns it.
"""

from __future__ import annotations

import functools
from typing import Any

import warp as wp

from dls_quadruped.mpc.warp_argmin import argmin_final
from dls_quadruped.mpc.warp_math import clampf, hash32, normal_pair, seed_key

NUM_FLAGS = 11
"""Flags per robot: the nine inputs of ``solve_glue.INPUT_WIDTHS``, the warm starts, the solution."""
_F32 = wp.array(dtype=wp.float32)
_U8 = wp.array(dtype=wp.uint8)


@wp.func
def clean_row(src: _F32, dst: _F32, start: int, n: int) -> int:
    """dst[start:start + n] = src where finite, else 0; returns 1 if any entry was not finite."""
    bad = wp.int32(0)  # a dynamic variable: a plain literal is a constant to Warp
    for j in range(n):
        v = src[start + j]
        ok = wp.isfinite(v)
        dst[start + j] = wp.where(ok, v, 0.0)
        bad = wp.where(ok, bad, 1)
    return bad


@wp.kernel(enable_backward=False)
def clean_kernel(base_seed: int, frame_xy: int, frame_yaw: int, frame_z: int, com_offset: wp.vec3,
                 counter: wp.array(dtype=wp.int64), seed: wp.array(dtype=wp.int64), width: int,
                 x: _F32, phase: _F32, base_xy: _F32, base_yaw: _F32, terrain_z: _F32, h_ref: _F32, vel_ref: _F32,
                 wz_ref: _F32, foothold: _F32, warm: _F32,
                 cx: _F32, cphase: _F32, cbase_xy: _F32, cbase_yaw: _F32, cterrain_z: _F32, ch_ref: _F32,
                 cvel_ref: _F32, cwz_ref: _F32, cfoothold: _F32, cwarm: _F32, flags: _U8):
    """Thread b cleans robot b's inputs (``width`` = G D warm-start entries) and sets its :data:`NUM_FLAGS` flags;
    frame_* = 1: that part of the frame was given (else the default from the cleaned state / 0 terrain)."""
    b = wp.tid()
    if b == 0:  # this solve's seed: a hash of the MPC's seed and the solve count, in [0, 2^31)
        k = counter[0] + wp.int64(1)
        counter[0] = k
        seed[0] = wp.int64(hash32(hash32(wp.uint32(base_seed)) ^ wp.uint32(k)) >> wp.uint32(1))
    f = b * NUM_FLAGS
    bad_x = clean_row(x, cx, b * 24, 24)
    if bad_x == 1:
        for j in range(24):
            cx[b * 24 + j] = 0.0
    flags[f + 0] = wp.uint8(bad_x)
    bad_phase = clean_row(phase, cphase, b * 4, 4)
    for i in range(4):
        v = cphase[b * 4 + i]
        if v < 0.0 or v > 1.0:  # outside the gait cycle: the robot falls back (the torch path raises)
            bad_phase = 1
            cphase[b * 4 + i] = 0.0
    flags[f + 1] = wp.uint8(bad_phase)
    if frame_xy == 1:
        flags[f + 2] = wp.uint8(clean_row(base_xy, cbase_xy, b * 2, 2))
    else:  # base origin = CoM - R c_b, R = Rz(yaw) Ry(pitch) Rx(roll) of the cleaned state
        roll, pitch, yaw = cx[b * 24 + 6], cx[b * 24 + 7], cx[b * 24 + 8]
        cr, sr, cp, sp, cy, sy = wp.cos(roll), wp.sin(roll), wp.cos(pitch), wp.sin(pitch), wp.cos(yaw), wp.sin(yaw)
        c0, c1, c2 = com_offset[0], com_offset[1], com_offset[2]
        rc0 = cy * cp * c0 + (cy * sp * sr - sy * cr) * c1 + (cy * sp * cr + sy * sr) * c2
        rc1 = sy * cp * c0 + (sy * sp * sr + cy * cr) * c1 + (sy * sp * cr - cy * sr) * c2
        cbase_xy[b * 2] = cx[b * 24] - rc0
        cbase_xy[b * 2 + 1] = cx[b * 24 + 1] - rc1
        flags[f + 2] = wp.uint8(0)
    if frame_yaw == 1:
        flags[f + 3] = wp.uint8(clean_row(base_yaw, cbase_yaw, b, 1))
    else:
        cbase_yaw[b] = cx[b * 24 + 8]
        flags[f + 3] = wp.uint8(0)
    if frame_z == 1:
        flags[f + 4] = wp.uint8(clean_row(terrain_z, cterrain_z, b * 4, 4))
    else:
        for i in range(4):
            cterrain_z[b * 4 + i] = 0.0
        flags[f + 4] = wp.uint8(0)
    flags[f + 5] = wp.uint8(clean_row(h_ref, ch_ref, b, 1))
    flags[f + 6] = wp.uint8(clean_row(vel_ref, cvel_ref, b * 2, 2))
    flags[f + 7] = wp.uint8(clean_row(wz_ref, cwz_ref, b, 1))
    flags[f + 8] = wp.uint8(clean_row(foothold, cfoothold, b * 12, 12))
    flags[f + 9] = wp.uint8(clean_row(warm, cwarm, b * width, width))
    flags[f + 10] = wp.uint8(0)


@wp.struct
class Outputs:
    """The result buffers of :func:`decode_kernel`, flat, field-major (each field (B, width) row-major)."""

    f: _F32
    d: _F32
    foot_target_w: _F32
    force_w: _F32
    p_h: _F32
    F_h: _F32
    best_cost: _F32
    best_input_cost: _F32
    initial_cost: _F32
    best_encoded: _F32
    step_costs: _F32
    step_input_costs: _F32
    state_terms: _F32
    best_index: wp.array(dtype=wp.int64)
    warm_start_index: wp.array(dtype=wp.int64)
    contact: _U8
    contact_horizon: _U8
    fallback: _U8
    have_prev: _U8


@wp.func
def decoded(P: Any, dec_idx: wp.array(dtype=wp.int32), dec_w: _F32, k: int, s: int) -> float:
    """Decoded scalar s (0..7 p, 8..19 F offsets) of step k: the table's <= 4 weighted encoded entries."""
    t = (k * 20 + s) * 4
    return (dec_w[t] * P[dec_idx[t]] + dec_w[t + 1] * P[dec_idx[t + 1]] + dec_w[t + 2] * P[dec_idx[t + 2]]
            + dec_w[t + 3] * P[dec_idx[t + 3]])


@wp.func
def contacts(P: Any, phase: _F32, b: int, k: int, dt: float) -> wp.vec4:
    """Stance flags (0/1) of step k: remainder(phase0 + k (f dt), 1) < d (gait.contact_sequence)."""
    cv = wp.vec4()
    for i in range(4):
        a = phase[b * 4 + i] + float(k) * (P[i] * dt)
        cv[i] = wp.where(a - wp.floor(a) < P[4 + i], 1.0, 0.0)
    return cv


@wp.func
def leg_action(P: Any, dec_idx: wp.array(dtype=wp.int32), dec_w: _F32, prm: _F32, k: int, i: int, c: float,
               shift: float, frame: wp.vec4, tz: float):
    """Leg i's action at step k: p_h (vec2, clipped), F_h (vec3: forces from offsets, Table 1 limits), the target and
    the force in the world frame (vec3 each); ``frame`` = (base x, base y, cos yaw, sin yaw), ``tz`` the target's z.
    samples.forces_from_offsets, clip_horizon, horizontal_to_world."""
    qx = clampf(decoded(P, dec_idx, dec_w, k, 2 * i), prm[24], prm[25])
    qy = clampf(decoded(P, dec_idx, dec_w, k, 2 * i + 1), prm[26], prm[27])
    fz = clampf(c * (decoded(P, dec_idx, dec_w, k, 10 + 3 * i) + shift), prm[22], prm[23])
    fxr = c * decoded(P, dec_idx, dec_w, k, 8 + 3 * i)
    fyr = c * decoded(P, dec_idx, dec_w, k, 9 + 3 * i)
    nxy = wp.sqrt(fxr * fxr + fyr * fyr)
    lim = prm[21] * fz
    factor = wp.where(nxy > lim, lim / wp.max(nxy, 1e-12), 1.0)
    fx, fy = fxr * factor, fyr * factor
    nx, ny = prm[28 + 2 * i] + qx, prm[29 + 2 * i] + qy
    target = wp.vec3(frame[0] + frame[2] * nx - frame[3] * ny, frame[1] + frame[3] * nx + frame[2] * ny, tz)
    force = wp.vec3(frame[2] * fx - frame[3] * fy, frame[3] * fx + frame[2] * fy, fz)
    return wp.vec2(qx, qy), wp.vec3(fx, fy, fz), target, force


@functools.lru_cache(maxsize=4)
def decode_kernel(size: int):
    """The winners' decoding for samples of up to ``size`` encoded entries (``warp_kernel.BUCKETS``)."""
    vec_d = wp.types.vector(length=size, dtype=wp.float32)

    @wp.kernel(enable_backward=False, module="unique")
    def decode(m_total: int, n_steps: int, g_total: int, dim: int, seed: wp.array(dtype=wp.int64),
               prm: _F32, sigma: _F32, lo: _F32, hi: _F32, dec_idx: wp.array(dtype=wp.int32), dec_w: _F32,
               warm: _F32, group: wp.array(dtype=wp.int64), perturb: _F32, x0: _F32, phase: _F32, base_xy: _F32,
               base_yaw: _F32, terrain_z: _F32, h_ref: _F32, vel_ref: _F32, wz_ref: _F32, foothold: _F32,
               costs: wp.array2d(dtype=wp.float32), last_cost: wp.array2d(dtype=wp.float32),
               last_index: wp.array2d(dtype=wp.int32), last_first: int, last_n: int,
               flags: _U8, out: Outputs):
        b = wp.tid()
        arg = argmin_final(last_cost, last_index, last_first, last_n, b)
        bad_in = wp.int32(0)
        for t in range(NUM_FLAGS - 1):
            bad_in = wp.where(flags[b * NUM_FLAGS + t] != wp.uint8(0), 1, bad_in)
        have_prev = out.have_prev[b] != wp.uint8(0)
        pick = wp.where(bad_in == 1 and not have_prev, 0, arg)  # no previous action: warm start 0 itself
        # ---- the sample `pick` as the rollout drew it
        key = seed_key(seed[0])
        pm = perturb[pick]
        wb = (b * g_total + wp.int32(group[pick])) * dim
        half_d = wp.uint32(dim // 2)
        row = wp.uint32(b) * wp.uint32(m_total) + wp.uint32(pick)
        P = vec_d()
        finite = wp.isfinite(0.0)  # True, as a dynamic variable (a literal is a constant to Warp)
        for j in range(0, dim, 2):
            z = normal_pair(row * half_d + wp.uint32(j // 2), key)
            P[j] = clampf(warm[wb + j] + pm * (sigma[j] * z[0]), lo[j], hi[j])
            P[j + 1] = clampf(warm[wb + j + 1] + pm * (sigma[j + 1] * z[1]), lo[j + 1], hi[j + 1])
            finite = finite and wp.isfinite(P[j]) and wp.isfinite(P[j + 1])
        dt, weight, w_r, foot_r = prm[0], prm[47], prm[46], prm[36]
        frame = wp.vec4(base_xy[2 * b], base_xy[2 * b + 1], wp.cos(base_yaw[b]), wp.sin(base_yaw[b]))
        cv = contacts(P, phase, b, 0, dt)
        shift = weight / wp.max(cv[0] + cv[1] + cv[2] + cv[3], 1.0)
        for i in range(4):  # the last guard: the first action finite
            ph, fh, tg, fw = leg_action(P, dec_idx, dec_w, prm, 0, i, cv[i], shift, frame,
                                        terrain_z[b * 4 + i] + foot_r)
            finite = finite and wp.isfinite(ph[0]) and wp.isfinite(ph[1]) and wp.isfinite(fh[0])
            finite = finite and wp.isfinite(fh[1]) and wp.isfinite(fh[2]) and wp.isfinite(tg[0])
            finite = finite and wp.isfinite(tg[1]) and wp.isfinite(tg[2]) and wp.isfinite(fw[0]) and wp.isfinite(fw[1])
        bad = bad_in == 1 or not finite
        write = not bad or not have_prev  # a fallback robot with a previous action keeps it (buffers untouched)
        inf = float(wp.inf)
        input_total = wp.float32(0.0)
        for k in range(n_steps):
            cv = contacts(P, phase, b, k, dt)
            shift = weight / wp.max(cv[0] + cv[1] + cv[2] + cv[3], 1.0)
            step_cost = wp.float32(0.0)
            for i in range(4):
                ph, fh, tg, fw = leg_action(P, dec_idx, dec_w, prm, k, i, cv[i], shift, frame,
                                            terrain_z[b * 4 + i] + foot_r)
                ex, ey = tg[0] - foothold[b * 12 + 3 * i], tg[1] - foothold[b * 12 + 3 * i + 1]
                step_cost += w_r * (ex * ex + ey * ey)
                if write:
                    out.contact_horizon[(b * n_steps + k) * 4 + i] = wp.uint8(cv[i])
                    if k == 0:
                        out.contact[b * 4 + i] = wp.uint8(cv[i])
                        for a in range(3):
                            out.F_h[b * 12 + 3 * i + a] = fh[a]
                            out.foot_target_w[b * 12 + 3 * i + a] = tg[a]
                            out.force_w[b * 12 + 3 * i + a] = fw[a]
                        out.p_h[b * 8 + 2 * i] = ph[0]
                        out.p_h[b * 8 + 2 * i + 1] = ph[1]
            out.step_input_costs[b * n_steps + k] = wp.where(bad, inf, step_cost)
            out.step_costs[b * n_steps + k] = wp.where(bad, inf, wp.nan)
            input_total += step_cost
        if write:
            for j in range(dim):
                out.best_encoded[b * dim + j] = P[j]
            for i in range(4):
                out.f[b * 4 + i] = P[i]
                out.d[b * 4 + i] = P[4 + i]
        for t in range(9):
            out.state_terms[b * 9 + t] = wp.where(bad, inf, wp.nan)
        xb = b * 24
        ez, evx, evy = x0[xb + 2] - h_ref[b], x0[xb + 3] - vel_ref[2 * b], x0[xb + 4] - vel_ref[2 * b + 1]
        ewz = x0[xb + 11] - wz_ref[b]
        init = (ez * ez * prm[37] + evx * evx * prm[38] + evy * evy * prm[39] + x0[xb + 5] * x0[xb + 5] * prm[40]
                + x0[xb + 6] * x0[xb + 6] * prm[41] + x0[xb + 7] * x0[xb + 7] * prm[42]
                + x0[xb + 9] * x0[xb + 9] * prm[43] + x0[xb + 10] * x0[xb + 10] * prm[44] + ewz * ewz * prm[45])
        out.initial_cost[b] = wp.where(bad or wp.isnan(init), inf, init)
        out.best_cost[b] = wp.where(bad, inf, costs[b, arg])
        out.best_input_cost[b] = wp.where(bad, inf, input_total)
        out.best_index[b] = wp.where(bad, wp.int64(-1), wp.int64(arg))
        out.warm_start_index[b] = wp.where(bad, wp.int64(-1), group[arg])
        out.fallback[b] = wp.where(bad, wp.uint8(1), wp.uint8(0))
        flags[b * NUM_FLAGS + NUM_FLAGS - 1] = wp.where(bad_in == 0 and not finite, wp.uint8(1), wp.uint8(0))
        out.have_prev[b] = wp.uint8(1)

    return decode

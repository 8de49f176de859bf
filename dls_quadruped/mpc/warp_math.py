"""Scalar float32 helpers of the ``warp`` MPC kernel, in Warp's kernel language (``wp.func``).

Each mirrors its counterpart in ``rollout_kernel.cpp`` (and ``counter_hash.h``) operation by operation, so that a
sample drawn, clipped and rolled out here gets the numbers the ``cpp`` kernel gets (up to the compilers' FMA
contraction: ~1 ulp per operation):

* :func:`hash32`: the counter hash (``core.hashing.hash32`` on the low 32 bits), uint32 arithmetic mod 2^32;
* :func:`log_f`: the exponent split and atanh series of ``log_f`` (bit operations through :func:`bits_of` /
  :func:`float_of`, native one-liners: Warp 1.19 has no bit cast in its language);
* :func:`sincos_f`: the Cody-Waite reduction and minimax polynomials of ``sincos_f``; the quadrant's sign flips are
  negations (the same bits as xor-ing the sign bit);
* :func:`normal_pair`: Box-Muller of the two hashes of one counter (``rng.normal_pair``);
* :func:`clampf`: ``min(max(v, lo), hi)`` with the C++ operand order (NaN stays NaN).

Imported only by the Warp kernels (``warp_kernel.py``, ``warp_solve.py``): ``import dls_quadruped.mpc`` does not
import Warp.
"""

from __future__ import annotations

import warp as wp

U_SCALE = wp.constant(wp.float32(1.0 / 4294967297.0))
"""Uniform in (0, 1] from a 32-bit hash: (h + 1) U_SCALE (the double constant rounded to float32, as in C++)."""
A_SCALE = wp.constant(wp.float32(6.283185307179586 / 4294967296.0))
"""Angle in [0, 2 pi) from a 32-bit hash: h A_SCALE."""


@wp.func_native("uint32_t u; memcpy(&u, &x, 4); return u;")
def bits_of(x: wp.float32) -> wp.uint32:  # type: ignore[empty-body]
    """The IEEE-754 bits of ``x``."""


@wp.func_native("float f; memcpy(&f, &u, 4); return f;")
def float_of(u: wp.uint32) -> wp.float32:  # type: ignore[empty-body]
    """The float whose IEEE-754 bits are ``u``."""


@wp.func
def hash32(x0: wp.uint32) -> wp.uint32:
    """counter_hash.h's hash32 (three xor-shift-multiply rounds)."""
    x = x0 ^ (x0 >> wp.uint32(16))
    x = x * wp.uint32(0x7FEB352D)
    x = x ^ (x >> wp.uint32(15))
    x = x * wp.uint32(0x1B873593)
    x = x ^ (x >> wp.uint32(16))
    x = x * wp.uint32(0x5BD1E995)
    return x ^ (x >> wp.uint32(13))


@wp.func
def clampf(v: wp.float32, lo: wp.float32, hi: wp.float32) -> wp.float32:
    """std::min(std::max(v, lo), hi): max returns v unless v < lo, min returns it unless hi < it."""
    a = wp.where(v < lo, lo, v)
    return wp.where(hi < a, hi, a)


@wp.func
def log_f(x: wp.float32) -> wp.float32:
    """Natural log of a positive normal float (rollout_kernel.cpp's log_f: mantissa in [sqrt(2)/2, sqrt(2)))."""
    bits = bits_of(x)
    mant = bits & wp.uint32(0x7FFFFF)
    big = wp.where(mant > wp.uint32(0x3504F3), wp.uint32(1), wp.uint32(0))
    m = float_of((mant | wp.uint32(0x3F800000)) - (big << wp.uint32(23)))
    e = wp.int32((bits >> wp.uint32(23)) & wp.uint32(255)) - 127 + wp.int32(big)
    t = (m - 1.0) / (m + 1.0)
    t2 = t * t
    p = 2.0 * t * (1.0 + t2 * (0.333333333 + t2 * (0.2 + t2 * (0.142857143 + t2 * 0.111111111))))
    return p + wp.float32(e) * 0.693147180559945


@wp.func
def sincos_f(x: wp.float32) -> wp.vec2:
    """(sin x, cos x): rollout_kernel.cpp's sincos_f (reduction by pi/2 in three parts, polynomials on
    [-pi/4, pi/4])."""
    q = wp.rint(x * 0.636619772367581343)
    r = x - q * 1.5703125
    r = r - q * 4.837512969970703125e-4
    r = r - q * 7.54978995489188216e-8
    r2 = r * r
    sp = r + r * r2 * (-1.6666654611e-1 + r2 * (8.3321608736e-3 + r2 * (-1.9515295891e-4)))
    cp = 1.0 - 0.5 * r2 + r2 * r2 * (4.166664568298827e-2 + r2 * (-1.388731625493765e-3 + r2 * 2.443315711809948e-5))
    qi = wp.uint32(wp.int32(q))  # the quadrant mod 4 in the low two bits
    odd = (qi & wp.uint32(1)) != wp.uint32(0)
    s0 = wp.where(odd, cp, sp)
    c0 = wp.where(odd, sp, cp)
    s = wp.where((qi & wp.uint32(2)) != wp.uint32(0), -s0, s0)  # quadrants 2, 3: -sin
    c = wp.where(((qi + wp.uint32(1)) & wp.uint32(2)) != wp.uint32(0), -c0, c0)  # quadrants 1, 2: -cos
    return wp.vec2(s, c)


@wp.func
def normal_pair(counter: wp.uint32, key: wp.uint32) -> wp.vec2:
    """Two standard normals of one noise counter (Box-Muller): (radius cos a, radius sin a), rng.normal_pair."""
    h1 = hash32((counter * wp.uint32(2)) ^ key)
    h2 = hash32((counter * wp.uint32(2) + wp.uint32(1)) ^ key)
    u1 = (wp.float32(h1) + 1.0) * U_SCALE
    angle = wp.float32(h2) * A_SCALE
    radius = wp.sqrt(-2.0 * log_f(u1))
    sc = sincos_f(angle)
    return wp.vec2(radius * sc[1], radius * sc[0])


@wp.func
def seed_key(seed: wp.int64) -> wp.uint32:
    """The hash key of a solve's noise seed: hash32(low 32 bits of seed + 0x2545F491)."""
    return hash32(wp.uint32(seed) + wp.uint32(0x2545F491))

// Sampling-MPC cost kernel in plain C++ (the "cpp" kernel of dls_quadruped.mpc.kernel).
//
// Same maths as kernel.reference_costs, per sample: counter-hash normals (rng.py) -> perturb and
// box-clip the encoded sample (samples.sample_encoded) -> decode p, F per step (encodings, as a
// table of <= 4 (index, weight) pairs per decoded scalar) -> forces from offsets, F = c (dF + m g /
// max(sum c, 1) e_z) (samples.forces_from_offsets) -> clip p box, F_z range, friction cone
// (samples.clip_horizon) -> horizontal -> world frame -> contacts from (phase, f, d) ->
// explicit-Euler SRBD rollout and quadratic cost (srbd.srbd_step, cost.rollout_cost_reference)
// -> NaN cost = +inf. float32 throughout, like the torch kernels.
//
// Layout: samples are processed in blocks of L lanes; every operation is a plain loop over the lanes
// that GCC vectorises with the target's own vector width (AVX2, AVX-512, NEON), OpenMP over blocks.
// The lane loops are branch-free so that they vectorise without masked instructions (which only
// AVX-512 has): no per-lane early exit, no libm call (own sincos/log), and no conditional float
// operation -- under the default -ftrapping-math GCC may not speculate a float op that sits on one
// side of a `?:`, so both sides are computed and a select picks one. No `#pragma omp simd` either:
// it would force vectorisation even in the -fno-tree-vectorize comparison build.
// tests/mpc/test_cpp_vectorise.py checks from GCC's -fopt-info report that every lane loop
// (`for (int l = 0; l < L; ++l)`) vectorises for x86-64-v3 (AVX2 + FMA) and armv8-a (NEON).
// Called through ctypes (no torch headers: builds in ~1 s); all pointers are contiguous CPU arrays.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>

#include "counter_hash.h"  // hash32 (rng.hash32)

namespace {

constexpr int L = 16;  // lanes per block

inline uint32_t bits_of(float x) {
  uint32_t u;
  std::memcpy(&u, &x, 4);
  return u;
}

inline float float_of(uint32_t u) {
  float x;
  std::memcpy(&x, &u, 4);
  return x;
}

// v clipped to [lo, hi] (lo <= hi); NaN stays NaN, like `v < lo ? lo : (v > hi ? hi : v)`.
inline float clamp(float v, float lo, float hi) { return std::min(std::max(v, lo), hi); }

// sin and cos of a float (Cody-Waite reduction by pi/2, minimax polynomials on [-pi/4, pi/4];
// ~1 ulp for |x| < 1e4, NaN in -> NaN out). The quadrant swaps sin/cos by a select and flips
// signs by xor-ing the sign bit.
inline void sincos_f(float x, float& s, float& c) {
  const float q = std::nearbyint(x * 0.636619772367581343f);
  float r = x - q * 1.5703125f;
  r = r - q * 4.837512969970703125e-4f;
  r = r - q * 7.54978995489188216e-8f;
  const float r2 = r * r;
  const float sp = r + r * r2 * (-1.6666654611e-1f + r2 * (8.3321608736e-3f + r2 * (-1.9515295891e-4f)));
  const float cp = 1.0f - 0.5f * r2 + r2 * r2 * (4.166664568298827e-2f + r2 * (-1.388731625493765e-3f + r2 * 2.443315711809948e-5f));
  const uint32_t qi = static_cast<uint32_t>(static_cast<int32_t>(q));  // quadrant mod 4 in the low 2 bits
  const bool odd = (qi & 1u) != 0u;
  const float s0 = odd ? cp : sp;
  const float c0 = odd ? sp : cp;
  s = float_of(bits_of(s0) ^ ((qi & 2u) << 30));          // quadrants 2, 3: -sin
  c = float_of(bits_of(c0) ^ (((qi + 1u) & 2u) << 30));   // quadrants 1, 2: -cos
}

// natural log of a positive normal float (exponent split, atanh series; ~1 ulp).
// x = 2^e m with m in [sqrt(2)/2, sqrt(2)): a mantissa above sqrt(2) (bits 0x3504F3) is halved by
// taking one off its exponent field, in integer arithmetic (exact, like 0.5 m).
inline float log_f(float x) {
  const uint32_t bits = bits_of(x);
  const uint32_t mant = bits & 0x7FFFFFu;
  const uint32_t big = mant > 0x3504F3u ? 1u : 0u;
  const float m = float_of((mant | 0x3F800000u) - (big << 23));
  const int e = static_cast<int>((bits >> 23) & 255u) - 127 + static_cast<int>(big);
  const float t = (m - 1.0f) / (m + 1.0f);
  const float t2 = t * t;
  const float p = 2.0f * t * (1.0f + t2 * (0.333333333f + t2 * (0.2f + t2 * (0.142857143f + t2 * 0.111111111f))));
  return p + static_cast<float>(e) * 0.693147180559945f;
}

}  // namespace

extern "C" {

// prm (floats): [0] dt, [1] mass, [2] gravity, [3..11] inertia (row-major), [12..20] inverse
// inertia, [21] mu, [22] fz_lo, [23] fz_hi, [24] px_lo, [25] px_hi, [26] py_lo, [27] py_hi,
// [28..35] nominal footholds (x, y per leg), [36] foot radius, [37..46] weights
// (z, vx, vy, vz, roll, pitch, roll_rate, pitch_rate, yaw_rate, foothold_xy), [47] m g of the
// force offsets' gravity compensation.
// dec_idx / dec_w: (N, 20, 4) decode tables for the 8 p scalars then the 12 F scalars.
// Returns 0, or -1 if D is too large for the on-stack sample buffer.
int mpc_costs(int B, int M, int N, int G, int D, int64_t seed, int num_threads,
              const float* prm, const float* sigma, const float* lo, const float* hi,
              const int32_t* dec_idx, const float* dec_w,
              const float* warm, const int64_t* group, const float* perturb,
              const float* x0, const float* phase, const float* base_xy, const float* base_yaw,
              const float* terrain_z, const float* h_ref, const float* vel_ref, const float* wz_ref,
              const float* foothold, float* out) {
  constexpr int DMAX = 512;
  if (D > DMAX || D % 2) return -1;
  const int blocks_per_robot = (M + L - 1) / L;
  const long total_blocks = static_cast<long>(B) * blocks_per_robot;
  const uint32_t key = hash32(static_cast<uint32_t>(seed) + 0x2545F491u);
  const float dt = prm[0], mass = prm[1], grav = prm[2];
  const float* I = prm + 3;
  const float* Ii = prm + 12;
  const float mu = prm[21], fz_lo = prm[22], fz_hi = prm[23];
  const float px_lo = prm[24], px_hi = prm[25], py_lo = prm[26], py_hi = prm[27];
  const float* nominal = prm + 28;
  const float foot_r = prm[36];
  const float* w = prm + 37;
  const float weight = prm[47];

#pragma omp parallel for num_threads(num_threads) schedule(static) if (num_threads > 1)
  for (long blk = 0; blk < total_blocks; ++blk) {
    const int b = static_cast<int>(blk / blocks_per_robot);
    const int m0 = static_cast<int>(blk % blocks_per_robot) * L;
    alignas(64) float P[DMAX][L];
    // The last block of a robot may be partial: its padding lanes repeat the last sample's group and
    // perturbation flag (contiguous copies, no gathers) and their costs are never written.
    const int valid = std::min(L, M - m0);
    alignas(64) float pm[L];
    alignas(64) int64_t gr[L];
    for (int l = 0; l < L; ++l) {
      pm[l] = perturb[M - 1];
      gr[l] = group[M - 1];
    }
    std::memcpy(pm, perturb + m0, sizeof(float) * valid);
    std::memcpy(gr, group + m0, sizeof(int64_t) * valid);
    int64_t mixed = 0;  // groups are contiguous runs: almost every block has a single warm start
    for (int l = 0; l < L; ++l) mixed |= gr[l] ^ gr[0];

    // ---- draw and box-clip the encoded samples (samples.sample_encoded)
    const float* wb = warm + static_cast<long>(b) * G * D;
    // rng.normals counter (b M + m) D/2 + j/2 in int64; only its low 32 bits reach the hash, so
    // uint32 arithmetic (mod 2^32) gives the same bits and vectorises on every target.
    const uint32_t row0 = static_cast<uint32_t>(b) * static_cast<uint32_t>(M) + static_cast<uint32_t>(m0);
    const uint32_t half_d = static_cast<uint32_t>(D / 2);
    for (int j = 0; j < D; j += 2) {
      for (int l = 0; l < L; ++l) {
        const uint32_t counter = (row0 + static_cast<uint32_t>(l)) * half_d + static_cast<uint32_t>(j / 2);
        const uint32_t h1 = hash32((counter * 2u) ^ key);
        const uint32_t h2 = hash32((counter * 2u + 1u) ^ key);
        const float u1 = (static_cast<float>(h1) + 1.0f) * static_cast<float>(1.0 / 4294967297.0);
        const float angle = static_cast<float>(h2) * static_cast<float>(6.283185307179586 / 4294967296.0);
        const float radius = std::sqrt(-2.0f * log_f(u1));
        float sa, ca;
        sincos_f(angle, sa, ca);
        P[j][l] = radius * ca;
        P[j + 1][l] = radius * sa;
      }
    }
    for (int j = 0; j < D; ++j) {  // centre (the lane's warm start) + perturb sigma z, box clip
      const float sg = sigma[j], lj = lo[j], hj = hi[j];
      alignas(64) float cen[L];
      const float c0 = wb[gr[0] * D + j];
      for (int l = 0; l < L; ++l) cen[l] = c0;
      if (mixed)  // a block straddling groups (at most G - 1 per robot): each lane picks its warm start
        for (int g = 0; g < G; ++g) {
          const float cg = wb[g * D + j];
          for (int l = 0; l < L; ++l) cen[l] = gr[l] == g ? cg : cen[l];
        }
      for (int l = 0; l < L; ++l) P[j][l] = clamp(cen[l] + pm[l] * (sg * P[j][l]), lj, hj);
    }

    // ---- rollout state
    const float* xb = x0 + b * 24;
    alignas(64) float px[L], py[L], pz[L], vx[L], vy[L], vz[L], ro[L], pi[L], ya[L], wx[L], wy[L], wz[L];
    alignas(64) float feet[4][3][L], total[L];
    for (int l = 0; l < L; ++l) {
      px[l] = xb[0]; py[l] = xb[1]; pz[l] = xb[2]; vx[l] = xb[3]; vy[l] = xb[4]; vz[l] = xb[5];
      ro[l] = xb[6]; pi[l] = xb[7]; ya[l] = xb[8]; wx[l] = xb[9]; wy[l] = xb[10]; wz[l] = xb[11];
      for (int i = 0; i < 4; ++i)
        for (int a = 0; a < 3; ++a) feet[i][a][l] = xb[12 + 3 * i + a];
      total[l] = 0.0f;
    }
    const float cyaw = std::cos(base_yaw[b]), syaw = std::sin(base_yaw[b]);
    const float bx = base_xy[2 * b], by = base_xy[2 * b + 1];
    const float hr = h_ref[b], vxr = vel_ref[2 * b], vyr = vel_ref[2 * b + 1], wzr = wz_ref[b];
    const float* fh = foothold + b * 12;
    const float* ph = phase + b * 4;
    const float* tz = terrain_z + b * 4;

    for (int k = 0; k < N; ++k) {
      // decoded p_h (scalars 0..7) and F_h (8..19) of step k
      alignas(64) float dv[20][L];
      for (int s = 0; s < 20; ++s) {
        const int32_t* di = dec_idx + (k * 20 + s) * 4;
        const float* dw = dec_w + (k * 20 + s) * 4;
        const float *r0 = P[di[0]], *r1 = P[di[1]], *r2 = P[di[2]], *r3 = P[di[3]];
        const float w0 = dw[0], w1 = dw[1], w2 = dw[2], w3 = dw[3];
        for (int l = 0; l < L; ++l) dv[s][l] = w0 * r0[l] + w1 * r1[l] + w2 * r2[l] + w3 * r3[l];
      }
      // contacts of step k (gait.contact_sequence: (phase0 + k f dt) mod 1 < d)
      alignas(64) float cv[4][L];
      for (int i = 0; i < 4; ++i) {
        const float* fr = P[i];
        const float* du = P[4 + i];
        const float p0 = ph[i], kf = static_cast<float>(k);
        for (int l = 0; l < L; ++l) {
          const float ang = p0 + kf * (fr[l] * dt);  // small: f and d are box-clipped
          const int tr = static_cast<int>(ang);  // floor = trunc - (trunc > x), in integers: no libm
          const float fl = static_cast<float>(tr - (static_cast<float>(tr) > ang ? 1 : 0));
          cv[i][l] = (ang - fl) < du[l] ? 1.0f : 0.0f;
        }
      }
      for (int l = 0; l < L; ++l) {
        float sfx = 0.f, sfy = 0.f, sfz = 0.f, tx = 0.f, ty = 0.f, tzq = 0.f, rcost = 0.f;
        float nf[4][3];
        // gravity compensation of this step: m g shared by its stance legs, max(n, 1) written as a select of
        // constants (a std::max on the sum of the selected flags became a branch and stopped the vectoriser)
        const float nst = cv[0][l] + cv[1][l] + cv[2][l] + cv[3][l];
        const float shift = weight / (nst + (nst < 0.5f ? 1.0f : 0.0f));
#pragma GCC unroll 4
        for (int i = 0; i < 4; ++i) {
          const float c = cv[i][l];
          // decoded p_h, F_h of leg i at step k
          const float dec[5] = {dv[2 * i][l], dv[2 * i + 1][l], dv[8 + 3 * i][l], dv[9 + 3 * i][l], dv[10 + 3 * i][l]};
          // forces from offsets, zero in swing (samples.forces_from_offsets), then Table 1 limits
          // (samples.clip_horizon)
          const float qx = clamp(dec[0], px_lo, px_hi) + nominal[2 * i];
          const float qy = clamp(dec[1], py_lo, py_hi) + nominal[2 * i + 1];
          const float fz = clamp(c * (dec[4] + shift), fz_lo, fz_hi);
          const float fxr = c * dec[2], fyr = c * dec[3];
          const float nxy = std::sqrt(fxr * fxr + fyr * fyr);
          const float lim = mu * fz;
          // radial scaling onto the cone: lim / |F_xy| where |F_xy| > lim, else 1, written as
          // lim / max(|F_xy|, lim, 1e-12) so that no float op sits on one side of a select (GCC moves a
          // product or quotient into the arm that uses it); differs only if |F_xy| <= lim < 1e-12 N.
          const float big = nxy > lim ? nxy : lim;
          const float scale = lim / (big > 1e-12f ? big : 1e-12f);
          const float fxh = fxr * scale, fyh = fyr * scale;
          // frame H -> world (samples.horizontal_to_world)
          const float tgx = bx + cyaw * qx - syaw * qy, tgy = by + syaw * qx + cyaw * qy, tgz = tz[i] + foot_r;
          const float ex = tgx - fh[3 * i], ey = tgy - fh[3 * i + 1];
          rcost += ex * ex + ey * ey;
          const float fx = c * (cyaw * fxh - syaw * fyh), fy = c * (syaw * fxh + cyaw * fyh), fzc = c * fz;
          const float rx = feet[i][0][l] - px[l], ry = feet[i][1][l] - py[l], rz = feet[i][2][l] - pz[l];
          sfx += fx; sfy += fy; sfz += fzc;
          tx += ry * fzc - rz * fy;
          ty += rz * fx - rx * fzc;
          tzq += rx * fy - ry * fx;
          nf[i][0] = c * feet[i][0][l] + (1.0f - c) * tgx;
          nf[i][1] = c * feet[i][1][l] + (1.0f - c) * tgy;
          nf[i][2] = c * feet[i][2][l] + (1.0f - c) * tgz;
        }
        float sr, cr, sp, cp, sy, cy;
        sincos_f(ro[l], sr, cr);
        sincos_f(pi[l], sp, cp);
        sincos_f(ya[l], sy, cy);
        // R = Rz Ry Rx; torque_b = R^T torque_w
        const float r00 = cy * cp, r10 = sy * cp, r20 = -sp;
        const float r01 = cy * sp * sr - sy * cr, r11 = sy * sp * sr + cy * cr, r21 = cp * sr;
        const float r02 = cy * sp * cr + sy * sr, r12 = sy * sp * cr - cy * sr, r22 = cp * cr;
        const float tbx = r00 * tx + r10 * ty + r20 * tzq;
        const float tby = r01 * tx + r11 * ty + r21 * tzq;
        const float tbz = r02 * tx + r12 * ty + r22 * tzq;
        const float owx = wx[l], owy = wy[l], owz = wz[l];
        const float iwx = I[0] * owx + I[1] * owy + I[2] * owz;
        const float iwy = I[3] * owx + I[4] * owy + I[5] * owz;
        const float iwz = I[6] * owx + I[7] * owy + I[8] * owz;
        const float hx = tbx - (owy * iwz - owz * iwy), hy = tby - (owz * iwx - owx * iwz), hz = tbz - (owx * iwy - owy * iwx);
        const float dwx = Ii[0] * hx + Ii[1] * hy + Ii[2] * hz;
        const float dwy = Ii[3] * hx + Ii[4] * hy + Ii[5] * hz;
        const float dwz = Ii[6] * hx + Ii[7] * hy + Ii[8] * hz;
        const float tp = sp / cp;  // eq. C.2.3
        const float dro = owx + sr * tp * owy + cr * tp * owz;
        const float dpi = cr * owy - sr * owz;
        const float dya = (sr * owy + cr * owz) / cp;
        px[l] += dt * vx[l]; py[l] += dt * vy[l]; pz[l] += dt * vz[l];
        vx[l] += dt * (sfx / mass); vy[l] += dt * (sfy / mass); vz[l] += dt * (sfz / mass - grav);
        ro[l] += dt * dro; pi[l] += dt * dpi; ya[l] += dt * dya;
        wx[l] = owx + dt * dwx; wy[l] = owy + dt * dwy; wz[l] = owz + dt * dwz;
#pragma GCC unroll 4
        for (int i = 0; i < 4; ++i)
#pragma GCC unroll 3
          for (int a = 0; a < 3; ++a) feet[i][a][l] = nf[i][a];
        const float ez = pz[l] - hr, evx = vx[l] - vxr, evy = vy[l] - vyr, ewz = wz[l] - wzr;
        total[l] += w[0] * ez * ez + w[1] * evx * evx + w[2] * evy * evy + w[3] * vz[l] * vz[l]
                    + w[4] * ro[l] * ro[l] + w[5] * pi[l] * pi[l] + w[6] * wx[l] * wx[l]
                    + w[7] * wy[l] * wy[l] + w[8] * ewz * ewz + w[9] * rcost;
      }
    }
    for (int l = 0; l < L; ++l) total[l] = total[l] != total[l] ? INFINITY : total[l];  // NaN cost = +inf
    std::memcpy(out + static_cast<long>(b) * M + m0, total, sizeof(float) * valid);
  }
  return 0;
}

// mpc_costs, then each robot's argmin in the same call (torch.min(dim=1): the first minimum; costs are
// never NaN): best_cost (B,), best_index (B,).
int mpc_solve(int B, int M, int N, int G, int D, int64_t seed, int num_threads,
              const float* prm, const float* sigma, const float* lo, const float* hi,
              const int32_t* dec_idx, const float* dec_w,
              const float* warm, const int64_t* group, const float* perturb,
              const float* x0, const float* phase, const float* base_xy, const float* base_yaw,
              const float* terrain_z, const float* h_ref, const float* vel_ref, const float* wz_ref,
              const float* foothold, float* out, float* best_cost, int64_t* best_index) {
  const int rc = mpc_costs(B, M, N, G, D, seed, num_threads, prm, sigma, lo, hi, dec_idx, dec_w, warm, group,
                           perturb, x0, phase, base_xy, base_yaw, terrain_z, h_ref, vel_ref, wz_ref, foothold, out);
  if (rc != 0) return rc;
  for (int b = 0; b < B; ++b) {
    const float* row = out + static_cast<long>(b) * M;
    float best = row[0];
    int64_t arg = 0;
    for (int m = 1; m < M; ++m)
      if (row[m] < best) {
        best = row[m];
        arg = m;
      }
    best_cost[b] = best;
    best_index[b] = arg;
  }
  return 0;
}

}  // extern "C"

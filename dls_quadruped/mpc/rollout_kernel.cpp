// Sampling-MPC cost kernel in plain C++ (the "cpp" kernel of dls_quadruped.mpc.kernel).
//
// Same maths as kernel.reference_costs, per sample: counter-hash normals (rng.py) -> perturb and
// box-clip the encoded sample (samples.sample_encoded) -> decode p, F per step (encodings, as a
// table of <= 4 (index, weight) pairs per decoded scalar) -> clip p box, F_z range, friction cone
// (samples.clip_horizon) -> horizontal -> world frame -> contacts from (phase, f, d) ->
// explicit-Euler SRBD rollout and quadratic cost (srbd.srbd_step, cost.rollout_cost_reference)
// -> NaN cost = +inf. float32 throughout, like the torch kernels.
//
// Layout: samples are processed in blocks of L lanes; every operation is a loop over the lanes
// (vectorised by the compiler, no libm calls: own sincos/log), OpenMP over blocks.
// Called through ctypes (no torch headers: builds in ~1 s); all pointers are contiguous CPU arrays.
#include <cmath>
#include <cstdint>
#include <cstring>

namespace {

constexpr int L = 16;  // lanes per block

inline uint32_t hash32(uint32_t x) {  // rng.hash32
  x ^= x >> 16;
  x *= 0x7FEB352Du;
  x ^= x >> 15;
  x *= 0x1B873593u;
  x ^= x >> 16;
  x *= 0x5BD1E995u;
  return x ^ (x >> 13);
}

// sin and cos of a float (Cody-Waite reduction by pi/2, minimax polynomials on [-pi/4, pi/4];
// ~1 ulp for |x| < 1e4, NaN in -> NaN out). Branch-free so the lane loops vectorise.
inline void sincos_f(float x, float& s, float& c) {
  float q = std::nearbyint(x * 0.636619772367581343f);
  float r = x - q * 1.5703125f;
  r = r - q * 4.837512969970703125e-4f;
  r = r - q * 7.54978995489188216e-8f;
  float r2 = r * r;
  float sp = r + r * r2 * (-1.6666654611e-1f + r2 * (8.3321608736e-3f + r2 * (-1.9515295891e-4f)));
  float cp = 1.0f - 0.5f * r2 + r2 * r2 * (4.166664568298827e-2f + r2 * (-1.388731625493765e-3f + r2 * 2.443315711809948e-5f));
  int qi = static_cast<int>(q) & 3;
  float s0 = (qi & 1) ? cp : sp;
  float c0 = (qi & 1) ? sp : cp;
  s = (qi & 2) ? -s0 : s0;
  c = ((qi + 1) & 2) ? -c0 : c0;
}

// natural log of a positive normal float (exponent split, atanh series; ~1 ulp).
inline float log_f(float x) {
  uint32_t bits;
  std::memcpy(&bits, &x, 4);
  int e = static_cast<int>((bits >> 23) & 255u) - 127;
  uint32_t mb = (bits & 0x7FFFFFu) | 0x3F800000u;
  float m;
  std::memcpy(&m, &mb, 4);
  bool big = m > 1.41421356f;
  m = big ? 0.5f * m : m;
  e = big ? e + 1 : e;
  float t = (m - 1.0f) / (m + 1.0f);
  float t2 = t * t;
  float p = 2.0f * t * (1.0f + t2 * (0.333333333f + t2 * (0.2f + t2 * (0.142857143f + t2 * 0.111111111f))));
  return p + static_cast<float>(e) * 0.693147180559945f;
}

}  // namespace

extern "C" {

// prm (floats): [0] dt, [1] mass, [2] gravity, [3..11] inertia (row-major), [12..20] inverse
// inertia, [21] mu, [22] fz_lo, [23] fz_hi, [24] px_lo, [25] px_hi, [26] py_lo, [27] py_hi,
// [28..35] nominal footholds (x, y per leg), [36] foot radius, [37..46] weights
// (z, vx, vy, vz, roll, pitch, roll_rate, pitch_rate, yaw_rate, foothold_xy).
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

#pragma omp parallel for num_threads(num_threads) schedule(static) if (num_threads > 1)
  for (long blk = 0; blk < total_blocks; ++blk) {
    const int b = static_cast<int>(blk / blocks_per_robot);
    const int m0 = static_cast<int>(blk % blocks_per_robot) * L;
    alignas(64) float P[DMAX][L];
    int ms[L];
    for (int l = 0; l < L; ++l) ms[l] = (m0 + l < M) ? m0 + l : M - 1;

    // ---- draw and box-clip the encoded samples (samples.sample_encoded)
    const float* wb = warm + static_cast<long>(b) * G * D;
    alignas(64) float pm[L];
    bool one_group = true;  // groups are contiguous runs: almost every block has a single warm start
    for (int l = 0; l < L; ++l) {
      pm[l] = perturb[ms[l]];
      one_group = one_group && group[ms[l]] == group[ms[0]];
    }
    const float* ws0 = wb + group[ms[0]] * D;
    for (int j = 0; j < D; j += 2) {
#pragma omp simd
      for (int l = 0; l < L; ++l) {
        const int m = ms[l];
        const uint64_t counter = (static_cast<uint64_t>(b) * M + m) * (D / 2) + j / 2;
        const uint32_t h1 = hash32(static_cast<uint32_t>(counter * 2) ^ key);
        const uint32_t h2 = hash32(static_cast<uint32_t>(counter * 2 + 1) ^ key);
        const float u1 = (static_cast<float>(h1) + 1.0f) * static_cast<float>(1.0 / 4294967297.0);
        const float angle = static_cast<float>(h2) * static_cast<float>(6.283185307179586 / 4294967296.0);
        const float radius = std::sqrt(-2.0f * log_f(u1));
        float sa, ca;
        sincos_f(angle, sa, ca);
        P[j][l] = radius * ca;
        P[j + 1][l] = radius * sa;
      }
    }
    for (int j = 0; j < D; ++j) {  // centre + perturb sigma z, box clip
      const float sg = sigma[j], lj = lo[j], hj = hi[j];
      if (one_group) {
        const float cj = ws0[j];
#pragma omp simd
        for (int l = 0; l < L; ++l) {
          const float v = cj + pm[l] * (sg * P[j][l]);
          P[j][l] = v < lj ? lj : (v > hj ? hj : v);
        }
      } else {
        for (int l = 0; l < L; ++l) {
          const float v = wb[group[ms[l]] * D + j] + pm[l] * (sg * P[j][l]);
          P[j][l] = v < lj ? lj : (v > hj ? hj : v);
        }
      }
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
#pragma omp simd
        for (int l = 0; l < L; ++l) dv[s][l] = w0 * r0[l] + w1 * r1[l] + w2 * r2[l] + w3 * r3[l];
      }
      // contacts of step k (gait.contact_sequence: (phase0 + k f dt) mod 1 < d)
      alignas(64) float cv[4][L];
      for (int i = 0; i < 4; ++i) {
        const float* fr = P[i];
        const float* du = P[4 + i];
        const float p0 = ph[i], kf = static_cast<float>(k);
#pragma omp simd
        for (int l = 0; l < L; ++l) {
          const float ang = p0 + kf * (fr[l] * dt);  // small: f and d are box-clipped
          float fl = static_cast<float>(static_cast<int>(ang));  // floor, vectorisable
          fl = fl > ang ? fl - 1.0f : fl;
          cv[i][l] = (ang - fl) < du[l] ? 1.0f : 0.0f;
        }
      }
#pragma omp simd
      for (int l = 0; l < L; ++l) {
        float sfx = 0.f, sfy = 0.f, sfz = 0.f, tx = 0.f, ty = 0.f, tzq = 0.f, rcost = 0.f;
        float nf[4][3];
#pragma GCC unroll 4
        for (int i = 0; i < 4; ++i) {
          const float c = cv[i][l];
          // decoded p_h, F_h of leg i at step k
          const float dec[5] = {dv[2 * i][l], dv[2 * i + 1][l], dv[8 + 3 * i][l], dv[9 + 3 * i][l], dv[10 + 3 * i][l]};
          // Table 1 limits (samples.clip_horizon)
          float qx = dec[0] < px_lo ? px_lo : (dec[0] > px_hi ? px_hi : dec[0]);
          float qy = dec[1] < py_lo ? py_lo : (dec[1] > py_hi ? py_hi : dec[1]);
          qx += nominal[2 * i];
          qy += nominal[2 * i + 1];
          const float fz = dec[4] < fz_lo ? fz_lo : (dec[4] > fz_hi ? fz_hi : dec[4]);
          const float nxy = std::sqrt(dec[2] * dec[2] + dec[3] * dec[3]);
          const float lim = mu * fz;
          const float scale = nxy > lim ? lim / (nxy > 1e-12f ? nxy : 1e-12f) : 1.0f;
          const float fxh = dec[2] * scale, fyh = dec[3] * scale;
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
    float* ob = out + static_cast<long>(b) * M;
    for (int l = 0; l < L && m0 + l < M; ++l) ob[m0 + l] = std::isnan(total[l]) ? INFINITY : total[l];
  }
  return 0;
}

}  // extern "C"

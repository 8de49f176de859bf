// The elementwise parts of SamplingMPC.solve around the cost kernel, bit for bit as the torch code they
// replace (dls_quadruped.mpc.solve_glue drives them; tests/mpc/test_solve_glue.py compares every field).
//
// Bit-exactness rules: built with -ffp-contract=off (a product is rounded before it is added, as two
// torch ops do), every expression keeps torch's evaluation order (a + b * c - d * e is ((a + b c) - d e)),
// python-float constants arrive already rounded to float32 (as torch casts a scalar operand), and
// nothing here is transcendental or a reduction: torch computes the log, cos, sin, the spline matmul, the
// sums and even the square roots (torch's float sqrt is not always the correctly rounded one: measured
// 1 ulp off on a 24-element tensor) between the calls, on tensors of the shapes the torch path uses.
#include <cmath>
#include <cstdint>

#include "counter_hash.h"  // hash32 (core.hashing.hash32 on the low 32 bits)

namespace {

// torch.clamp / torch.minimum(torch.maximum(v, lo), hi): NaN propagates.
inline float clamp_nan(float v, float lo, float hi) {
  if (v != v) return v;
  const float a = v < lo ? lo : v;
  return a > hi ? hi : a;
}

}  // namespace

extern "C" {

// Cleaning of the solve's per-robot inputs: dst = src where finite, else 0 (the state: the whole row if any
// entry is not finite); bad (9, B): 1 where a row has a non-finite entry. Inputs, floats per robot: state 24,
// phase 4, base_xy 2, base_yaw 1, terrain_z 4, com height ref 1, velocity ref 2, yaw-rate ref 1, footholds 12;
// dst holds them one after the other, each (B, n).
void clean_inputs(int B, const float* s0, const float* s1, const float* s2, const float* s3, const float* s4,
                  const float* s5, const float* s6, const float* s7, const float* s8, float* dst, uint8_t* bad) {
  const float* src[9] = {s0, s1, s2, s3, s4, s5, s6, s7, s8};
  const int width[9] = {24, 4, 2, 1, 4, 1, 2, 1, 12};
  for (int t = 0; t < 9; ++t) {
    const int n = width[t];
    for (int b = 0; b < B; ++b) {
      const float* s = src[t] + static_cast<long>(b) * n;
      float* d = dst + static_cast<long>(b) * n;
      uint8_t any_bad = 0;
      for (int j = 0; j < n; ++j) {
        const bool ok = std::isfinite(s[j]);
        any_bad |= ok ? 0 : 1;
        d[j] = ok ? s[j] : 0.0f;
      }
      if (t == 0 && any_bad)
        for (int j = 0; j < n; ++j) d[j] = 0.0f;
      bad[t * B + b] = any_bad;
    }
    dst += static_cast<long>(B) * n;
  }
}

// 1 if all n entries of x are finite, else 0 (torch.isfinite(x).all()).
int all_finite(int64_t n, const float* x) {
  for (int64_t i = 0; i < n; ++i)
    if (!std::isfinite(x[i])) return 0;
  return 1;
}

// srbd.rotation_from_euler's products: R = Rz(yaw) Ry(pitch) Rx(roll) (B, 3, 3) from torch's cos and sin of
// the (B, 3) Euler angles (roll, pitch, yaw).
void rotation_from_cos_sin(int B, const float* cos_e, const float* sin_e, float* R) {
  for (int b = 0; b < B; ++b) {
    const float cr = cos_e[3 * b], cp = cos_e[3 * b + 1], cy = cos_e[3 * b + 2];
    const float sr = sin_e[3 * b], sp = sin_e[3 * b + 1], sy = sin_e[3 * b + 2];
    float* r = R + 9 * b;
    r[0] = cy * cp;
    r[1] = (cy * sp) * sr - sy * cr;
    r[2] = (cy * sp) * cr + sy * sr;
    r[3] = sy * cp;
    r[4] = (sy * sp) * sr + cy * cr;
    r[5] = (sy * sp) * cr - cy * sr;
    r[6] = -sp;
    r[7] = cp * sr;
    r[8] = cp * cr;
  }
}

// rng.normal_pair's integer part for the winner of every robot (samples.sample_encoded with K = 1):
// u1 (B, D/2) in (0, 1] and angle (B, D/2) [rad]; torch then takes log(u1), cos(angle), sin(angle).
// Also the initial cost's terms (cost.state_cost of x0 against Refs.state_vector): (B, 24)
// (x - x_ref)^2 q, summed by torch.
// warm_start_index (B,) = group[best_index].
void winner_noise_args(int B, int M, int D, int64_t seed, const int64_t* best_index, const int64_t* group,
                       int64_t* warm_start_index, float* u1, float* angle,
                       const float* x0, const float* h_ref, const float* vel_ref, const float* wz_ref,
                       const float* q, float* init_terms) {
  const uint32_t key = hash32(static_cast<uint32_t>(seed + 0x2545F491LL));
  const int half = D / 2;
  const float u_scale = static_cast<float>(1.0 / 4294967297.0);
  const float a_scale = static_cast<float>(2.0 * 3.141592653589793 / 4294967296.0);
  for (int b = 0; b < B; ++b) {
    warm_start_index[b] = group[best_index[b]];
    const int64_t counter0 = (static_cast<int64_t>(b) * M + best_index[b]) * half;
    for (int p = 0; p < half; ++p) {
      const uint32_t c = static_cast<uint32_t>(counter0 + p);
      const uint32_t h1 = hash32((c * 2u) ^ key), h2 = hash32((c * 2u + 1u) ^ key);
      u1[b * half + p] = (static_cast<float>(h1) + 1.0f) * u_scale;
      angle[b * half + p] = static_cast<float>(h2) * a_scale;
    }
    float xr[24] = {0.0f};
    xr[2] = h_ref[b];
    xr[3] = vel_ref[2 * b];
    xr[4] = vel_ref[2 * b + 1];
    xr[11] = wz_ref[b];
    for (int j = 0; j < 24; ++j) {
      const float e = x0[b * 24 + j] - xr[j];
      init_terms[b * 24 + j] = (e * e) * q[j];
    }
  }
}

// The winner's encoded sample (samples.sample_encoded): clip(centre + (perturb sigma) (radius z), lo, hi)
// with radius = sqrt(-2 log u1) (torch) and z = cos, sin of the angle (entries 2p, 2p + 1). best: (B, D).
void winner_sample(int B, int G, int D, const float* warm, const int64_t* group, const float* perturb,
                   const int64_t* best_index, const float* sigma, const float* lo, const float* hi,
                   const float* radius_in, const float* cos_a, const float* sin_a, float* best) {
  const int half = D / 2;
  for (int b = 0; b < B; ++b) {
    const int64_t m = best_index[b];
    const float* centre = warm + (static_cast<long>(b) * G + group[m]) * D;
    const float pm = perturb[m];
    for (int p = 0; p < half; ++p) {
      const float radius = radius_in[b * half + p];
      const float z[2] = {radius * cos_a[b * half + p], radius * sin_a[b * half + p]};
      for (int i = 0; i < 2; ++i) {
        const int j = 2 * p + i;
        const float v = centre[j] + (pm * sigma[j]) * z[i];
        best[b * D + j] = clamp_nan(v, lo[j], hi[j]);
      }
    }
  }
}

// Decoding the winner, part 1 (gait.contact_sequence, samples.forces_from_offsets): per robot b, step k, leg i
//   f, d: rows of the winner (stride fd_stride); F: decoded force offset s (0..11, leg-major) of robot b at step k
//   at F[b F_bs + k F_ks + s F_ss] (the encoded row itself for "first" / "discrete", torch's spline matmul);
//   phase: (B, 4);
//   c: [dt, weight, ...] (see winner_decode).
// Outputs: contact (B, N, 4) bool; F_h (B, N, 4, 3) forces before the limits; sumsq (B, N, 4) F_x^2 + F_y^2,
// whose square root torch takes.
void winner_forces(int B, int N, const float* f, const float* d, int fd_stride, const float* F, int64_t F_bs,
                   int64_t F_ks, int64_t F_ss, const float* phase, const float* c, uint8_t* contact, float* F_h,
                   float* sumsq) {
  const float dt = c[0], weight = c[1];
  for (int b = 0; b < B; ++b)
    for (int k = 0; k < N; ++k) {
      const long bk = static_cast<long>(b) * N + k;
      float cf[4];
      float nst = 0.0f;
      for (int i = 0; i < 4; ++i) {
        const float fdt = f[b * fd_stride + i] * dt;
        const float a = phase[b * 4 + i] + static_cast<float>(k) * fdt;
        float ph = std::fmod(a, 1.0f);
        if (ph != 0.0f && ph < 0.0f) ph += 1.0f;  // torch.remainder(a, 1.0)
        const bool on = ph < d[b * fd_stride + i];
        contact[bk * 4 + i] = on ? 1 : 0;
        cf[i] = on ? 1.0f : 0.0f;
        nst = nst + cf[i];
      }
      const float shift = (1.0f / (nst < 1.0f ? 1.0f : nst)) * weight;  // python float / tensor = reciprocal * float
      for (int i = 0; i < 4; ++i) {
        const float* Fi = F + b * F_bs + k * F_ks + (3 * i) * F_ss;
        float* out = F_h + (bk * 4 + i) * 3;
        out[0] = cf[i] * Fi[0];
        out[1] = cf[i] * Fi[F_ss];
        out[2] = cf[i] * (Fi[2 * F_ss] + shift);
        sumsq[bk * 4 + i] = out[0] * out[0] + out[1] * out[1];
      }
    }
}

// Decoding the winner, part 2 (samples.clip_horizon, horizontal_to_world, cost.input_step_costs' terms):
//   p: decoded offset s (0..7, leg-major) of robot b at step k at p[b p_bs + k p_ks + s p_ss] (as F above);
//   F_h, norm_xy: winner_forces' forces and torch.sqrt of its sumsq;
//   base_xy: (B, 2); cos_yaw, sin_yaw: (B,) (torch's cos/sin); terrain_z: (B, 4); foothold: (B, 4, 3)
//   reference footholds; nominal: (4, 2); r: (24,) R diagonal;
//   c: [dt, weight, px_lo, px_hi, py_lo, py_hi, fz_lo, fz_hi, mu, foot_radius] (float32).
// Outputs: p_h0 (B, 4, 2), F_h0, target0, force0 (B, 4, 3): step 0; input_terms (B, N, 24): ((u - u_ref)^2 r)
// with u = [targets (12), forces (12)] world; step_costs (B, N) NaN; init_cost (B,): NaN -> +inf in place.
// The solve's last guard: returns the number of robots with a flag in bad_in (9, B) or a non-finite action
// (best (B, D) -- f and d are its first 8 entries -- p_h0, F_h0, target0, force0).
int winner_decode(int B, int N, int D, const float* p, int64_t p_bs, int64_t p_ks, int64_t p_ss, const float* F_h,
                  const float* norm_xy, const float* base_xy,
                  const float* cos_yaw, const float* sin_yaw, const float* terrain_z, const float* foothold,
                  const float* nominal, const float* r, const float* c, float* p_h0, float* F_h0, float* target0,
                  float* force0, float* input_terms, float* step_costs, const float* best, const uint8_t* bad_in,
                  float* init_cost) {
  const float px_lo = c[2], px_hi = c[3], py_lo = c[4], py_hi = c[5];
  const float fz_lo = c[6], fz_hi = c[7], mu = c[8], foot_r = c[9];
  for (int b = 0; b < B; ++b) {
    const float cy = cos_yaw[b], sy = sin_yaw[b];
    for (int k = 0; k < N; ++k) {
      const long bk = static_cast<long>(b) * N + k;
      float u[24];
      for (int i = 0; i < 4; ++i) {
        const float* pi = p + b * p_bs + k * p_ks + (2 * i) * p_ss;
        const float* Fi = F_h + (bk * 4 + i) * 3;
        const float px = clamp_nan(pi[0], px_lo, px_hi), py = clamp_nan(pi[p_ss], py_lo, py_hi);
        const float fz = clamp_nan(Fi[2], fz_lo, fz_hi);
        const float nxy = norm_xy[bk * 4 + i];
        const float limit = mu * fz;
        const float denom = nxy != nxy ? nxy : (nxy < 1e-12f ? 1e-12f : nxy);  // clamp_min(1e-12)
        const float factor = nxy > limit ? limit / denom : 1.0f;
        const float fx = Fi[0] * factor, fy = Fi[1] * factor;
        const float qx = nominal[2 * i] + px, qy = nominal[2 * i + 1] + py;
        const float tx = (base_xy[2 * b] + cy * qx) - sy * qy;
        const float ty = (base_xy[2 * b + 1] + sy * qx) + cy * qy;
        const float tz = terrain_z[b * 4 + i] + foot_r;
        const float wx = cy * fx - sy * fy, wy = sy * fx + cy * fy;
        u[3 * i] = tx; u[3 * i + 1] = ty; u[3 * i + 2] = tz;
        u[12 + 3 * i] = wx; u[12 + 3 * i + 1] = wy; u[12 + 3 * i + 2] = fz;
        if (k == 0) {
          p_h0[(b * 4 + i) * 2] = px; p_h0[(b * 4 + i) * 2 + 1] = py;
          F_h0[(b * 4 + i) * 3] = fx; F_h0[(b * 4 + i) * 3 + 1] = fy; F_h0[(b * 4 + i) * 3 + 2] = fz;
          target0[(b * 4 + i) * 3] = tx; target0[(b * 4 + i) * 3 + 1] = ty; target0[(b * 4 + i) * 3 + 2] = tz;
          force0[(b * 4 + i) * 3] = wx; force0[(b * 4 + i) * 3 + 1] = wy; force0[(b * 4 + i) * 3 + 2] = fz;
        }
      }
      for (int j = 0; j < 24; ++j) {
        const float ref = j < 12 ? foothold[b * 12 + j] : 0.0f;
        const float e = u[j] - ref;
        input_terms[bk * 24 + j] = (e * e) * r[j];
      }
      step_costs[bk] = NAN;
    }
  }
  int num_bad = 0;
  for (int b = 0; b < B; ++b) {
    if (init_cost[b] != init_cost[b]) init_cost[b] = INFINITY;  // cost.nan_to_inf of the initial cost
    bool ok = true;
    for (int t = 0; t < 9; ++t) ok = ok && bad_in[t * B + b] == 0;
    for (int j = 0; j < D; ++j) ok = ok && std::isfinite(best[b * D + j]);
    for (int j = 0; j < 8; ++j) ok = ok && std::isfinite(p_h0[b * 8 + j]);
    for (int j = 0; j < 12; ++j)
      ok = ok && std::isfinite(F_h0[b * 12 + j]) && std::isfinite(target0[b * 12 + j]) && std::isfinite(force0[b * 12 + j]);
    num_bad += ok ? 0 : 1;
  }
  return num_bad;
}

}  // extern "C"

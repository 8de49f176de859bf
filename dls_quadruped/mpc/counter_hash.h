// The 32-bit integer hash behind the sampler's counter-based random numbers: dls_quadruped.core.hashing.hash32
// on the low 32 bits (rng.py draws normal pairs from hash32(2 c ^ key), hash32(2 c + 1 ^ key)). One definition
// for the cost kernel (rollout_kernel.cpp) and the fused solve's winner re-draw (solve_glue.cpp), which must
// produce the same bits.
#pragma once

#include <cstdint>

inline uint32_t hash32(uint32_t x) {
  x ^= x >> 16;
  x *= 0x7FEB352Du;
  x ^= x >> 15;
  x *= 0x1B873593u;
  x ^= x >> 16;
  x *= 0x5BD1E995u;
  return x ^ (x >> 13);
}

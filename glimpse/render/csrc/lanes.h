// Eight floats as one vector (GCC's vector extensions: one AVX2 register where built with it, else pairs of SSE
// registers), the helpers the kernels write their lanes with, and the moves between per-item records and lanes.
// Every operation is written for all lanes; every store writes whole vectors.
#pragma once

#ifdef __AVX__
#include <immintrin.h>
#endif

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>

namespace glimpse_lanes {

constexpr int kLanes = 8;
typedef float Floats __attribute__((vector_size(kLanes * sizeof(float))));
typedef int32_t Ints __attribute__((vector_size(kLanes * sizeof(int32_t))));
constexpr Floats kLaneOffsets = {0, 1, 2, 3, 4, 5, 6, 7};
constexpr Ints kLaneIndices = {0, 1, 2, 3, 4, 5, 6, 7};
static_assert(kLanes == 8, "kLaneOffsets and kLaneIndices list one value per lane");

inline Floats load(const float* p) {
  Floats v;
  std::memcpy(&v, p, sizeof v);
  return v;
}
inline Ints load(const int* p) {
  Ints v;
  std::memcpy(&v, p, sizeof v);
  return v;
}
inline void store(float* p, Floats v) { std::memcpy(p, &v, sizeof v); }
inline void store(int* p, Ints v) { std::memcpy(p, &v, sizeof v); }
inline Floats min(Floats a, Floats b) { return a < b ? a : b; }
inline Floats max(Floats a, Floats b) { return a > b ? a : b; }
inline int lane_bits(Ints mask) {  // bit i set where lane i of a comparison's result is set (all bits)
#ifdef __AVX__
  return _mm256_movemask_ps(reinterpret_cast<__m256>(mask));  // one instruction instead of 8 extractions
#else
  int bits = 0;
  for (int i = 0; i < kLanes; ++i) bits |= (mask[i] & 1) << i;
  return bits;
#endif
}

inline Floats sqrt_lanes(Floats v) {
#ifdef __AVX__
  return reinterpret_cast<Floats>(_mm256_sqrt_ps(reinterpret_cast<__m256>(v)));
#else
  for (int i = 0; i < kLanes; ++i) v[i] = std::sqrt(v[i]);
  return v;
#endif
}

inline Floats ceil_lanes(Floats v) {
#ifdef __AVX__
  return reinterpret_cast<Floats>(_mm256_round_ps(reinterpret_cast<__m256>(v), _MM_FROUND_TO_POS_INF | _MM_FROUND_NO_EXC));
#else
  for (int i = 0; i < kLanes; ++i) v[i] = std::ceil(v[i]);
  return v;
#endif
}

inline Floats log_lanes(Floats v) {  // std::log lane by lane: the same values as the scalar code's
  for (int i = 0; i < kLanes; ++i) v[i] = std::log(v[i]);
  return v;
}

// Items first .. first + count - 1 (count in 1..kLanes) of an [items, F] float array as F vectors, out[f] lane l
// holding field f of item first + l. Lanes past count repeat the last item, so that every lane computes on real
// inputs; scatter leaves them out.
template <int F>
inline void gather(const float* items, int64_t first, int count, Floats (&out)[F]) {
  alignas(32) float fields[F][kLanes];
  for (int l = 0; l < kLanes; ++l) {
    const float* item = items + (first + std::min(l, count - 1)) * F;
    for (int f = 0; f < F; ++f) fields[f][l] = item[f];
  }
  for (int f = 0; f < F; ++f) out[f] = load(fields[f]);
}

inline Floats gather(const float* items, int64_t first, int count) {
  Floats out[1];
  gather<1>(items, first, count, out);
  return out[0];
}

// The inverse of gather: lanes 0 .. count - 1 of the F vectors written to items first .. first + count - 1.
template <int F>
inline void scatter(const Floats (&in)[F], float* items, int64_t first, int count) {
  alignas(32) float fields[F][kLanes];
  for (int f = 0; f < F; ++f) store(fields[f], in[f]);
  for (int l = 0; l < count; ++l) {
    float* item = items + (first + l) * F;
    for (int f = 0; f < F; ++f) item[f] = fields[f][l];
  }
}

inline void scatter(Floats in, float* items, int64_t first, int count) { scatter<1>({in}, items, first, count); }

}  // namespace glimpse_lanes

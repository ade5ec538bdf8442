// The closest rotation of a 3x3 matrix (the orthogonal polar factor), as glimpse/humans/person.py's
// polar_rotation computes it: Newton's iteration X <- (X + X^-T) / 2 from X / |det X|^(1/3). Shared by the
// posing kernels (pose_cpu.cpp, skinning_cpu.cpp).
#pragma once

#include <algorithm>
#include <cmath>

namespace glimpse_polar {

constexpr int kPolarIterations = 6;  // person.py POLAR_ITERATIONS
constexpr float kDetFloor = 1e-12f;  // person.py DET_FLOOR

inline float det3(const float* m) {
  return m[0] * (m[4] * m[8] - m[5] * m[7]) - m[1] * (m[3] * m[8] - m[5] * m[6]) + m[2] * (m[3] * m[7] - m[4] * m[6]);
}

// The closest rotation to the 3x3 row-major m (positive determinant), as person.polar_rotation computes it.
inline void polar(const float* m, float* x) {
  const float scale = std::cbrt(std::max(std::fabs(det3(m)), kDetFloor));
  for (int k = 0; k < 9; ++k) x[k] = m[k] / scale;
  for (int it = 0; it < kPolarIterations; ++it) {
    const float* r0 = x;
    const float* r1 = x + 3;
    const float* r2 = x + 6;
    float cof[9] = {r1[1] * r2[2] - r1[2] * r2[1], r1[2] * r2[0] - r1[0] * r2[2], r1[0] * r2[1] - r1[1] * r2[0],
                    r2[1] * r0[2] - r2[2] * r0[1], r2[2] * r0[0] - r2[0] * r0[2], r2[0] * r0[1] - r2[1] * r0[0],
                    r0[1] * r1[2] - r0[2] * r1[1], r0[2] * r1[0] - r0[0] * r1[2], r0[0] * r1[1] - r0[1] * r1[0]};
    const float det = std::max(r0[0] * cof[0] + r0[1] * cof[1] + r0[2] * cof[2], kDetFloor);
    for (int k = 0; k < 9; ++k) x[k] = 0.5f * (x[k] + cof[k] / det);
  }
}

}  // namespace glimpse_polar

// The 3DGS real spherical-harmonics basis (glimpse/render/sh.py: ordering, signs, constants) and its
// derivative, shared by the kernels that colour Gaussians (preprocess_cpu.cpp, pose_cpu.cpp).
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>

namespace glimpse_sh {

// 3DGS's SH constants (glimpse/render/sh.py).
constexpr float C0 = 0.28209479177387814f;
constexpr float C1 = 0.4886025119029199f;
constexpr float C2[5] = {1.0925484305920792f, -1.0925484305920792f, 0.31539156525252005f, -1.0925484305920792f,
                         0.5462742152960396f};
constexpr float C3[7] = {-0.5900435899266435f, 2.890611442640554f, -0.4570457994644658f, 0.3731763325901154f,
                         -0.4570457994644658f, 1.445305721320277f, -0.5900435899266435f};
constexpr float kRgbOffset = 0.5f;  // sh.py RGB_OFFSET
constexpr float kNormFloor = 1e-12f;  // torch.nn.functional.normalize's eps (sh.py normalises directions)

// The SH basis up to `degree` at the unit direction (x, y, z): K = (degree + 1)^2 values.
inline void sh_basis(int degree, float x, float y, float z, float* b) {
  b[0] = C0;
  if (degree < 1) return;
  b[1] = -C1 * y, b[2] = C1 * z, b[3] = -C1 * x;
  if (degree < 2) return;
  const float xx = x * x, yy = y * y, zz = z * z;
  b[4] = C2[0] * x * y, b[5] = C2[1] * y * z, b[6] = C2[2] * (2 * zz - xx - yy), b[7] = C2[3] * x * z,
  b[8] = C2[4] * (xx - yy);
  if (degree < 3) return;
  b[9] = C3[0] * y * (3 * xx - yy), b[10] = C3[1] * x * y * z, b[11] = C3[2] * y * (4 * zz - xx - yy),
  b[12] = C3[3] * z * (2 * zz - 3 * xx - 3 * yy), b[13] = C3[4] * x * (4 * zz - xx - yy),
  b[14] = C3[5] * z * (xx - yy), b[15] = C3[6] * x * (xx - 3 * yy);
}

// Gradient with respect to the unit direction of sum_k v_b[k] * basis_k(x, y, z).
inline void sh_basis_backward(int degree, float x, float y, float z, const float* v_b, float& gx, float& gy,
                              float& gz) {
  gx = gy = gz = 0;
  if (degree < 1) return;
  gx += -C1 * v_b[3], gy += -C1 * v_b[1], gz += C1 * v_b[2];
  if (degree < 2) return;
  const float xx = x * x, yy = y * y, zz = z * z;
  gx += C2[0] * y * v_b[4] - 2 * C2[2] * x * v_b[6] + C2[3] * z * v_b[7] + 2 * C2[4] * x * v_b[8];
  gy += C2[0] * x * v_b[4] + C2[1] * z * v_b[5] - 2 * C2[2] * y * v_b[6] - 2 * C2[4] * y * v_b[8];
  gz += C2[1] * y * v_b[5] + 4 * C2[2] * z * v_b[6] + C2[3] * x * v_b[7];
  if (degree < 3) return;
  gx += 6 * C3[0] * x * y * v_b[9] + C3[1] * y * z * v_b[10] - 2 * C3[2] * x * y * v_b[11] -
        6 * C3[3] * x * z * v_b[12] + C3[4] * (4 * zz - 3 * xx - yy) * v_b[13] + 2 * C3[5] * x * z * v_b[14] +
        C3[6] * (3 * xx - 3 * yy) * v_b[15];
  gy += C3[0] * (3 * xx - 3 * yy) * v_b[9] + C3[1] * x * z * v_b[10] + C3[2] * (4 * zz - xx - 3 * yy) * v_b[11] -
        6 * C3[3] * y * z * v_b[12] - 2 * C3[4] * x * y * v_b[13] - 2 * C3[5] * y * z * v_b[14] -
        6 * C3[6] * x * y * v_b[15];
  gz += C3[1] * x * y * v_b[10] + 8 * C3[2] * y * z * v_b[11] + C3[3] * (6 * zz - 3 * xx - 3 * yy) * v_b[12] +
        8 * C3[4] * x * z * v_b[13] + C3[5] * (xx - yy) * v_b[14];
}


// The colour max(sum_k Y_k(dir / |dir|) coeffs[k * channels + c] + 0.5, 0) seen along ``dir`` (any length),
// from one Gaussian's coefficients [K >= (degree + 1)^2, channels] -> rgb [channels] (sh.py sh_to_rgb).
inline void sh_colour(int degree, const float* dir, const float* coeffs, int64_t channels, float* rgb) {
  const float norm = std::max(std::sqrt(dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]), kNormFloor);
  float b[16];
  sh_basis(degree, dir[0] / norm, dir[1] / norm, dir[2] / norm, b);
  const int terms = (degree + 1) * (degree + 1);
  for (int64_t c = 0; c < channels; ++c) {
    float sum = 0.0f;
    for (int k = 0; k < terms; ++k) sum += b[k] * coeffs[k * channels + c];
    rgb[c] = std::max(sum + kRgbOffset, 0.0f);
  }
}

}  // namespace glimpse_sh

// Per-Gaussian preprocessing on the CPU, forward and hand-written backward: covariances from
// rotations and scales, and colours from spherical harmonics. The maths and conventions are those
// of glimpse/render/projection.py (quat_scale_to_covariance_torch) and glimpse/render/sh.py
// (sh_to_rgb_torch), the references the tests compare these against. One pass per Gaussian in
// place of PyTorch's dozens of elementwise kernels and their autograd graph.
#include <torch/extension.h>
#include <ATen/Parallel.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "lanes.h"
#include "sh_basis.h"

namespace {

using namespace glimpse_lanes;
using namespace glimpse_sh;

constexpr int64_t kGrain = 1024;

// Rotation matrices (row-major) of unit quaternions (w, x, y, z).
inline void rotation(Floats w, Floats x, Floats y, Floats z, Floats R[9]) {
  R[0] = 1.0f - 2.0f * (y * y + z * z), R[1] = 2.0f * (x * y - w * z), R[2] = 2.0f * (x * z + w * y);
  R[3] = 2.0f * (x * y + w * z), R[4] = 1.0f - 2.0f * (x * x + z * z), R[5] = 2.0f * (y * z - w * x);
  R[6] = 2.0f * (x * z - w * y), R[7] = 2.0f * (y * z + w * x), R[8] = 1.0f - 2.0f * (x * x + y * y);
}

// Unit quaternions q / max(|q|, floor) of quaternions q [4] (any length), and the lengths divided by.
inline Floats normalised(const Floats* q, Floats* unit) {
  const Floats norm = max(sqrt_lanes(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]), Floats{} + kNormFloor);
  for (int k = 0; k < 4; ++k) unit[k] = q[k] / norm;
  return norm;
}

// M = R S (R the rotation, S = diag(scales)): the covariance is M Mᵀ.
inline void rotation_scale(const Floats* R, const Floats* scales, Floats* M) {
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) M[3 * i + j] = R[3 * i + j] * scales[j];
}

void check_float(const std::vector<torch::Tensor>& tensors, const char* what) {
  for (const auto& t : tensors)
    TORCH_CHECK(t.dtype() == torch::kFloat32 && t.is_contiguous() && t.device().is_cpu(), what,
                ": contiguous float32 CPU tensors expected");
}

}  // namespace

// quats [N, 4] (wxyz, any length), scales [N, 3] -> covariances [N, 3, 3] = R S S^T R^T. Eight Gaussians at a
// time, one per lane (lanes.h).
torch::Tensor covariance_forward(torch::Tensor quats, torch::Tensor scales) {
  check_float({quats, scales}, "covariance_forward");
  const int64_t N = quats.size(0);
  auto out = torch::empty({N, 3, 3}, quats.options());
  const float *q = quats.data_ptr<float>(), *s = scales.data_ptr<float>();
  float* cov = out.data_ptr<float>();
  at::parallel_for(0, N, kGrain, [&](int64_t begin, int64_t end) {
    for (int64_t n = begin; n < end; n += kLanes) {  // Gaussians n .. n + count - 1, one per lane
      const int count = static_cast<int>(std::min<int64_t>(kLanes, end - n));
      Floats quat[4], unit[4], scale[3], R[9], M[9], c[9];
      gather(q, n, count, quat);
      gather(s, n, count, scale);
      normalised(quat, unit);
      rotation(unit[0], unit[1], unit[2], unit[3], R);
      rotation_scale(R, scale, M);
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) c[3 * i + j] = M[3 * i] * M[3 * j] + M[3 * i + 1] * M[3 * j + 1] + M[3 * i + 2] * M[3 * j + 2];
      scatter(c, cov, n, count);
    }
  });
  return out;
}

// Gradients of a loss with respect to quats [N, 4] and scales [N, 3], given v_cov [N, 3, 3].
std::vector<torch::Tensor> covariance_backward(torch::Tensor quats, torch::Tensor scales, torch::Tensor v_cov) {
  v_cov = v_cov.contiguous();
  check_float({quats, scales, v_cov}, "covariance_backward");
  const int64_t N = quats.size(0);
  auto v_quats = torch::empty_like(quats), v_scales = torch::empty_like(scales);
  const float *q = quats.data_ptr<float>(), *s = scales.data_ptr<float>(), *vc = v_cov.data_ptr<float>();
  float *vq = v_quats.data_ptr<float>(), *vs = v_scales.data_ptr<float>();
  at::parallel_for(0, N, kGrain, [&](int64_t begin, int64_t end) {
    for (int64_t n = begin; n < end; n += kLanes) {  // Gaussians n .. n + count - 1, one per lane
      const int count = static_cast<int>(std::min<int64_t>(kLanes, end - n));
      Floats quat[4], unit[4], scale[3], G[9], R[9], M[9], vM[9], vR[9], v_scale[3];
      gather(q, n, count, quat);
      gather(s, n, count, scale);
      gather(vc, n, count, G);
      const Floats norm = normalised(quat, unit);
      const Floats w = unit[0], x = unit[1], y = unit[2], z = unit[3];
      rotation(w, x, y, z, R);
      rotation_scale(R, scale, M);
      for (int i = 0; i < 3; ++i)  // cov = M M^T: v_M = (G + G^T) M
        for (int j = 0; j < 3; ++j) {
          Floats sum{};
          for (int k = 0; k < 3; ++k) sum += (G[3 * i + k] + G[3 * k + i]) * M[3 * k + j];
          vM[3 * i + j] = sum;
        }
      for (int j = 0; j < 3; ++j) {
        v_scale[j] = vM[j] * R[j] + vM[3 + j] * R[3 + j] + vM[6 + j] * R[6 + j];
        for (int i = 0; i < 3; ++i) vR[3 * i + j] = vM[3 * i + j] * scale[j];
      }
      scatter(v_scale, vs, n, count);
      // through the rotation matrix of the unit quaternion
      const Floats vw = 2.0f * (-z * vR[1] + y * vR[2] + z * vR[3] - x * vR[5] - y * vR[6] + x * vR[7]);
      const Floats vx = 2.0f * (y * vR[1] + z * vR[2] + y * vR[3] - 2.0f * x * vR[4] - w * vR[5] + z * vR[6] +
                                w * vR[7] - 2.0f * x * vR[8]);
      const Floats vy = 2.0f * (-2.0f * y * vR[0] + x * vR[1] + w * vR[2] + x * vR[3] + z * vR[5] - w * vR[6] +
                                z * vR[7] - 2.0f * y * vR[8]);
      const Floats vz = 2.0f * (-2.0f * z * vR[0] - w * vR[1] + x * vR[2] + w * vR[3] - 2.0f * z * vR[4] +
                                y * vR[5] + x * vR[6] + y * vR[7]);
      // and through the normalisation q / |q|
      const Floats along = w * vw + x * vx + y * vy + z * vz;
      scatter({(vw - w * along) / norm, (vx - x * along) / norm, (vy - y * along) / norm, (vz - z * along) / norm},
              vq, n, count);
    }
  });
  return {v_quats, v_scales};
}

// Colours max(sum_k Y_k(dirs) coeffs[:, k, :] + 0.5, 0) [N, C] from coeffs [N, K >= (degree + 1)^2, C] and
// view directions dirs [N, 3] (any length).
torch::Tensor sh_forward(int64_t degree, torch::Tensor coeffs, torch::Tensor dirs) {
  check_float({coeffs, dirs}, "sh_forward");
  const int64_t N = coeffs.size(0), K = coeffs.size(1), C = coeffs.size(2), used = (degree + 1) * (degree + 1);
  TORCH_CHECK(degree >= 0 && degree <= 3 && K >= used, "sh_forward: bad degree or too few coefficients");
  auto out = torch::empty({N, C}, coeffs.options());
  const float *sh = coeffs.data_ptr<float>(), *d = dirs.data_ptr<float>();
  float* rgb = out.data_ptr<float>();
  at::parallel_for(0, N, kGrain, [&](int64_t begin, int64_t end) {
    for (int64_t n = begin; n < end; ++n) sh_colour(static_cast<int>(degree), d + 3 * n, sh + n * K * C, C, rgb + n * C);
  });
  return out;
}

// Gradients with respect to coeffs [N, K, C] (zero beyond the degree) and dirs [N, 3], given v_rgb [N, C].
std::vector<torch::Tensor> sh_backward(int64_t degree, torch::Tensor coeffs, torch::Tensor dirs, torch::Tensor v_rgb) {
  v_rgb = v_rgb.contiguous();
  check_float({coeffs, dirs, v_rgb}, "sh_backward");
  const int64_t N = coeffs.size(0), K = coeffs.size(1), C = coeffs.size(2), used = (degree + 1) * (degree + 1);
  TORCH_CHECK(degree >= 0 && degree <= 3 && K >= used, "sh_backward: bad degree or too few coefficients");
  // every coefficient is written below (0 beyond the degree): no fill beforehand, one pass over [N, K, C] less
  auto v_coeffs = torch::empty_like(coeffs), v_dirs = torch::empty_like(dirs);
  const float *sh = coeffs.data_ptr<float>(), *d = dirs.data_ptr<float>(), *g = v_rgb.data_ptr<float>();
  float *vsh = v_coeffs.data_ptr<float>(), *vd = v_dirs.data_ptr<float>();
  at::parallel_for(0, N, kGrain, [&](int64_t begin, int64_t end) {
    float b[16], v_b[16];
    for (int64_t n = begin; n < end; ++n) {
      const float* dn = d + 3 * n;
      const float norm = std::max(std::sqrt(dn[0] * dn[0] + dn[1] * dn[1] + dn[2] * dn[2]), kNormFloor);
      const float x = dn[0] / norm, y = dn[1] / norm, z = dn[2] / norm;
      sh_basis(static_cast<int>(degree), x, y, z, b);
      std::fill(v_b, v_b + 16, 0.0f);
      std::fill(vsh + (n * K + used) * C, vsh + (n + 1) * K * C, 0.0f);
      for (int64_t c = 0; c < C; ++c) {
        float sum = 0;
        for (int64_t k = 0; k < used; ++k) sum += b[k] * sh[(n * K + k) * C + c];
        const float gc = sum + kRgbOffset >= 0.0f ? g[n * C + c] : 0.0f;  // clamp_min passes ties (PyTorch)
        for (int64_t k = 0; k < used; ++k) {
          vsh[(n * K + k) * C + c] = b[k] * gc;
          v_b[k] += sh[(n * K + k) * C + c] * gc;
        }
      }
      float gx, gy, gz;
      sh_basis_backward(static_cast<int>(degree), x, y, z, v_b, gx, gy, gz);
      const float along = x * gx + y * gy + z * gz;  // through the normalisation d / |d|
      vd[3 * n] = (gx - x * along) / norm;
      vd[3 * n + 1] = (gy - y * along) / norm;
      vd[3 * n + 2] = (gz - z * along) / norm;
    }
  });
  return {v_coeffs, v_dirs};
}

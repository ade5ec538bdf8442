// Posing a frozen person's Gaussians for one frame, forward only, on the CPU (rendering finished runs).
// The maths and conventions are those of glimpse/humans/person.py (PersonGaussians.posed, the reference
// the tests compare this against): per Gaussian the blended transform A = (sum_j w_j P_j) C^-1 with C^-1
// cached, means A mu, covariances A Sigma A^T with Sigma the canonical covariance, view
// directions rotated into the canonical frame by the closest rotation of A (Newton's polar iteration
// from A / |det A|^(1/3)), colours from spherical harmonics of degree 0-3 in the 3DGS convention.
// One Gaussian per iteration, independent of the others: parallel over Gaussians, nothing shared.
#include <torch/extension.h>
#include <ATen/Parallel.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "polar.h"
#include "sh_basis.h"

namespace {

using namespace glimpse_polar;
using namespace glimpse_sh;

constexpr int64_t kGrain = 1024;

}  // namespace

// weights [N, J]; joint_transforms [J, 4, 4] (the frame's P_j); canonical_inverse [N, 4, 4] ((sum_j w_j C_j)^-1);
// means [N, 3] and covariances [N, 3, 3] (canonical); sh [N, K, 3]; degree <= sqrt(K) - 1;
// camera_centre [3] (world). Returns posed means [N, 3], covariances [N, 3, 3] and colours [N, 3].
std::vector<torch::Tensor> pose_forward(torch::Tensor weights, torch::Tensor joint_transforms,
                                        torch::Tensor canonical_inverse, torch::Tensor means,
                                        torch::Tensor covariances, torch::Tensor sh, int64_t degree,
                                        torch::Tensor camera_centre) {
  for (const auto* t : {&weights, &joint_transforms, &canonical_inverse, &means, &covariances, &sh,
                        &camera_centre})
    TORCH_CHECK(t->dtype() == torch::kFloat32 && t->is_contiguous() && t->device().is_cpu(),
                "pose_cpu: contiguous float32 CPU tensors expected");
  const int64_t N = means.size(0), J = weights.size(1), K = sh.size(1);
  TORCH_CHECK(weights.size(0) == N && joint_transforms.size(0) == J && canonical_inverse.size(0) == N &&
                  covariances.size(0) == N && sh.size(0) == N && sh.size(2) == 3,
              "pose_cpu: inconsistent shapes");
  TORCH_CHECK(degree >= 0 && degree <= 3 && (degree + 1) * (degree + 1) <= K, "pose_cpu: bad SH degree");
  auto out_means = torch::empty({N, 3}, means.options());
  auto out_cov = torch::empty({N, 3, 3}, means.options());
  auto out_rgb = torch::empty({N, 3}, means.options());
  const float* W = weights.data_ptr<float>();
  const float* P = joint_transforms.data_ptr<float>();
  const float* Ci = canonical_inverse.data_ptr<float>();
  const float* mu = means.data_ptr<float>();
  const float* Sigma = covariances.data_ptr<float>();
  const float* S = sh.data_ptr<float>();
  const float* c = camera_centre.data_ptr<float>();
  float* om = out_means.data_ptr<float>();
  float* oc = out_cov.data_ptr<float>();
  float* orgb = out_rgb.data_ptr<float>();

  at::parallel_for(0, N, kGrain, [&](int64_t begin, int64_t end) {
    for (int64_t n = begin; n < end; ++n) {
      float B[12] = {0};  // the top three rows of sum_j w_j P_j
      const float* w = W + n * J;
      for (int64_t j = 0; j < J; ++j) {
        if (w[j] == 0.0f) continue;
        const float* p = P + j * 16;
        for (int k = 0; k < 12; ++k) B[k] += w[j] * p[k];
      }
      const float* ci = Ci + n * 16;
      float A[12];  // B @ C^-1 (both affine)
      for (int r = 0; r < 3; ++r) {
        for (int col = 0; col < 4; ++col)
          A[4 * r + col] = B[4 * r] * ci[col] + B[4 * r + 1] * ci[4 + col] + B[4 * r + 2] * ci[8 + col];
        A[4 * r + 3] += B[4 * r + 3];
      }
      const float* m = mu + 3 * n;
      float* pm = om + 3 * n;
      for (int r = 0; r < 3; ++r) pm[r] = A[4 * r] * m[0] + A[4 * r + 1] * m[1] + A[4 * r + 2] * m[2] + A[4 * r + 3];
      const float* sigma = Sigma + 9 * n;
      float M[9];  // A_3x3 @ Sigma
      for (int r = 0; r < 3; ++r)
        for (int col = 0; col < 3; ++col)
          M[3 * r + col] = A[4 * r] * sigma[col] + A[4 * r + 1] * sigma[3 + col] + A[4 * r + 2] * sigma[6 + col];
      float* cov = oc + 9 * n;  // M @ A_3x3^T
      for (int r = 0; r < 3; ++r)
        for (int col = 0; col < 3; ++col)
          cov[3 * r + col] = M[3 * r] * A[4 * col] + M[3 * r + 1] * A[4 * col + 1] + M[3 * r + 2] * A[4 * col + 2];

      float d[3] = {pm[0] - c[0], pm[1] - c[1], pm[2] - c[2]};
      if (degree > 0) {  // into the canonical frame: R^T d
        const float linear[9] = {A[0], A[1], A[2], A[4], A[5], A[6], A[8], A[9], A[10]};
        float R[9];
        polar(linear, R);
        const float e[3] = {R[0] * d[0] + R[3] * d[1] + R[6] * d[2], R[1] * d[0] + R[4] * d[1] + R[7] * d[2],
                            R[2] * d[0] + R[5] * d[1] + R[8] * d[2]};
        d[0] = e[0], d[1] = e[1], d[2] = e[2];
      }
      sh_colour(static_cast<int>(degree), d, S + n * K * 3, 3, orgb + 3 * n);
    }
  });
  return {out_means, out_cov, out_rgb};
}

// matrices [N, 3, 3] (positive determinant) -> their closest rotations [N, 3, 3] (person.polar_rotation).
torch::Tensor polar_rotations(torch::Tensor matrices) {
  TORCH_CHECK(matrices.dtype() == torch::kFloat32 && matrices.is_contiguous() && matrices.device().is_cpu(),
              "polar_rotations: contiguous float32 CPU tensor expected");
  const int64_t N = matrices.size(0);
  auto out = torch::empty_like(matrices);
  const float* m = matrices.data_ptr<float>();
  float* x = out.data_ptr<float>();
  at::parallel_for(0, N, kGrain, [&](int64_t begin, int64_t end) {
    for (int64_t n = begin; n < end; ++n) polar(m + 9 * n, x + 9 * n);
  });
  return out;
}

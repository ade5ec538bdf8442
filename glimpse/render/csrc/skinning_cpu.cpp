// Posing a person's canonical Gaussians for training, forward and hand-written backward, on the CPU.
// The maths and conventions are those of glimpse/humans/person.py (PersonGaussians.posed_with) and
// glimpse/body/skinning.py, the PyTorch references the tests compare this against. Per Gaussian:
//   w   = the skin weights at its canonical mean, trilinear in the baked grid (grid_sample, align_corners,
//         border padding: no gradient where the mean is outside the grid's cube)
//   A   = (sum_j w_j P_j) (sum_j w_j C_j)^-1   (P_j: the frame's joint transforms, C_j: the canonical ones)
//   mean' = A mu,  cov' = L Sigma L^T (L: A's linear part),  dir = R^T (mean' - camera centre)
// with R the closest rotation of L (Newton's polar iteration; no gradient flows through R). Gradients
// reach the means (through mean', cov' and the weights), the covariances and the P_j (summed over the
// Gaussians, per thread, then in a fixed order: the same on every run).
#include <torch/extension.h>
#include <omp.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "polar.h"

namespace {

constexpr int kMaxJoints = 64;  // per-Gaussian weights live on the stack (SMPL: 24)

// The weight grid, joints last: [z, y, x, J] (a lookup reads 8 runs of J floats, not 8 x J scattered ones),
// spanning the cube [lo, hi].
struct Grid {
  const float* values;
  int64_t J, R;
  float lo[3], hi[3];
};

// Trilinear weights w [J] at p, and (when dw is given) dw [J][3] = dw_j / dp.
inline void grid_lookup(const Grid& g, const float* p, float* w, float* dw) {
  int64_t base[3];
  float frac[3], scale[3];
  for (int a = 0; a < 3; ++a) {
    const float unit = (p[a] - g.lo[a]) / (g.hi[a] - g.lo[a]) * 2.0f - 1.0f;
    float x = (unit + 1.0f) / 2.0f * static_cast<float>(g.R - 1);
    scale[a] = static_cast<float>(g.R - 1) / (g.hi[a] - g.lo[a]);  // dx / dp
    if (x < 0.0f || x > static_cast<float>(g.R - 1)) {  // border padding: clamped, no gradient
      x = std::min(std::max(x, 0.0f), static_cast<float>(g.R - 1));
      scale[a] = 0.0f;
    }
    base[a] = std::min(static_cast<int64_t>(std::floor(x)), g.R - 2);
    frac[a] = x - static_cast<float>(base[a]);
  }
  const int64_t stride_y = g.R, stride_z = g.R * g.R;
  std::fill(w, w + g.J, 0.0f);
  if (dw != nullptr) std::fill(dw, dw + 3 * g.J, 0.0f);
  for (int corner = 0; corner < 8; ++corner) {
    const int cx = corner & 1, cy = (corner >> 1) & 1, cz = corner >> 2;
    const float fx = cx ? frac[0] : 1.0f - frac[0], fy = cy ? frac[1] : 1.0f - frac[1];
    const float fz = cz ? frac[2] : 1.0f - frac[2];
    const float sx = cx ? 1.0f : -1.0f, sy = cy ? 1.0f : -1.0f, sz = cz ? 1.0f : -1.0f;
    const float weight = fx * fy * fz;
    const float d[3] = {sx * fy * fz * scale[0], fx * sy * fz * scale[1], fx * fy * sz * scale[2]};
    const float* values = g.values + ((base[2] + cz) * stride_z + (base[1] + cy) * stride_y + base[0] + cx) * g.J;
    for (int64_t j = 0; j < g.J; ++j) {
      const float value = values[j];
      w[j] += weight * value;
      if (dw != nullptr)
        for (int a = 0; a < 3; ++a) dw[3 * j + a] += d[a] * value;
    }
  }
}

// An affine map as its top three rows [L | t], row-major (12 floats).
inline void blend(const float* w, const float* transforms, int64_t J, float* out) {
  std::fill(out, out + 12, 0.0f);
  for (int64_t j = 0; j < J; ++j) {
    if (w[j] == 0.0f) continue;
    for (int k = 0; k < 12; ++k) out[k] += w[j] * transforms[16 * j + k];
  }
}

inline void invert_affine(const float* m, float* out) {
  const float L[9] = {m[0], m[1], m[2], m[4], m[5], m[6], m[8], m[9], m[10]};
  float inv[9];
  const float det = glimpse_polar::det3(L);
  inv[0] = (L[4] * L[8] - L[5] * L[7]) / det, inv[1] = (L[2] * L[7] - L[1] * L[8]) / det;
  inv[2] = (L[1] * L[5] - L[2] * L[4]) / det, inv[3] = (L[5] * L[6] - L[3] * L[8]) / det;
  inv[4] = (L[0] * L[8] - L[2] * L[6]) / det, inv[5] = (L[2] * L[3] - L[0] * L[5]) / det;
  inv[6] = (L[3] * L[7] - L[4] * L[6]) / det, inv[7] = (L[1] * L[6] - L[0] * L[7]) / det;
  inv[8] = (L[0] * L[4] - L[1] * L[3]) / det;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) out[4 * r + c] = inv[3 * r + c];
    out[4 * r + 3] = -(inv[3 * r] * m[3] + inv[3 * r + 1] * m[7] + inv[3 * r + 2] * m[11]);
  }
}

inline void compose(const float* a, const float* b, float* out) {  // a o b, both affine
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 4; ++c) out[4 * r + c] = a[4 * r] * b[c] + a[4 * r + 1] * b[4 + c] + a[4 * r + 2] * b[8 + c];
    out[4 * r + 3] += a[4 * r + 3];
  }
}

struct Inputs {
  const float *means, *covariances, *posed, *canonical, *centre;
  Grid grid;
  int64_t N;
};

// Everything the forward computes for Gaussian n that the backward needs again.
struct Posed {
  float w[kMaxJoints], B[12], D[12], Dinv[12], A[12], mean[3], R[9];
};

inline void pose_one(const Inputs& in, int64_t n, Posed& s, float* dw) {
  grid_lookup(in.grid, in.means + 3 * n, s.w, dw);
  blend(s.w, in.posed, in.grid.J, s.B);
  blend(s.w, in.canonical, in.grid.J, s.D);
  invert_affine(s.D, s.Dinv);
  compose(s.B, s.Dinv, s.A);
  const float* m = in.means + 3 * n;
  for (int r = 0; r < 3; ++r) s.mean[r] = s.A[4 * r] * m[0] + s.A[4 * r + 1] * m[1] + s.A[4 * r + 2] * m[2] + s.A[4 * r + 3];
  const float L[9] = {s.A[0], s.A[1], s.A[2], s.A[4], s.A[5], s.A[6], s.A[8], s.A[9], s.A[10]};
  glimpse_polar::polar(L, s.R);
}

Inputs make_inputs(const torch::Tensor& means, const torch::Tensor& covariances, const torch::Tensor& grid,
                   const torch::Tensor& bounds, const torch::Tensor& posed, const torch::Tensor& canonical,
                   const torch::Tensor& centre) {
  for (const auto* t : {&means, &covariances, &grid, &bounds, &posed, &canonical, &centre})
    TORCH_CHECK(t->dtype() == torch::kFloat32 && t->is_contiguous() && t->device().is_cpu(),
                "skinning_cpu: contiguous float32 CPU tensors expected");
  TORCH_CHECK(grid.dim() == 4 && grid.size(3) <= kMaxJoints && grid.size(0) >= 2,
              "skinning_cpu: grid [R, R, R, J <= ", kMaxJoints, "] expected");
  Inputs in{means.data_ptr<float>(), covariances.data_ptr<float>(), posed.data_ptr<float>(),
            canonical.data_ptr<float>(), centre.data_ptr<float>(), {grid.data_ptr<float>(), grid.size(3), grid.size(0)},
            means.size(0)};
  for (int a = 0; a < 3; ++a) in.grid.lo[a] = bounds.data_ptr<float>()[a], in.grid.hi[a] = bounds.data_ptr<float>()[3 + a];
  return in;
}

}  // namespace

// means [N, 3], covariances [N, 3, 3] (canonical); grid [R, R, R, J] (joints last); bounds [2, 3] (the cube's corners);
// posed, canonical [J, 4, 4] (the frame's and the canonical joint transforms); centre [3] (camera, world).
// Returns posed means [N, 3], posed covariances [N, 3, 3] and view directions in the canonical frame [N, 3].
std::vector<torch::Tensor> skin_forward(torch::Tensor means, torch::Tensor covariances, torch::Tensor grid,
                                        torch::Tensor bounds, torch::Tensor posed, torch::Tensor canonical,
                                        torch::Tensor centre) {
  const Inputs in = make_inputs(means, covariances, grid, bounds, posed, canonical, centre);
  auto out_means = torch::empty({in.N, 3}, means.options()), out_cov = torch::empty({in.N, 3, 3}, means.options());
  auto out_dirs = torch::empty({in.N, 3}, means.options());
  float *om = out_means.data_ptr<float>(), *oc = out_cov.data_ptr<float>(), *od = out_dirs.data_ptr<float>();
#pragma omp parallel for schedule(static) num_threads(at::get_num_threads())
  for (int64_t n = 0; n < in.N; ++n) {
    Posed s;
    pose_one(in, n, s, nullptr);
    const float* sigma = in.covariances + 9 * n;
    float M[9];  // L Sigma
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c)
        M[3 * r + c] = s.A[4 * r] * sigma[c] + s.A[4 * r + 1] * sigma[3 + c] + s.A[4 * r + 2] * sigma[6 + c];
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c)
        oc[9 * n + 3 * r + c] = M[3 * r] * s.A[4 * c] + M[3 * r + 1] * s.A[4 * c + 1] + M[3 * r + 2] * s.A[4 * c + 2];
    const float d[3] = {s.mean[0] - in.centre[0], s.mean[1] - in.centre[1], s.mean[2] - in.centre[2]};
    for (int r = 0; r < 3; ++r) {
      om[3 * n + r] = s.mean[r];
      od[3 * n + r] = s.R[r] * d[0] + s.R[3 + r] * d[1] + s.R[6 + r] * d[2];  // R^T d
    }
  }
  return {out_means, out_cov, out_dirs};
}

// Gradients with respect to means [N, 3], covariances [N, 3, 3] and posed [J, 4, 4], given those of the
// posed means, covariances and directions.
std::vector<torch::Tensor> skin_backward(torch::Tensor means, torch::Tensor covariances, torch::Tensor grid,
                                         torch::Tensor bounds, torch::Tensor posed, torch::Tensor canonical,
                                         torch::Tensor centre, torch::Tensor v_means, torch::Tensor v_cov,
                                         torch::Tensor v_dirs) {
  v_means = v_means.contiguous(), v_cov = v_cov.contiguous(), v_dirs = v_dirs.contiguous();
  const Inputs in = make_inputs(means, covariances, grid, bounds, posed, canonical, centre);
  const int64_t J = in.grid.J;
  const int threads = at::get_num_threads();
  auto g_means = torch::empty({in.N, 3}, means.options()), g_cov = torch::empty({in.N, 3, 3}, means.options());
  auto partial = torch::zeros({threads, J, 4, 4}, means.options());
  float *gm = g_means.data_ptr<float>(), *gc = g_cov.data_ptr<float>(), *gp_all = partial.data_ptr<float>();
  const float *vm = v_means.data_ptr<float>(), *vc = v_cov.data_ptr<float>(), *vd = v_dirs.data_ptr<float>();
#pragma omp parallel num_threads(threads)
  {
    float* gp = gp_all + omp_get_thread_num() * J * 16;
    std::vector<float> dw(3 * J);
#pragma omp for schedule(static)
    for (int64_t n = 0; n < in.N; ++n) {
      Posed s;
      pose_one(in, n, s, dw.data());
      const float* m = in.means + 3 * n;
      const float* sigma = in.covariances + 9 * n;
      const float* G = vc + 9 * n;
      float v_mean[3];  // of the posed mean, the direction's share included (R is held fixed)
      for (int r = 0; r < 3; ++r)
        v_mean[r] = vm[3 * n + r] + s.R[3 * r] * vd[3 * n] + s.R[3 * r + 1] * vd[3 * n + 1] + s.R[3 * r + 2] * vd[3 * n + 2];
      // cov' = L Sigma L^T: v_L = G L Sigma^T + G^T L Sigma; v_Sigma = L^T G L
      float L[9] = {s.A[0], s.A[1], s.A[2], s.A[4], s.A[5], s.A[6], s.A[8], s.A[9], s.A[10]};
      float LS[9], LSt[9], GL[9];
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) {
          LS[3 * r + c] = L[3 * r] * sigma[c] + L[3 * r + 1] * sigma[3 + c] + L[3 * r + 2] * sigma[6 + c];
          LSt[3 * r + c] = L[3 * r] * sigma[3 * c] + L[3 * r + 1] * sigma[3 * c + 1] + L[3 * r + 2] * sigma[3 * c + 2];
          GL[3 * r + c] = G[3 * r] * L[c] + G[3 * r + 1] * L[3 + c] + G[3 * r + 2] * L[6 + c];
        }
      float vA[12];  // v of A = [L | t]
      for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 3; ++c) {
          float sum = v_mean[r] * m[c];
          for (int k = 0; k < 3; ++k) sum += G[3 * r + k] * LSt[3 * k + c] + G[3 * k + r] * LS[3 * k + c];
          vA[4 * r + c] = sum;
        }
        vA[4 * r + 3] = v_mean[r];
      }
      for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 3; ++c) {
          gc[9 * n + 3 * r + c] = L[r] * GL[c] + L[3 + r] * GL[3 + c] + L[6 + r] * GL[6 + c];
        }
        gm[3 * n + r] = L[r] * v_mean[0] + L[3 + r] * v_mean[1] + L[6 + r] * v_mean[2];
      }
      // A = B o Dinv (A_L = B_L Dinv_L, A_t = B_L Dinv_t + B_t): v_B_L = v_A_L Dinv_L^T + v_A_t Dinv_t^T,
      // v_B_t = v_A_t, v_Dinv_L = B_L^T v_A_L, v_Dinv_t = B_L^T v_A_t
      float vB[12], vDinv[12];
      for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 3; ++c) {
          vB[4 * r + c] = vA[4 * r] * s.Dinv[4 * c] + vA[4 * r + 1] * s.Dinv[4 * c + 1] + vA[4 * r + 2] * s.Dinv[4 * c + 2] +
                          vA[4 * r + 3] * s.Dinv[4 * c + 3];
          vDinv[4 * r + c] = s.B[r] * vA[c] + s.B[4 + r] * vA[4 + c] + s.B[8 + r] * vA[8 + c];
        }
        vB[4 * r + 3] = vA[4 * r + 3];
        vDinv[4 * r + 3] = s.B[r] * vA[3] + s.B[4 + r] * vA[7] + s.B[8 + r] * vA[11];
      }
      // Dinv = [Li | -Li t] with Li = D_L^-1: v_Li = vDinv_L - vDinv_t t^T, v_t = -Li^T vDinv_t,
      // v_D_L = -Li^T v_Li Li^T
      const float t[3] = {s.D[3], s.D[7], s.D[11]};
      float vLi[9], Li[9] = {s.Dinv[0], s.Dinv[1], s.Dinv[2], s.Dinv[4], s.Dinv[5], s.Dinv[6], s.Dinv[8], s.Dinv[9], s.Dinv[10]};
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) vLi[3 * r + c] = vDinv[4 * r + c] - vDinv[4 * r + 3] * t[c];
      float vD[12], tmp[9];
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) tmp[3 * r + c] = vLi[3 * r] * Li[3 * c] + vLi[3 * r + 1] * Li[3 * c + 1] + vLi[3 * r + 2] * Li[3 * c + 2];
      for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 3; ++c) vD[4 * r + c] = -(Li[r] * tmp[c] + Li[3 + r] * tmp[3 + c] + Li[6 + r] * tmp[6 + c]);
        vD[4 * r + 3] = -(Li[r] * vDinv[3] + Li[3 + r] * vDinv[7] + Li[6 + r] * vDinv[11]);
      }
      // the blends: v_P_j += w_j v_B; v_w_j = <P_j, v_B> + <C_j, v_D>; then the weights' gradient to the mean
      for (int64_t j = 0; j < J; ++j) {
        if (s.w[j] == 0.0f && dw[3 * j] == 0.0f && dw[3 * j + 1] == 0.0f && dw[3 * j + 2] == 0.0f) continue;
        float v_w = 0.0f;
        for (int k = 0; k < 12; ++k) {
          gp[16 * j + k] += s.w[j] * vB[k];
          v_w += in.posed[16 * j + k] * vB[k] + in.canonical[16 * j + k] * vD[k];
        }
        for (int a = 0; a < 3; ++a) gm[3 * n + a] += v_w * dw[3 * j + a];
      }
    }
  }
  return {g_means, g_cov, partial.sum(0)};
}

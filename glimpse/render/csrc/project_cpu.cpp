// EWA projection of 3D Gaussians, forward and hand-written backward, on the CPU.
// The maths and conventions are those of glimpse/render/projection.py (the reference,
// differentiated by autograd), which the tests compare this against.
#include <torch/extension.h>
#include <ATen/Parallel.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "raster_rules.h"

namespace {

using glimpse_raster::kAlphaMin;

constexpr float kLowPass = 0.3f;
constexpr float kDetFloor = 1e-12f;
constexpr float kFovMargin = 0.3f;
constexpr float kRadiusSigmas = 3.0f;       // projection.py RADIUS_SIGMAS
constexpr float kExtentSafety = 1e-3f;      // projection.py EXTENT_SAFETY
constexpr int64_t kGrain = 2048;

struct CameraParams {
  float fx, fy, cx, cy, R[9], t[3];
  float lo_x, hi_x, lo_y, hi_y;  // clamp range of x/z and y/z for the Jacobian
  float near, far;
};

CameraParams camera_params(const torch::Tensor& K, const torch::Tensor& R, const torch::Tensor& t, int64_t width,
                           int64_t height, double near, double far) {
  auto k = K.to(torch::kFloat64).contiguous(), r = R.to(torch::kFloat64).contiguous(),
       tt = t.to(torch::kFloat64).contiguous();
  const double* kp = k.data_ptr<double>();
  CameraParams c{};
  c.fx = kp[0];
  c.fy = kp[4];
  c.cx = kp[2];
  c.cy = kp[5];
  for (int i = 0; i < 9; ++i) c.R[i] = r.data_ptr<double>()[i];
  for (int i = 0; i < 3; ++i) c.t[i] = tt.data_ptr<double>()[i];
  const double mx = kFovMargin * width / kp[0], my = kFovMargin * height / kp[4];
  c.lo_x = -kp[2] / kp[0] - mx;
  c.hi_x = (width - kp[2]) / kp[0] + mx;
  c.lo_y = -kp[5] / kp[4] - my;
  c.hi_y = (height - kp[5]) / kp[4] + my;
  c.near = near;
  c.far = far;
  return c;
}

// M = J R (2x3) for a camera-frame point (x, y, z); also returns the clamped tx, ty and whether each clamped.
struct Jacobian {
  float M[6], J00, J02, J11, J12, tx, ty;
  bool clamp_x, clamp_y;
};

inline Jacobian jacobian(const CameraParams& c, float x, float y, float z) {
  Jacobian j;
  const float rx = x / z, ry = y / z;
  const float cxz = std::min(c.hi_x, std::max(c.lo_x, rx)), cyz = std::min(c.hi_y, std::max(c.lo_y, ry));
  j.clamp_x = cxz != rx;
  j.clamp_y = cyz != ry;
  j.tx = z * cxz;
  j.ty = z * cyz;
  j.J00 = c.fx / z;
  j.J02 = -c.fx * j.tx / (z * z);
  j.J11 = c.fy / z;
  j.J12 = -c.fy * j.ty / (z * z);
  for (int k = 0; k < 3; ++k) {
    j.M[k] = j.J00 * c.R[k] + j.J02 * c.R[6 + k];
    j.M[3 + k] = j.J11 * c.R[3 + k] + j.J12 * c.R[6 + k];
  }
  return j;
}

// The undilated 2D covariance [[a0, b0], [b0, c0]] = M Σ Mᵀ of a 3x3 covariance Σ (row-major);
// also leaves M Σ (2x3) in MS for the backward.
struct Cov2d {
  float a0, b0, c0;
};

inline Cov2d projected_covariance(const Jacobian& j, const float* S, float* MS) {
  for (int r = 0; r < 2; ++r)
    for (int k = 0; k < 3; ++k) MS[3 * r + k] = j.M[3 * r] * S[k] + j.M[3 * r + 1] * S[3 + k] + j.M[3 * r + 2] * S[6 + k];
  return {MS[0] * j.M[0] + MS[1] * j.M[1] + MS[2] * j.M[2], MS[0] * j.M[3] + MS[1] * j.M[4] + MS[2] * j.M[5],
          MS[3] * j.M[3] + MS[4] * j.M[4] + MS[5] * j.M[5]};
}

// One Gaussian in front of the camera: what forward and backward both derive from its camera-frame
// point p and 3x3 covariance S.
struct Footprint {
  Jacobian j;
  float MS[6];              // M Σ
  float a0, b0, c0;         // undilated 2D covariance
  float a, cc, det;         // dilated diagonal and determinant
  float z;                  // depth used in the projection (1 when out of the depth range)
  bool in_depth, valid;
};

inline Footprint footprint(const CameraParams& c, const float* p, const float* S) {
  Footprint f;
  f.in_depth = p[2] > c.near && p[2] < c.far;
  f.z = f.in_depth ? p[2] : 1.0f;
  f.j = jacobian(c, p[0], p[1], f.z);
  const Cov2d cov = projected_covariance(f.j, S, f.MS);
  f.a0 = cov.a0;
  f.b0 = cov.b0;
  f.c0 = cov.c0;
  f.a = f.a0 + kLowPass;
  f.cc = f.c0 + kLowPass;
  f.det = f.a * f.cc - f.b0 * f.b0;
  f.valid = f.in_depth && f.det > 0.0f;
  return f;
}

// Where a Gaussian is drawn (projection.py _finish_projection's rules): the half-extents of the box outside which
// alpha = o exp(-s) < 1/255, its 3-sigma screen radius, and whether it is drawn at all (valid, alpha can reach
// 1/255, the box meets the image). Zero extents and radius when not drawn.
struct ScreenBox {
  float extent_x, extent_y;
  int radius;
  bool visible;
};

inline ScreenBox screen_box(float mx, float my, float a, float b, float c, float opacity, bool valid, int64_t width,
                            int64_t height) {
  const float level = std::log(std::max(opacity / kAlphaMin, 1.0f));
  // a, c > 0 for every positive-semidefinite covariance; where not, the reference's extents are NaN: not drawn
  if (!valid || !(level > 0.0f) || !(a > 0.0f) || !(c > 0.0f)) return {0.0f, 0.0f, 0, false};
  const float ex = std::sqrt(2.0f * level * a) * (1.0f + kExtentSafety);
  const float ey = std::sqrt(2.0f * level * c) * (1.0f + kExtentSafety);
  const bool on_image = mx + ex >= 0.0f && mx - ex <= static_cast<float>(width - 1) && my + ey >= 0.0f &&
                        my - ey <= static_cast<float>(height - 1);
  if (!on_image) return {0.0f, 0.0f, 0, false};
  const float largest = 0.5f * (a + c) + std::sqrt(std::max(0.25f * ((a - c) * (a - c)) + b * b, 0.0f));
  return {ex, ey, static_cast<int>(std::ceil(kRadiusSigmas * std::sqrt(largest))), true};
}

}  // namespace

// means [N,3], covariances [N,3,3], opacities [N] (float32, contiguous) ->
// means2d [N,2], conics [N,3], depths [N], opacities_out [N], camera-frame points [N,3] (for the backward),
// binning extents [N,2] (pixels), radii [N] int32 and a visibility mask [N] (ScreenBox).
std::vector<torch::Tensor> project_forward(torch::Tensor means, torch::Tensor covariances, torch::Tensor opacities,
                                           torch::Tensor K, torch::Tensor R, torch::Tensor t, int64_t width,
                                           int64_t height, double near, double far, bool antialiased) {
  TORCH_CHECK(means.dtype() == torch::kFloat32 && covariances.dtype() == torch::kFloat32 &&
                  opacities.dtype() == torch::kFloat32 && means.is_contiguous() && covariances.is_contiguous() &&
                  opacities.is_contiguous(),
              "project_cpu: contiguous float32 inputs expected");
  const CameraParams c = camera_params(K, R, t, width, height, near, far);
  const int64_t N = means.size(0);
  auto opts = means.options();
  // every output is written for every Gaussian below: no fill needed
  auto means2d = torch::empty({N, 2}, opts), conics = torch::empty({N, 3}, opts), depths = torch::empty({N}, opts);
  auto opac_out = torch::empty({N}, opts), cam = torch::empty({N, 3}, opts), extents = torch::empty({N, 2}, opts);
  auto radii = torch::empty({N}, opts.dtype(torch::kInt32));
  auto visible = torch::empty({N}, opts.dtype(torch::kBool));
  float* ext = extents.data_ptr<float>();
  int* rad = radii.data_ptr<int>();
  bool* vis = visible.data_ptr<bool>();
  const float *m = means.data_ptr<float>(), *S = covariances.data_ptr<float>(), *o = opacities.data_ptr<float>();
  float *m2 = means2d.data_ptr<float>(), *cn = conics.data_ptr<float>(), *d = depths.data_ptr<float>(),
        *oo = opac_out.data_ptr<float>(), *pc = cam.data_ptr<float>();
  at::parallel_for(0, N, kGrain, [&](int64_t begin, int64_t end) {
    for (int64_t i = begin; i < end; ++i) {
      float p[3];
      for (int r = 0; r < 3; ++r)
        p[r] = c.R[3 * r] * m[3 * i] + c.R[3 * r + 1] * m[3 * i + 1] + c.R[3 * r + 2] * m[3 * i + 2] + c.t[r];
      std::copy(p, p + 3, pc + 3 * i);
      d[i] = p[2];
      const Footprint fp = footprint(c, p, S + 9 * i);
      const float a0 = fp.a0, b0 = fp.b0, c0 = fp.c0, a = fp.a, cc = fp.cc, det = fp.det, z = fp.z;
      const bool valid = fp.valid;
      const float det_safe = valid ? det : 1.0f;
      cn[3 * i] = cc / det_safe;
      cn[3 * i + 1] = -b0 / det_safe;
      cn[3 * i + 2] = a / det_safe;
      m2[2 * i] = c.fx * p[0] / z + c.cx;
      m2[2 * i + 1] = c.fy * p[1] / z + c.cy;
      float opacity = o[i];
      if (antialiased) {
        const float ratio = (a0 * c0 - b0 * b0) / std::max(det, kDetFloor);
        opacity *= std::sqrt(std::max(ratio, kDetFloor));
      }
      oo[i] = opacity;
      const ScreenBox box = screen_box(m2[2 * i], m2[2 * i + 1], a, b0, cc, opacity, valid, width, height);
      ext[2 * i] = box.extent_x;
      ext[2 * i + 1] = box.extent_y;
      rad[i] = box.radius;
      vis[i] = box.visible;
    }
  });
  return {means2d, conics, depths, opac_out, cam, extents, radii, visible};
}

// Gradients of means [N,3], covariances [N,3,3] and opacities [N] from those of
// means2d [N,2], conics [N,3], depths [N] and opacities_out [N].
std::vector<torch::Tensor> project_backward(torch::Tensor means, torch::Tensor covariances, torch::Tensor opacities,
                                            torch::Tensor cam, torch::Tensor K, torch::Tensor R, torch::Tensor t,
                                            int64_t width, int64_t height, double near, double far, bool antialiased,
                                            torch::Tensor v_means2d, torch::Tensor v_conics, torch::Tensor v_depths,
                                            torch::Tensor v_opac_out) {
  const CameraParams c = camera_params(K, R, t, width, height, near, far);
  const int64_t N = means.size(0);
  v_means2d = v_means2d.contiguous();
  v_conics = v_conics.contiguous();
  v_depths = v_depths.contiguous();
  v_opac_out = v_opac_out.contiguous();
  // every gradient is written for every Gaussian below: no fill needed
  auto v_means = torch::empty({N, 3}, means.options()), v_cov = torch::empty({N, 3, 3}, means.options()),
       v_opac = torch::empty({N}, means.options());
  const float *S = covariances.data_ptr<float>(), *o = opacities.data_ptr<float>(), *pc = cam.data_ptr<float>();
  const float *gm2 = v_means2d.data_ptr<float>(), *gcn = v_conics.data_ptr<float>(),
              *gd = v_depths.data_ptr<float>(), *go = v_opac_out.data_ptr<float>();
  float *vm = v_means.data_ptr<float>(), *vS = v_cov.data_ptr<float>(), *vo = v_opac.data_ptr<float>();
  at::parallel_for(0, N, kGrain, [&](int64_t begin, int64_t end) {
    for (int64_t i = begin; i < end; ++i) {
      const float* p = pc + 3 * i;
      const Footprint fp = footprint(c, p, S + 9 * i);
      const Jacobian& j = fp.j;
      const float* MS = fp.MS;
      const float a0 = fp.a0, b0 = fp.b0, c0 = fp.c0, a = fp.a, cc = fp.cc, det = fp.det, z = fp.z;
      const bool in_depth = fp.in_depth, valid = fp.valid;
      // opacity
      float v_a0 = 0.0f, v_b0 = 0.0f, v_c0 = 0.0f, v_det = 0.0f;
      if (antialiased) {
        const float det_c = std::max(det, kDetFloor);
        const float ratio = (a0 * c0 - b0 * b0) / det_c;
        const float comp = std::sqrt(std::max(ratio, kDetFloor));
        vo[i] = go[i] * comp;
        if (ratio > kDetFloor) {
          const float v_ratio = go[i] * o[i] * 0.5f / comp;
          v_a0 += v_ratio * c0 / det_c;
          v_c0 += v_ratio * a0 / det_c;
          v_b0 += -v_ratio * 2.0f * b0 / det_c;
          if (det > kDetFloor) v_det += -v_ratio * ratio / det_c;
        }
      } else {
        vo[i] = go[i];
      }
      // conics = (c, -b0, a) / det
      if (valid) {
        const float inv = 1.0f / det;
        const float A = cc * inv, B = -b0 * inv, C = a * inv;
        const float vA = gcn[3 * i], vB = gcn[3 * i + 1], vC = gcn[3 * i + 2];
        v_det += -(vA * A + vB * B + vC * C) * inv;
        v_c0 += vA * inv;
        v_b0 += -vB * inv;
        v_a0 += vC * inv;
      }
      // det = (a0 + l)(c0 + l) - b0^2
      v_a0 += v_det * cc;
      v_c0 += v_det * a;
      v_b0 += -2.0f * v_det * b0;
      // Σ2 = M Σ Mᵀ with V = [[v_a0, v_b0/2], [v_b0/2, v_c0]]: v_M = 2 V M Σ, v_Σ = Mᵀ V M
      const float V00 = v_a0, V01 = 0.5f * v_b0, V11 = v_c0;
      float vM[6];
      for (int k = 0; k < 3; ++k) {
        vM[k] = 2.0f * (V00 * MS[k] + V01 * MS[3 + k]);
        vM[3 + k] = 2.0f * (V01 * MS[k] + V11 * MS[3 + k]);
      }
      float* vSi = vS + 9 * i;
      for (int r = 0; r < 3; ++r)
        for (int k = 0; k < 3; ++k)
          vSi[3 * r + k] = j.M[r] * (V00 * j.M[k] + V01 * j.M[3 + k]) + j.M[3 + r] * (V01 * j.M[k] + V11 * j.M[3 + k]);
      // M = J R: v_J = v_M Rᵀ (only J00, J02, J11, J12 are variables)
      const float vJ00 = vM[0] * c.R[0] + vM[1] * c.R[1] + vM[2] * c.R[2];
      const float vJ02 = vM[0] * c.R[6] + vM[1] * c.R[7] + vM[2] * c.R[8];
      const float vJ11 = vM[3] * c.R[3] + vM[4] * c.R[4] + vM[5] * c.R[5];
      const float vJ12 = vM[3] * c.R[6] + vM[4] * c.R[7] + vM[5] * c.R[8];
      float vp[3] = {0.0f, 0.0f, 0.0f};
      if (in_depth) {
        const float z2 = z * z, z3 = z2 * z;
        vp[2] += -c.fx / z2 * vJ00 + 2.0f * c.fx * j.tx / z3 * vJ02 - c.fy / z2 * vJ11 + 2.0f * c.fy * j.ty / z3 * vJ12;
        const float v_tx = -c.fx / z2 * vJ02, v_ty = -c.fy / z2 * vJ12;
        if (j.clamp_x) vp[2] += v_tx * j.tx / z; else vp[0] += v_tx;
        if (j.clamp_y) vp[2] += v_ty * j.ty / z; else vp[1] += v_ty;
        // means2d = (fx x / z + cx, fy y / z + cy)
        vp[0] += c.fx / z * gm2[2 * i];
        vp[1] += c.fy / z * gm2[2 * i + 1];
        vp[2] += -c.fx * p[0] / z2 * gm2[2 * i] - c.fy * p[1] / z2 * gm2[2 * i + 1];
      }
      vp[2] += gd[i];
      for (int k = 0; k < 3; ++k) vm[3 * i + k] = c.R[k] * vp[0] + c.R[3 + k] * vp[1] + c.R[6 + k] * vp[2];
    }
  });
  return {v_means, v_cov, v_opac};
}

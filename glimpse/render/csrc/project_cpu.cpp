// EWA projection of 3D Gaussians, forward and hand-written backward, on the CPU.
// The maths and conventions are those of glimpse/render/projection.py (the reference,
// differentiated by autograd), which the tests compare this against. Eight Gaussians are computed
// at a time, one per lane of a vector (lanes.h): their records are moved into lanes and back.
#include <torch/extension.h>
#include <ATen/Parallel.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "lanes.h"
#include "raster_rules.h"

namespace {

using glimpse_raster::kAlphaMin;
using namespace glimpse_lanes;

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

// M = J R (2x3) for camera-frame points (x, y, z); also the clamped tx, ty and where each clamped.
struct Jacobian {
  Floats M[6], J00, J02, J11, J12, tx, ty;
  Ints clamp_x, clamp_y;
};

inline Jacobian jacobian(const CameraParams& c, Floats x, Floats y, Floats z) {
  Jacobian j;
  const Floats rx = x / z, ry = y / z;
  const Floats cxz = min(Floats{} + c.hi_x, max(Floats{} + c.lo_x, rx)),
               cyz = min(Floats{} + c.hi_y, max(Floats{} + c.lo_y, ry));
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
  Floats a0, b0, c0;
};

inline Cov2d projected_covariance(const Jacobian& j, const Floats* S, Floats* MS) {
  for (int r = 0; r < 2; ++r)
    for (int k = 0; k < 3; ++k) MS[3 * r + k] = j.M[3 * r] * S[k] + j.M[3 * r + 1] * S[3 + k] + j.M[3 * r + 2] * S[6 + k];
  return {MS[0] * j.M[0] + MS[1] * j.M[1] + MS[2] * j.M[2], MS[0] * j.M[3] + MS[1] * j.M[4] + MS[2] * j.M[5],
          MS[3] * j.M[3] + MS[4] * j.M[4] + MS[5] * j.M[5]};
}

// Gaussians in front of the camera: what forward and backward both derive from their camera-frame points p and
// 3x3 covariances S.
struct Footprint {
  Jacobian j;
  Floats MS[6];              // M Σ
  Floats a0, b0, c0;         // undilated 2D covariance
  Floats a, cc, det;         // dilated diagonal and determinant
  Floats z;                  // depth used in the projection (1 when out of the depth range)
  Ints in_depth, valid;
};

inline Footprint footprint(const CameraParams& c, const Floats* p, const Floats* S) {
  Footprint f;
  f.in_depth = (p[2] > c.near) & (p[2] < c.far);
  f.z = f.in_depth ? p[2] : 1.0f;
  f.j = jacobian(c, p[0], p[1], f.z);
  const Cov2d cov = projected_covariance(f.j, S, f.MS);
  f.a0 = cov.a0;
  f.b0 = cov.b0;
  f.c0 = cov.c0;
  f.a = f.a0 + kLowPass;
  f.cc = f.c0 + kLowPass;
  f.det = f.a * f.cc - f.b0 * f.b0;
  f.valid = f.in_depth & (f.det > 0.0f);
  return f;
}

// Where Gaussians are drawn (projection.py _finish_projection's rules): the half-extents of the box outside which
// alpha = o exp(-s) < 1/255, the 3-sigma screen radius, and whether each is drawn at all (valid, alpha can reach
// 1/255, the box meets the image). Zero extents and radius where not drawn.
struct ScreenBox {
  Floats extent_x, extent_y;
  Ints radius, visible;
};

inline ScreenBox screen_box(Floats mx, Floats my, Floats a, Floats b, Floats c, Floats opacity, Ints valid,
                            int64_t width, int64_t height) {
  const Floats level = log_lanes(max(opacity / kAlphaMin, Floats{} + 1.0f));
  // a, c > 0 for every positive-semidefinite covariance; where not, the reference's extents are NaN: not drawn
  const Ints drawable = valid & (level > 0.0f) & (a > 0.0f) & (c > 0.0f);
  const Floats ex = sqrt_lanes(2.0f * level * a) * (1.0f + kExtentSafety);
  const Floats ey = sqrt_lanes(2.0f * level * c) * (1.0f + kExtentSafety);
  const Ints on_image = (mx + ex >= 0.0f) & (mx - ex <= static_cast<float>(width - 1)) & (my + ey >= 0.0f) &
                        (my - ey <= static_cast<float>(height - 1));
  const Ints visible = drawable & on_image;
  const Floats largest = 0.5f * (a + c) + sqrt_lanes(max(0.25f * ((a - c) * (a - c)) + b * b, Floats{}));
  const Floats radius = ceil_lanes(visible ? kRadiusSigmas * sqrt_lanes(largest) : 0.0f);
  return {visible ? ex : 0.0f, visible ? ey : 0.0f, __builtin_convertvector(radius, Ints), visible};
}

// Camera-frame points R m + t of world points m [3].
inline void camera_points(const CameraParams& c, const Floats* m, Floats* p) {
  for (int r = 0; r < 3; ++r) p[r] = c.R[3 * r] * m[0] + c.R[3 * r + 1] * m[1] + c.R[3 * r + 2] * m[2] + c.t[r];
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
    for (int64_t i = begin; i < end; i += kLanes) {  // Gaussians i .. i + count - 1, one per lane
      const int count = static_cast<int>(std::min<int64_t>(kLanes, end - i));
      Floats mean[3], cov[9], p[3];
      gather(m, i, count, mean);
      gather(S, i, count, cov);
      camera_points(c, mean, p);
      scatter(p, pc, i, count);
      scatter(p[2], d, i, count);
      const Footprint fp = footprint(c, p, cov);
      const Floats det_safe = fp.valid ? fp.det : 1.0f;
      scatter({fp.cc / det_safe, -fp.b0 / det_safe, fp.a / det_safe}, cn, i, count);
      const Floats mx = c.fx * p[0] / fp.z + c.cx, my = c.fy * p[1] / fp.z + c.cy;
      scatter({mx, my}, m2, i, count);
      Floats opacity = gather(o, i, count);
      if (antialiased) {
        const Floats ratio = (fp.a0 * fp.c0 - fp.b0 * fp.b0) / max(fp.det, Floats{} + kDetFloor);
        opacity *= sqrt_lanes(max(ratio, Floats{} + kDetFloor));
      }
      scatter(opacity, oo, i, count);
      const ScreenBox box = screen_box(mx, my, fp.a, fp.b0, fp.cc, opacity, fp.valid, width, height);
      scatter({box.extent_x, box.extent_y}, ext, i, count);
      const int drawn = lane_bits(box.visible);
      for (int l = 0; l < count; ++l) {
        rad[i + l] = box.radius[l];
        vis[i + l] = (drawn >> l) & 1;
      }
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
    for (int64_t i = begin; i < end; i += kLanes) {  // Gaussians i .. i + count - 1, one per lane
      const int count = static_cast<int>(std::min<int64_t>(kLanes, end - i));
      Floats p[3], cov[9], g_mean2d[2], g_conic[3];
      gather(pc, i, count, p);
      gather(S, i, count, cov);
      gather(gm2, i, count, g_mean2d);
      gather(gcn, i, count, g_conic);
      const Floats g_opacity = gather(go, i, count);
      const Footprint fp = footprint(c, p, cov);
      const Jacobian& j = fp.j;
      const Floats* MS = fp.MS;
      const Floats a0 = fp.a0, b0 = fp.b0, c0 = fp.c0, a = fp.a, cc = fp.cc, det = fp.det, z = fp.z;
      // opacity
      Floats v_a0{}, v_b0{}, v_c0{}, v_det{};
      if (antialiased) {
        const Floats opacity = gather(o, i, count);
        const Floats det_c = max(det, Floats{} + kDetFloor);
        const Floats ratio = (a0 * c0 - b0 * b0) / det_c;
        const Floats comp = sqrt_lanes(max(ratio, Floats{} + kDetFloor));
        scatter(g_opacity * comp, vo, i, count);
        const Ints compensated = ratio > kDetFloor;
        const Floats v_ratio = g_opacity * opacity * 0.5f / comp;
        v_a0 += compensated ? v_ratio * c0 / det_c : 0.0f;
        v_c0 += compensated ? v_ratio * a0 / det_c : 0.0f;
        v_b0 += compensated ? -v_ratio * 2.0f * b0 / det_c : 0.0f;
        v_det += compensated & (det > kDetFloor) ? -v_ratio * ratio / det_c : 0.0f;
      } else {
        scatter(g_opacity, vo, i, count);
      }
      // conics = (c, -b0, a) / det
      const Floats inv = 1.0f / (fp.valid ? det : 1.0f);
      const Floats A = cc * inv, B = -b0 * inv, C = a * inv;
      const Floats vA = g_conic[0], vB = g_conic[1], vC = g_conic[2];
      v_det += fp.valid ? -(vA * A + vB * B + vC * C) * inv : 0.0f;
      v_c0 += fp.valid ? vA * inv : 0.0f;
      v_b0 += fp.valid ? -vB * inv : 0.0f;
      v_a0 += fp.valid ? vC * inv : 0.0f;
      // det = (a0 + l)(c0 + l) - b0^2
      v_a0 += v_det * cc;
      v_c0 += v_det * a;
      v_b0 += -2.0f * v_det * b0;
      // Σ2 = M Σ Mᵀ with V = [[v_a0, v_b0/2], [v_b0/2, v_c0]]: v_M = 2 V M Σ, v_Σ = Mᵀ V M
      const Floats V00 = v_a0, V01 = 0.5f * v_b0, V11 = v_c0;
      Floats vM[6], v_cov[9];
      for (int k = 0; k < 3; ++k) {
        vM[k] = 2.0f * (V00 * MS[k] + V01 * MS[3 + k]);
        vM[3 + k] = 2.0f * (V01 * MS[k] + V11 * MS[3 + k]);
      }
      for (int r = 0; r < 3; ++r)
        for (int k = 0; k < 3; ++k)
          v_cov[3 * r + k] =
              j.M[r] * (V00 * j.M[k] + V01 * j.M[3 + k]) + j.M[3 + r] * (V01 * j.M[k] + V11 * j.M[3 + k]);
      scatter(v_cov, vS, i, count);
      // M = J R: v_J = v_M Rᵀ (only J00, J02, J11, J12 are variables)
      const Floats vJ00 = vM[0] * c.R[0] + vM[1] * c.R[1] + vM[2] * c.R[2];
      const Floats vJ02 = vM[0] * c.R[6] + vM[1] * c.R[7] + vM[2] * c.R[8];
      const Floats vJ11 = vM[3] * c.R[3] + vM[4] * c.R[4] + vM[5] * c.R[5];
      const Floats vJ12 = vM[3] * c.R[6] + vM[4] * c.R[7] + vM[5] * c.R[8];
      // in the depth range (elsewhere the projection is constant)
      const Floats z2 = z * z, z3 = z2 * z;
      Floats vz = -c.fx / z2 * vJ00 + 2.0f * c.fx * j.tx / z3 * vJ02 - c.fy / z2 * vJ11 + 2.0f * c.fy * j.ty / z3 * vJ12;
      const Floats v_tx = -c.fx / z2 * vJ02, v_ty = -c.fy / z2 * vJ12;
      vz += j.clamp_x ? v_tx * j.tx / z : 0.0f;
      vz += j.clamp_y ? v_ty * j.ty / z : 0.0f;
      Floats vx = j.clamp_x ? 0.0f : v_tx, vy = j.clamp_y ? 0.0f : v_ty;
      // means2d = (fx x / z + cx, fy y / z + cy)
      vx += c.fx / z * g_mean2d[0];
      vy += c.fy / z * g_mean2d[1];
      vz += -c.fx * p[0] / z2 * g_mean2d[0] - c.fy * p[1] / z2 * g_mean2d[1];
      const Floats vp[3] = {fp.in_depth ? vx : 0.0f, fp.in_depth ? vy : 0.0f,
                            (fp.in_depth ? vz : 0.0f) + gather(gd, i, count)};
      Floats v_mean[3];
      for (int k = 0; k < 3; ++k) v_mean[k] = c.R[k] * vp[0] + c.R[3 + k] * vp[1] + c.R[6 + k] * vp[2];
      scatter(v_mean, vm, i, count);
    }
  });
  return {v_means, v_cov, v_opac};
}

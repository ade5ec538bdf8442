// Which triangle is nearest at each pixel centre, and at what depth: the z-buffer of glimpse/render/mesh_raster.py,
// whose numpy version is the reference. Each triangle in front of the camera is projected, and every pixel centre of
// its box tested against its three edges; the nearest surface is kept, ties to the lower face index. The arithmetic
// is numpy's, in float64 and in the same order, without fused multiply-adds and with IEEE infinities and NaNs (this
// file opts out of the build's -ffinite-math-only), so the result equals the reference to the bit, broken input
// included (tests/test_mesh_raster.py).
#include <torch/extension.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

// numpy rounds each product and each sum, and compares NaNs as IEEE says: so must this
#pragma GCC push_options
#pragma GCC optimize("fp-contract=off", "no-finite-math-only")
#ifdef __clang__
#pragma clang fp contract(off)
#endif

namespace {

constexpr double kMinArea = 1e-12;  // twice the projected area (pixels^2) below which a triangle covers nothing

// twice the signed area of (p, q, pixel): numpy's (q_x - p_x) (v - p_y) - (q_y - p_y) (u - p_x)
inline double edge(double px, double py, double qx, double qy, double u, double v) {
  return (qx - px) * (v - py) - (qy - py) * (u - px);
}

}  // namespace

// points [V, 3] float64, camera coordinates; faces [F, 3] int64; fx, fy, cx, cy: the pinhole's K; near: the camera z
// at or below which a corner drops its triangle. Returns depth [H, W] float64 (inf where no triangle) and face [H, W]
// int64, the index into faces (-1 where none). A triangle with a coordinate that is not finite covers nothing, as
// in numpy, where its edge tests fail.
std::vector<torch::Tensor> mesh_raster_forward(torch::Tensor points, torch::Tensor faces, double fx, double fy,
                                               double cx, double cy, double near, int64_t width, int64_t height) {
  TORCH_CHECK(points.dtype() == torch::kFloat64 && faces.dtype() == torch::kInt64 && points.dim() == 2 &&
                  points.size(1) == 3 && faces.dim() == 2 && faces.size(1) == 3,
              "mesh_raster: points [V, 3] float64 and faces [F, 3] int64");
  points = points.contiguous();
  faces = faces.contiguous();
  const int64_t F = faces.size(0), V = points.size(0);
  auto depth = torch::full({height, width}, std::numeric_limits<double>::infinity(), points.options());
  auto face = torch::full({height, width}, -1, faces.options());
  double* depth_ptr = depth.data_ptr<double>();
  int64_t* face_ptr = face.data_ptr<int64_t>();
  const double* xyz = points.data_ptr<double>();
  const int64_t* corner_ids = faces.data_ptr<int64_t>();
  for (int64_t f = 0; f < F; ++f) {
    double u[3], v[3], inv_z[3];
    bool in_front = true;
    for (int k = 0; k < 3; ++k) {
      const int64_t i = corner_ids[f * 3 + k];
      TORCH_CHECK(i >= 0 && i < V, "mesh_raster: a face names vertex ", i, " of ", V);
      const double* p = xyz + i * 3;
      in_front = in_front && p[2] > near;
      u[k] = p[0] / p[2] * fx + cx;  // numpy: corners[..., :2] / corners[..., 2:3] * [fx, fy] + [cx, cy]
      v[k] = p[1] / p[2] * fy + cy;
      inv_z[k] = 1.0 / p[2];
    }
    if (!in_front) continue;
    bool finite = true;
    for (int k = 0; k < 3; ++k) finite = finite && std::isfinite(u[k]) && std::isfinite(v[k]) && std::isfinite(inv_z[k]);
    if (!finite) continue;
    const double area = (u[1] - u[0]) * (v[2] - v[0]) - (v[1] - v[0]) * (u[2] - u[0]);
    const double size = std::fabs(area);
    if (!(size > kMinArea)) continue;
    const double sign = area < 0 ? -1.0 : 1.0;
    // the pixel centres of the triangle's box, clipped to the image in float64 (a box off the image, however far,
    // is empty before any conversion to an integer)
    const double u_lo = std::max(std::ceil(std::min({u[0], u[1], u[2]})), 0.0);
    const double v_lo = std::max(std::ceil(std::min({v[0], v[1], v[2]})), 0.0);
    const double u_hi = std::min(std::floor(std::max({u[0], u[1], u[2]})), static_cast<double>(width - 1));
    const double v_hi = std::min(std::floor(std::max({v[0], v[1], v[2]})), static_cast<double>(height - 1));
    if (!(u_lo <= u_hi && v_lo <= v_hi)) continue;
    const int64_t u_first = static_cast<int64_t>(u_lo), u_last = static_cast<int64_t>(u_hi);
    const int64_t v_first = static_cast<int64_t>(v_lo), v_last = static_cast<int64_t>(v_hi);
    for (int64_t y = v_first; y <= v_last; ++y) {
      for (int64_t x = u_first; x <= u_last; ++x) {
        const double X = static_cast<double>(x), Y = static_cast<double>(y);
        const double wa = sign * edge(u[1], v[1], u[2], v[2], X, Y), wb = sign * edge(u[2], v[2], u[0], v[0], X, Y),
                     wc = sign * edge(u[0], v[0], u[1], v[1], X, Y);
        if (!(wa >= 0.0 && wb >= 0.0 && wc >= 0.0)) continue;
        // numpy: (weights * inv_z).sum(1), the three products summed left to right
        const double d = 1.0 / (wa / size * inv_z[0] + wb / size * inv_z[1] + wc / size * inv_z[2]);
        const int64_t q = y * width + x;
        // faces come in ascending order: an equal depth keeps the lower index
        if (face_ptr[q] < 0 || d < depth_ptr[q]) {  // (a first cover counts even at infinite depth, as in numpy)
          depth_ptr[q] = d;
          face_ptr[q] = f;
        }
      }
    }
  }
  return {depth, face};
}

#pragma GCC pop_options

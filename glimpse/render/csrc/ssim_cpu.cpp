// The SSIM map of glimpse/metrics/image.py (scikit-image's definition) and its gradient with respect to the
// first image, fused for the training losses' D-SSIM on the CPU.
//
// Per channel of each image, the five moments x, y, x^2, y^2, xy are blurred by the separable Gaussian (taps
// given, radius r) with symmetric padding ("d c b a | a b c d"), rows first, then columns; the map is
//   S = (2 mx my + C1)(2 cxy + C2) / ((mx^2 + my^2 + C1)(vx + vy + C2)),
// vx = m(x^2) - mx^2, cxy = m(xy) - mx my. The backward takes dL/dS per pixel to three per-pixel maps, dL/dmx,
// dL/dm(x^2) and dL/dm(xy), blurs them by the blur's adjoint (columns' adjoint, then rows'), and combines
// them: dL/dx = G'(dL/dmx) + 2 x G'(dL/dm(x^2)) + y G'(dL/dm(xy)). PyTorch computes the same map with about
// fifty whole-image operations forward and backward (tests/test_ssim_cpu.py compares the two).
//
// Images are [B, H, W, C] float32, channel last; internally planes [B * C][H][W], so every blur's inner loop
// runs along contiguous memory.
#include <torch/extension.h>
#include <ATen/Parallel.h>

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <vector>

namespace {

inline int64_t reflect(int64_t j, int64_t n) { return j < 0 ? -j - 1 : (j >= n ? 2 * n - 1 - j : j); }

struct Taps {
  const float* w;  // [2 r + 1], symmetric
  int r;
};

// Eight floats as one vector (GCC's vector extensions: one AVX2 register where built with it).
typedef float Floats __attribute__((vector_size(8 * sizeof(float))));
constexpr int kLanes = 8;
inline Floats load(const float* p) {
  Floats v;
  std::memcpy(&v, p, sizeof v);
  return v;
}
inline void store(float* p, Floats v) { std::memcpy(p, &v, sizeof v); }

// dst[i] (+)= sum over k < count of weights[k] lines[k][i], i < n: each output summed in a register and stored
// once (a loop over k outside the loop over i loads and stores dst once per tap).
void weighted_lines(float* dst, const float* const* lines, const float* weights, int count, int64_t n,
                    bool accumulate) {
  int64_t i = 0;
  for (; i + kLanes <= n; i += kLanes) {
    Floats sum = accumulate ? load(dst + i) : Floats{};
    for (int k = 0; k < count; ++k) sum += weights[k] * load(lines[k] + i);
    store(dst + i, sum);
  }
  for (; i < n; ++i) {
    float sum = accumulate ? dst[i] : 0.0f;
    for (int k = 0; k < count; ++k) sum += weights[k] * lines[k][i];
    dst[i] = sum;
  }
}

constexpr int kMaxTaps = 64;  // rows or values one output sums, at most (the adjoint's border: 3 (2r + 1))

// Along each row of `rows` rows of n values: the r values at either end by edge(line, i), the interior i in
// [r, n - r) as sum_k w[k] line[i - r + interior_offset(k)] (every index inside the line).
template <typename Edge, typename Offset>
void filter_rows(const float* in, float* out, int64_t rows, int64_t n, Taps taps, Edge edge, Offset interior_offset) {
  const int r = taps.r;
  at::parallel_for(0, rows, 16, [&](int64_t begin, int64_t end) {
    const float* lines[kMaxTaps];
    for (int64_t row = begin; row < end; ++row) {
      const float* src = in + row * n;
      float* dst = out + row * n;
      for (int64_t i = 0; i < n; ++i)
        if (i < r || i >= n - r) dst[i] = edge(src, i);
      for (int k = 0; k <= 2 * r; ++k) lines[k] = src + interior_offset(k);
      weighted_lines(dst + r, lines, taps.w, 2 * r + 1, n - 2 * r, false);
    }
  });
}

// out[i] = sum_k w[k] in[reflect(i + k - r)] along each row of `rows` rows of n values.
void blur_rows(const float* in, float* out, int64_t rows, int64_t n, Taps taps) {
  const int r = taps.r;
  auto edge = [&](const float* line, int64_t i) {
    float sum = 0.0f;
    for (int k = 0; k <= 2 * r; ++k) sum += taps.w[k] * line[reflect(i + k - r, n)];
    return sum;
  };
  filter_rows(in, out, rows, n, taps, edge, [](int k) { return k; });
}

// Each row y of `planes` planes of `height` rows of n values: the sum of the rows and weights that
// rows(plane, y, lines, weights) lists (it returns how many).
template <typename Rows>
void filter_columns(const float* in, float* out, int64_t planes, int64_t height, int64_t n, Rows rows) {
  at::parallel_for(0, planes * height, 8, [&](int64_t begin, int64_t end) {
    const float* lines[kMaxTaps];
    float weights[kMaxTaps];
    for (int64_t index = begin; index < end; ++index) {
      const int count = rows(in + index / height * height * n, index % height, lines, weights);
      weighted_lines(out + index * n, lines, weights, count, n, false);
    }
  });
}

// out[y] = sum_k w[k] in[reflect(y + k - r)] for rows of width n in each of `planes` planes of `height` rows.
void blur_columns(const float* in, float* out, int64_t planes, int64_t height, int64_t n, Taps taps) {
  const int r = taps.r;
  filter_columns(in, out, planes, height, n, [&](const float* plane, int64_t y, const float** lines, float* weights) {
    for (int k = 0; k <= 2 * r; ++k) {
      lines[k] = plane + reflect(y + k - r, height) * n;
      weights[k] = taps.w[k];
    }
    return 2 * r + 1;
  });
}

// The adjoint of a 1-D blur with symmetric padding gathers, at position j of a line of n values, the zero-padded
// full correlation ext(m) = sum over k with 0 <= m - k < n of w[k] a[m - k] (padded position m - r) at its own
// padded position and at those that mirror onto it: m = j + r; m = r - 1 - j where j < r; m = r + 2n - 1 - j where
// j >= n - r.
template <typename Visit>
inline void mirrored_positions(int64_t j, int64_t n, int r, Visit visit) {
  visit(j + r);
  if (j < r) visit(r - 1 - j);
  if (j >= n - r) visit(r + 2 * n - 1 - j);
}

// The adjoint of blur_rows: the interior gathers only its own padded position, dst[i] = sum_k w[k] a[i + r - k].
void blur_rows_adjoint(const float* in, float* out, int64_t rows, int64_t n, Taps taps) {
  const int r = taps.r;
  auto edge = [&](const float* line, int64_t j) {
    float sum = 0.0f;
    mirrored_positions(j, n, r, [&](int64_t m) {
      for (int64_t k = std::max<int64_t>(0, m - n + 1); k <= std::min<int64_t>(2 * r, m); ++k)
        sum += taps.w[k] * line[m - k];
    });
    return sum;
  };
  filter_rows(in, out, rows, n, taps, edge, [r](int k) { return 2 * r - k; });
}

// The adjoint of blur_columns (up to three padded positions per row: at most 3 (2r + 1) rows).
void blur_columns_adjoint(const float* in, float* out, int64_t planes, int64_t height, int64_t n, Taps taps) {
  const int r = taps.r;
  filter_columns(in, out, planes, height, n, [&](const float* plane, int64_t y, const float** lines, float* weights) {
    int count = 0;
    mirrored_positions(y, height, r, [&](int64_t m) {
      for (int64_t k = std::max<int64_t>(0, m - height + 1); k <= std::min<int64_t>(2 * r, m); ++k) {
        lines[count] = plane + (m - k) * n;
        weights[count++] = taps.w[k];
      }
    });
    return count;
  });
}

Taps check_taps(const torch::Tensor& taps) {
  TORCH_CHECK(taps.dtype() == torch::kFloat32 && taps.dim() == 1 && taps.size(0) % 2 == 1 && taps.is_contiguous() &&
                  3 * taps.size(0) <= kMaxTaps,
              "ssim_cpu: an odd number (at most ", kMaxTaps / 3, ") of float32 taps expected");
  return {taps.data_ptr<float>(), static_cast<int>(taps.size(0) / 2)};
}

void check_images(const torch::Tensor& pred, const torch::Tensor& target, int r) {
  TORCH_CHECK(pred.dtype() == torch::kFloat32 && target.dtype() == torch::kFloat32 && pred.is_contiguous() &&
                  target.is_contiguous() && pred.dim() == 4 && pred.sizes() == target.sizes(),
              "ssim_cpu: two contiguous float32 [B, H, W, C] images of one shape expected");
  TORCH_CHECK(pred.size(1) > 2 * r && pred.size(2) > 2 * r, "ssim_cpu: images smaller than the window");
}

// f(q, pixel) for every pixel and channel: q indexes the planes [B * C][H][W], pixel the images [B, H, W, C].
template <typename F>
void for_each_pixel(int64_t B, int64_t H, int64_t W, int64_t C, F f) {
  at::parallel_for(0, B * H, 16, [&](int64_t begin, int64_t end) {
    for (int64_t by = begin; by < end; ++by) {
      const int64_t b = by / H, row = by % H;
      for (int64_t c = 0; c < C; ++c) {
        const int64_t offset = ((b * C + c) * H + row) * W;
        for (int64_t i = 0; i < W; ++i) f(offset + i, (by * W + i) * C + c);
      }
    }
  });
}

// [B, H, W, C] images -> the five moments' planes [5][B * C][H][W]: x, y, x^2, y^2, xy.
void moment_planes(const torch::Tensor& pred, const torch::Tensor& target, float* out) {
  const int64_t B = pred.size(0), H = pred.size(1), W = pred.size(2), C = pred.size(3), count = B * C * H * W;
  const float *x = pred.data_ptr<float>(), *y = target.data_ptr<float>();
  for_each_pixel(B, H, W, C, [&](int64_t q, int64_t pixel) {
    const float xi = x[pixel], yi = y[pixel];
    out[q] = xi;
    out[count + q] = yi;
    out[2 * count + q] = xi * xi;
    out[3 * count + q] = yi * yi;
    out[4 * count + q] = xi * yi;
  });
}

// The per-pixel quantities of S from the blurred moments.
struct Pixel {
  float a1, a2, b1, b2, s;
};

inline Pixel ssim_pixel(float mx, float my, float mxx, float myy, float mxy, float c1, float c2) {
  const float a1 = 2.0f * mx * my + c1, a2 = 2.0f * (mxy - mx * my) + c2;
  const float b1 = mx * mx + my * my + c1, b2 = (mxx - mx * mx) + (myy - my * my) + c2;
  return {a1, a2, b1, b2, (a1 * a2) / (b1 * b2)};
}

}  // namespace

// pred, target [B, H, W, C] float32; taps [2r + 1]. Returns the SSIM map [B, H, W, C] and the blurred moments
// [5, B * C, H, W] (mx, my, m(x^2), m(y^2), m(xy)) that the backward needs.
std::vector<torch::Tensor> ssim_forward(torch::Tensor pred, torch::Tensor target, torch::Tensor taps_tensor,
                                        double c1, double c2) {
  const Taps taps = check_taps(taps_tensor);
  check_images(pred, target, taps.r);
  const int64_t B = pred.size(0), H = pred.size(1), W = pred.size(2), C = pred.size(3), P = B * C;
  const int64_t count = P * H * W;
  auto raw = torch::empty({5, P, H, W}, pred.options());
  auto rows = torch::empty({5, P, H, W}, pred.options());
  auto moments = torch::empty({5, P, H, W}, pred.options());
  float* m = raw.data_ptr<float>();
  moment_planes(pred, target, m);
  blur_rows(m, rows.data_ptr<float>(), 5 * P * H, W, taps);
  blur_columns(rows.data_ptr<float>(), moments.data_ptr<float>(), 5 * P, H, W, taps);
  auto map = torch::empty_like(pred);
  const float* mo = moments.data_ptr<float>();
  float* out = map.data_ptr<float>();
  const float fc1 = static_cast<float>(c1), fc2 = static_cast<float>(c2);
  for_each_pixel(B, H, W, C, [&](int64_t q, int64_t pixel) {
    out[pixel] = ssim_pixel(mo[q], mo[count + q], mo[2 * count + q], mo[3 * count + q], mo[4 * count + q], fc1, fc2).s;
  });
  return {map, moments};
}

// dL/dpred [B, H, W, C] from dL/dmap [B, H, W, C].
torch::Tensor ssim_backward(torch::Tensor grad_map, torch::Tensor pred, torch::Tensor target, torch::Tensor moments,
                            torch::Tensor taps_tensor, double c1, double c2) {
  const Taps taps = check_taps(taps_tensor);
  check_images(pred, target, taps.r);
  grad_map = grad_map.contiguous();
  TORCH_CHECK(grad_map.sizes() == pred.sizes() && grad_map.dtype() == torch::kFloat32,
              "ssim_cpu: the map's gradient must be float32 and shaped like the images");
  const int64_t B = pred.size(0), H = pred.size(1), W = pred.size(2), C = pred.size(3), P = B * C;
  const int64_t count = P * H * W;
  // per pixel: dL/dmx, dL/dm(x^2), dL/dm(xy)
  auto partials = torch::empty({3, P, H, W}, pred.options());
  const float *mo = moments.data_ptr<float>(), *g = grad_map.data_ptr<float>();
  float* d = partials.data_ptr<float>();
  const float fc1 = static_cast<float>(c1), fc2 = static_cast<float>(c2);
  for_each_pixel(B, H, W, C, [&](int64_t q, int64_t pixel) {
    const float mx = mo[q], my = mo[count + q];
    const Pixel px = ssim_pixel(mx, my, mo[2 * count + q], mo[3 * count + q], mo[4 * count + q], fc1, fc2);
    const float grad = g[pixel], denominator = px.b1 * px.b2;
    d[q] = grad * (2.0f * my * (px.a2 - px.a1) / denominator + 2.0f * mx * px.s * (1.0f / px.b2 - 1.0f / px.b1));
    d[count + q] = grad * (-px.s / px.b2);
    d[2 * count + q] = grad * (2.0f * px.a1 / denominator);
  });
  auto columns = torch::empty({3, P, H, W}, pred.options());
  auto spread = torch::empty({3, P, H, W}, pred.options());
  blur_columns_adjoint(d, columns.data_ptr<float>(), 3 * P, H, W, taps);
  blur_rows_adjoint(columns.data_ptr<float>(), spread.data_ptr<float>(), 3 * P * H, W, taps);
  auto grad_pred = torch::empty_like(pred);
  const float *s = spread.data_ptr<float>(), *x = pred.data_ptr<float>(), *y = target.data_ptr<float>();
  float* out = grad_pred.data_ptr<float>();
  for_each_pixel(B, H, W, C, [&](int64_t q, int64_t pixel) {
    out[pixel] = s[q] + 2.0f * x[pixel] * s[count + q] + y[pixel] * s[2 * count + q];
  });
  return grad_pred;
}

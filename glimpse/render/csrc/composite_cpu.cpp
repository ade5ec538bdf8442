// Tile-based alpha compositing of projected Gaussians on the CPU: forward and backward.
//
// The rules are those of glimpse/render/composite_torch.py (the reference):
// power = -0.5 (a dx^2 + c dy^2) - b dx dy with (dx, dy) = mean - pixel (pixel centres at
// integer coordinates); skip when power > 0 or alpha = min(0.999, o exp(power)) < 1/255;
// front to back, a pixel stops before its transmittance would reach 1e-4.
//
// Each tile is processed by one thread, Gaussian by Gaussian (outer loop) over the pixels of
// the Gaussian's box clipped to the tile (inner loop), so the inner loop is short and
// vectorisable. The backward accumulates gradients per thread (no atomics) and sums them.
#include <torch/extension.h>
#include <ATen/Parallel.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <vector>

namespace {

constexpr float kAlphaMin = 1.0f / 255.0f;
constexpr float kAlphaMax = 0.999f;
constexpr float kTransmittanceMin = 1e-4f;

struct Inputs {
  const float* means2d;   // [N, 2]
  const float* conics;    // [N, 3]
  const float* opacities; // [N]
  const float* features;  // [N, C]
  const float* extents;   // [N, 2] half-extents of the box where alpha can reach 1/255
  const int* offsets;     // [tiles + 1]
  const int* ids;         // [M]
  int64_t channels, width, height, tile, tiles_x, tiles_y;
};

// exp(x) for x <= 0, branch-free so that loops over pixels vectorise (std::exp is a library
// call that does not): Cephes' expf, about 1 ulp. x = n ln2 + r, |r| <= ln2 / 2, e^r by a
// degree-6 polynomial, times 2^n built in the exponent bits.
inline float fast_exp(float x) {
  x = std::max(x, -87.0f);  // keeps 2^n a normal float
  const float n = std::floor(x * 1.44269504088896341f + 0.5f);
  const float r = x - n * 0.693359375f + n * 2.12194440e-4f;
  float p = 1.9875691500e-4f;
  p = p * r + 1.3981999507e-3f;
  p = p * r + 8.3334519073e-3f;
  p = p * r + 4.1665795894e-2f;
  p = p * r + 1.6666665459e-1f;
  p = p * r + 5.0000001201e-1f;
  p = p * r * r + r + 1.0f;
  const int32_t bits = (static_cast<int32_t>(n) + 127) << 23;
  float scale;
  std::memcpy(&scale, &bits, sizeof scale);
  return p * scale;
}

// The pixel range [lo, hi) of axis `axis` of the tile starting at `start` that a Gaussian's box covers.
inline void box_range(float centre, float extent, int64_t start, int64_t stop, int64_t& lo, int64_t& hi) {
  lo = std::max<int64_t>(start, static_cast<int64_t>(std::ceil(centre - extent)));
  hi = std::min<int64_t>(stop, static_cast<int64_t>(std::floor(centre + extent)) + 1);
}

// One Gaussian as a tile sees it: its parameters and its box clipped to the tile, [xa, xb) x [ya, yb).
struct TileGaussian {
  float mx, my, a, b, c, o;
  const float* f;
  int64_t xa, xb, ya, yb;
};

inline TileGaussian tile_gaussian(const Inputs& in, int g, int64_t x0, int64_t x1, int64_t y0, int64_t y1) {
  TileGaussian t{in.means2d[2 * g], in.means2d[2 * g + 1], in.conics[3 * g], in.conics[3 * g + 1],
                 in.conics[3 * g + 2], in.opacities[g], in.features + g * in.channels, 0, 0, 0, 0};
  box_range(t.mx, in.extents[2 * g], x0, x1, t.xa, t.xb);
  box_range(t.my, in.extents[2 * g + 1], y0, y1, t.ya, t.yb);
  return t;
}

Inputs make_inputs(const torch::Tensor& means2d, const torch::Tensor& conics, const torch::Tensor& opacities,
                   const torch::Tensor& features, const torch::Tensor& extents, const torch::Tensor& offsets,
                   const torch::Tensor& ids, int64_t width, int64_t height, int64_t tile) {
  TORCH_CHECK(means2d.dtype() == torch::kFloat32 && conics.dtype() == torch::kFloat32 &&
                  opacities.dtype() == torch::kFloat32 && features.dtype() == torch::kFloat32 &&
                  extents.dtype() == torch::kFloat32,
              "composite_cpu: float32 inputs expected");
  TORCH_CHECK(offsets.dtype() == torch::kInt32 && ids.dtype() == torch::kInt32, "composite_cpu: int32 bins expected");
  TORCH_CHECK(means2d.is_contiguous() && conics.is_contiguous() && opacities.is_contiguous() &&
                  features.is_contiguous() && extents.is_contiguous() && offsets.is_contiguous() && ids.is_contiguous(),
              "composite_cpu: contiguous inputs expected");
  const int64_t tiles_x = (width + tile - 1) / tile, tiles_y = (height + tile - 1) / tile;
  TORCH_CHECK(offsets.numel() == tiles_x * tiles_y + 1, "composite_cpu: tile_offsets has the wrong length");
  return {means2d.data_ptr<float>(), conics.data_ptr<float>(), opacities.data_ptr<float>(),
          features.data_ptr<float>(), extents.data_ptr<float>(), offsets.data_ptr<int>(), ids.data_ptr<int>(),
          features.size(1), width, height, tile, tiles_x, tiles_y};
}

}  // namespace

// Returns image [H, W, C], final transmittance [H, W], and per pixel the number of list entries
// up to and including its last contributor [H, W] (int32), which the backward needs.
std::vector<torch::Tensor> composite_forward(torch::Tensor means2d, torch::Tensor conics, torch::Tensor opacities,
                                             torch::Tensor features, torch::Tensor extents,
                                             torch::Tensor tile_offsets, torch::Tensor gaussian_ids, int64_t width,
                                             int64_t height, int64_t tile) {
  const Inputs in = make_inputs(means2d, conics, opacities, features, extents, tile_offsets, gaussian_ids, width,
                                height, tile);
  const int64_t C = in.channels;
  // every pixel is written by its tile below: no fill needed
  auto image = torch::empty({height, width, C}, features.options());
  auto final_T = torch::empty({height, width}, features.options());
  auto last = torch::empty({height, width}, tile_offsets.options());
  float* image_ptr = image.data_ptr<float>();
  float* T_ptr = final_T.data_ptr<float>();
  int* last_ptr = last.data_ptr<int>();

  at::parallel_for(0, in.tiles_x * in.tiles_y, 1, [&](int64_t begin, int64_t end) {
    const int64_t P = in.tile * in.tile;
    std::vector<float> T(P), acc(P * C), alpha_row(in.tile);
    std::vector<int> n_last(P);
    std::vector<char> done(P);
    for (int64_t k = begin; k < end; ++k) {
      const int64_t x0 = (k % in.tiles_x) * in.tile, y0 = (k / in.tiles_x) * in.tile;
      const int64_t x1 = std::min(x0 + in.tile, in.width), y1 = std::min(y0 + in.tile, in.height);
      std::fill(T.begin(), T.end(), 1.0f);
      std::fill(acc.begin(), acc.end(), 0.0f);
      std::fill(n_last.begin(), n_last.end(), 0);
      std::fill(done.begin(), done.end(), 0);
      int64_t remaining = (x1 - x0) * (y1 - y0);
      const int start = in.offsets[k], stop = in.offsets[k + 1];
      for (int e = start; e < stop && remaining > 0; ++e) {
        const int g = in.ids[e];
        const TileGaussian tg = tile_gaussian(in, g, x0, x1, y0, y1);
        const float mx = tg.mx, my = tg.my, a = tg.a, b = tg.b, c = tg.c, o = tg.o;
        const float* f = tg.f;
        const int64_t xa = tg.xa, xb = tg.xb, ya = tg.ya, yb = tg.yb;
        for (int64_t y = ya; y < yb; ++y) {
          const float dy = my - static_cast<float>(y);
          const int width_in_box = static_cast<int>(xb - xa);
          const float first_dx = mx - static_cast<float>(xa);
          for (int i = 0; i < width_in_box; ++i) {  // vectorised (32-bit counter: AVX2 converts int32 only)
            const float dx = first_dx - static_cast<float>(i);
            const float power = -0.5f * (a * dx * dx + c * dy * dy) - b * dx * dy;
            const float alpha = std::min(kAlphaMax, o * fast_exp(std::min(power, 0.0f)));
            alpha_row[i] = (power <= 0.0f && alpha >= kAlphaMin) ? alpha : 0.0f;
          }
          for (int64_t x = xa; x < xb; ++x) {
            const int64_t p = (y - y0) * in.tile + (x - x0);
            const float alpha = alpha_row[x - xa];
            if (done[p] || alpha == 0.0f) continue;
            const float next_T = T[p] * (1.0f - alpha);
            if (next_T <= kTransmittanceMin) {
              done[p] = 1;
              --remaining;
              continue;
            }
            const float w = alpha * T[p];
            float* out = acc.data() + p * C;
            for (int64_t ch = 0; ch < C; ++ch) out[ch] += w * f[ch];
            T[p] = next_T;
            n_last[p] = e - start + 1;
          }
        }
      }
      for (int64_t y = y0; y < y1; ++y) {
        for (int64_t x = x0; x < x1; ++x) {
          const int64_t p = (y - y0) * in.tile + (x - x0), q = y * in.width + x;
          std::copy(acc.data() + p * C, acc.data() + (p + 1) * C, image_ptr + q * C);
          T_ptr[q] = T[p];
          last_ptr[q] = n_last[p];
        }
      }
    }
  });
  return {image, final_T, last};
}

// Gradients of a loss with respect to means2d [N, 2], conics [N, 3], opacities [N] and features [N, C],
// given its gradient with respect to the image [H, W, C].
std::vector<torch::Tensor> composite_backward(torch::Tensor means2d, torch::Tensor conics, torch::Tensor opacities,
                                              torch::Tensor features, torch::Tensor extents,
                                              torch::Tensor tile_offsets, torch::Tensor gaussian_ids,
                                              torch::Tensor final_T, torch::Tensor last, torch::Tensor grad_image,
                                              int64_t width, int64_t height, int64_t tile) {
  const Inputs in = make_inputs(means2d, conics, opacities, features, extents, tile_offsets, gaussian_ids, width,
                                height, tile);
  grad_image = grad_image.contiguous();
  const int64_t C = in.channels, N = means2d.size(0);
  const int64_t stride = 6 + C;  // per Gaussian: mean (2), conic (3), opacity (1), features (C)
  const int threads = at::get_num_threads();
  auto buffers = torch::zeros({threads, N, stride}, features.options());
  float* buffer_ptr = buffers.data_ptr<float>();
  const float* dL = grad_image.data_ptr<float>();
  const float* T_final = final_T.data_ptr<float>();
  const int* last_ptr = last.data_ptr<int>();

  at::parallel_for(0, in.tiles_x * in.tiles_y, 1, [&](int64_t begin, int64_t end) {
    float* grads = buffer_ptr + at::get_thread_num() * N * stride;
    const int64_t P = in.tile * in.tile;
    std::vector<float> T(P), behind(P * C), last_alpha(P), last_f(P * C), dL_tile(P * C), local(stride);
    std::vector<float> G_row(in.tile), power_row(in.tile);
    std::vector<int> n_last(P);
    for (int64_t k = begin; k < end; ++k) {
      const int64_t x0 = (k % in.tiles_x) * in.tile, y0 = (k / in.tiles_x) * in.tile;
      const int64_t x1 = std::min(x0 + in.tile, in.width), y1 = std::min(y0 + in.tile, in.height);
      int max_last = 0;
      std::fill(behind.begin(), behind.end(), 0.0f);
      std::fill(last_alpha.begin(), last_alpha.end(), 0.0f);
      std::fill(last_f.begin(), last_f.end(), 0.0f);
      for (int64_t y = y0; y < y1; ++y) {
        for (int64_t x = x0; x < x1; ++x) {
          const int64_t p = (y - y0) * in.tile + (x - x0), q = y * in.width + x;
          T[p] = T_final[q];
          n_last[p] = last_ptr[q];
          max_last = std::max(max_last, n_last[p]);
          std::copy(dL + q * C, dL + (q + 1) * C, dL_tile.data() + p * C);
        }
      }
      const int start = in.offsets[k];
      for (int e = start + max_last - 1; e >= start; --e) {  // back to front
        const int g = in.ids[e];
        const TileGaussian tg = tile_gaussian(in, g, x0, x1, y0, y1);
        const float mx = tg.mx, my = tg.my, a = tg.a, b = tg.b, c = tg.c, o = tg.o;
        const float* f = tg.f;
        const int64_t xa = tg.xa, xb = tg.xb, ya = tg.ya, yb = tg.yb;
        std::fill(local.begin(), local.end(), 0.0f);
        bool touched = false;
        for (int64_t y = ya; y < yb; ++y) {
          const float dy = my - static_cast<float>(y);
          const int width_in_box = static_cast<int>(xb - xa);
          const float first_dx = mx - static_cast<float>(xa);
          for (int i = 0; i < width_in_box; ++i) {  // vectorised pass
            const float dx = first_dx - static_cast<float>(i);
            const float power = -0.5f * (a * dx * dx + c * dy * dy) - b * dx * dy;
            power_row[i] = power;
            G_row[i] = fast_exp(std::min(power, 0.0f));
          }
          for (int64_t x = xa; x < xb; ++x) {
            const int64_t p = (y - y0) * in.tile + (x - x0);
            if (e - start >= n_last[p]) continue;  // after this pixel's last contributor
            const float dx = mx - static_cast<float>(x);
            if (power_row[x - xa] > 0.0f) continue;
            const float G = G_row[x - xa];
            const float raw = o * G;
            const float alpha = std::min(kAlphaMax, raw);
            if (alpha < kAlphaMin) continue;
            touched = true;
            T[p] /= (1.0f - alpha);  // transmittance in front of this Gaussian
            const float w = alpha * T[p];
            const float* dLp = dL_tile.data() + p * C;
            float* bp = behind.data() + p * C;
            float* lf = last_f.data() + p * C;
            float dL_dalpha = 0.0f;
            for (int64_t ch = 0; ch < C; ++ch) {
              local[6 + ch] += w * dLp[ch];
              bp[ch] = last_alpha[p] * lf[ch] + (1.0f - last_alpha[p]) * bp[ch];  // colour behind, normalised
              lf[ch] = f[ch];
              dL_dalpha += (f[ch] - bp[ch]) * dLp[ch];
            }
            dL_dalpha *= T[p];
            last_alpha[p] = alpha;
            if (raw <= kAlphaMax) {  // a clamped alpha does not depend on o or the Gaussian
              const float dL_dpower = dL_dalpha * alpha;
              local[5] += G * dL_dalpha;
              local[2] += -0.5f * dx * dx * dL_dpower;
              local[3] += -dx * dy * dL_dpower;
              local[4] += -0.5f * dy * dy * dL_dpower;
              local[0] += -(a * dx + b * dy) * dL_dpower;
              local[1] += -(b * dx + c * dy) * dL_dpower;
            }
          }
        }
        if (touched) {
          float* gg = grads + static_cast<int64_t>(g) * stride;
          for (int64_t j = 0; j < stride; ++j) gg[j] += local[j];
        }
      }
    }
  });
  auto total = buffers.sum(0);  // [N, stride]
  return {total.slice(1, 0, 2).contiguous(), total.slice(1, 2, 5).contiguous(), total.select(1, 5).contiguous(),
          total.slice(1, 6, 6 + C).contiguous()};
}

// Tile binning by counting sort. rects [V, 4] int32 (x0, y0, x1, y1: inclusive tile ranges) of the
// visible Gaussians ids [V] int32, both already in front-to-back order; appending each Gaussian to its
// tiles in that order leaves every tile's list sorted front to back.
std::vector<torch::Tensor> bin_tiles(torch::Tensor rects, torch::Tensor ids, int64_t tiles_x, int64_t tiles_y) {
  TORCH_CHECK(rects.dtype() == torch::kInt32 && ids.dtype() == torch::kInt32 && rects.is_contiguous() &&
                  ids.is_contiguous(),
              "bin_tiles: contiguous int32 inputs expected");
  const int64_t V = ids.numel(), tiles = tiles_x * tiles_y;
  const int* r = rects.data_ptr<int>();
  const int* id = ids.data_ptr<int>();
  auto offsets = torch::zeros({tiles + 1}, ids.options());
  int* off = offsets.data_ptr<int>();
  for (int64_t v = 0; v < V; ++v)
    for (int ty = r[4 * v + 1]; ty <= r[4 * v + 3]; ++ty)
      for (int tx = r[4 * v]; tx <= r[4 * v + 2]; ++tx) ++off[ty * tiles_x + tx + 1];
  for (int64_t k = 0; k < tiles; ++k) off[k + 1] += off[k];
  auto entries = torch::empty({off[tiles]}, ids.options());
  int* out = entries.data_ptr<int>();
  std::vector<int> fill(off, off + tiles);
  for (int64_t v = 0; v < V; ++v)
    for (int ty = r[4 * v + 1]; ty <= r[4 * v + 3]; ++ty)
      for (int tx = r[4 * v]; tx <= r[4 * v + 2]; ++tx) out[fill[ty * tiles_x + tx]++] = id[v];
  return {entries, offsets};
}

// project_cpu.cpp
std::vector<torch::Tensor> project_forward(torch::Tensor means, torch::Tensor covariances, torch::Tensor opacities,
                                           torch::Tensor K, torch::Tensor R, torch::Tensor t, int64_t width,
                                           int64_t height, double near, double far, bool antialiased);
std::vector<torch::Tensor> project_backward(torch::Tensor means, torch::Tensor covariances, torch::Tensor opacities,
                                            torch::Tensor cam, torch::Tensor K, torch::Tensor R, torch::Tensor t,
                                            int64_t width, int64_t height, double near, double far, bool antialiased,
                                            torch::Tensor v_means2d, torch::Tensor v_conics, torch::Tensor v_depths,
                                            torch::Tensor v_opac_out);

// pose_cpu.cpp
std::vector<torch::Tensor> pose_forward(torch::Tensor weights, torch::Tensor joint_transforms,
                                        torch::Tensor canonical_inverse, torch::Tensor means, torch::Tensor covariances,
                                        torch::Tensor sh, int64_t degree, torch::Tensor camera_centre);

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  m.def("project_forward", &project_forward, "EWA projection, forward (CPU)");
  m.def("project_backward", &project_backward, "EWA projection, backward (CPU)");
  m.def("bin_tiles", &bin_tiles, "Tile binning by counting sort (CPU)");
  m.def("forward", &composite_forward, "Gaussian compositing, forward (CPU)");
  m.def("backward", &composite_backward, "Gaussian compositing, backward (CPU)");
  m.def("pose_forward", &pose_forward, "Posing a frozen person's Gaussians, forward (CPU)");
}

// Tile-based alpha compositing of projected Gaussians on the CPU: forward and backward.
//
// The rules are those of glimpse/render/composite_torch.py (the reference):
// power = -0.5 (a dx^2 + c dy^2) - b dx dy with (dx, dy) = mean - pixel (pixel centres at
// integer coordinates); skip when power > 0 or alpha = min(0.999, o exp(power)) < 1/255;
// front to back, a pixel stops before its transmittance would reach 1e-4.
//
// The forward shares tiles among threads dynamically (busy tiles do not hold up a thread that has
// finished its share); the backward deals them round-robin, so that its per-thread sums are the same
// on every run. Within a tile, Gaussians are taken one by one (outer loop); each row of the
// Gaussian's box is computed in groups of 8 pixels as one vector (GCC's vector extensions: one AVX2
// register, a fixed width, no scalar epilogue), pixels outside the box masked off, branch-free, and
// only the groups that the row's ellipse reaches are walked (reach_steps, worked out one Gaussian ahead). Per-tile
// state is stored channel-major, so every channel is one more vector. Every store writes a whole vector
// (the old value where a pixel is not hit): the loops GCC vectorised itself turned the state updates
// into masked stores, which AMD CPUs execute slowly and which stall the next Gaussian's loads of the
// same pixels (no store forwarding); written this way the forward is about 1.2x faster. Each Gaussian's
// inputs are first packed into one record (a cache line for up to 8 channels), fetched a few list entries
// ahead. A pixel that has stopped keeps its transmittance negated (one array, no separate live mask). The
// backward walks each tile back to front the same way, keeps one running sum per pixel of the colour
// behind dotted with the image's gradient (gsplat's form of d pixel / d alpha, contracted), sums per lane the
// moments that give each Gaussian's gradients (one transposed horizontal sum per Gaussian and tile), keeps
// per-thread gradient buffers (no atomics) and sums them in parallel. Channels whose gradient is zero at every pixel are left out of its walk.
#include <torch/extension.h>
#include <ATen/Parallel.h>
#include <omp.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <vector>

#include "lanes.h"
#include "raster_rules.h"

namespace {

using namespace glimpse_lanes;  // kLanes: pixels of a row computed together (one AVX2 vector)

using glimpse_raster::kAlphaMin;

constexpr float kAlphaMax = 0.999f;
constexpr float kTransmittanceMin = 1e-4f;
constexpr int kTile = 16;  // pixels per tile side (glimpse/render/rasterize.py TILE_SIZE)
constexpr int kTilePixels = kTile * kTile;

struct Inputs {
  const float* means2d;   // [N, 2]
  const float* conics;    // [N, 3]
  const float* opacities; // [N]
  const float* features;  // [N, C]
  const float* extents;   // [N, 2] half-extents of the box where alpha can reach 1/255
  const int* offsets;     // [tiles + 1]
  const int* ids;         // [M]
  int64_t channels, width, height, tiles_x, tiles_y;
  float* records;         // [N, record_stride]: the above per Gaussian in one record (pack_records)
  int64_t record_stride;
};

// Each Gaussian's parameters packed into one record: mean x, y, conic a, b, c, opacity, extent x, y, then its C
// features, padded to whole cache lines. A tile's walk reads the Gaussians in depth order, scattered over the
// inputs: from five inputs that was five cache misses per Gaussian and tile, from the record one or two.
constexpr int kRecordHeader = 8;
constexpr int kLineFloats = 16;  // floats per 64-byte cache line

constexpr int kPrefetchAhead = 4;  // list entries ahead whose records are fetched (a miss costs a few Gaussians' work)

int64_t record_stride(int64_t channels) {
  return (kRecordHeader + channels + kLineFloats - 1) / kLineFloats * kLineFloats;
}

inline void prefetch_record(const Inputs& in, int g) {
  const float* rec = in.records + static_cast<int64_t>(g) * in.record_stride;
  for (int64_t line = 0; line < in.record_stride; line += kLineFloats) __builtin_prefetch(rec + line);
}

// Fills in.records; called by every thread of a parallel region (the loop is shared; a barrier ends it).
void pack_records(const Inputs& in, int64_t N) {
#pragma omp for schedule(static)
  for (int64_t g = 0; g < N; ++g) {
    float* rec = in.records + g * in.record_stride;
    rec[0] = in.means2d[2 * g];
    rec[1] = in.means2d[2 * g + 1];
    for (int j = 0; j < 3; ++j) rec[2 + j] = in.conics[3 * g + j];
    rec[5] = in.opacities[g];
    rec[6] = in.extents[2 * g];
    rec[7] = in.extents[2 * g + 1];
    std::memcpy(rec + kRecordHeader, in.features + g * in.channels, in.channels * sizeof(float));
  }
}

// The pixel range [lo, hi) of axis `axis` of the tile starting at `start` that a Gaussian's box covers.
inline void box_range(float centre, float extent, int64_t start, int64_t stop, int64_t& lo, int64_t& hi) {
  lo = std::max<int64_t>(start, static_cast<int64_t>(std::ceil(centre - extent)));
  hi = std::min<int64_t>(stop, static_cast<int64_t>(std::floor(centre + extent)) + 1);
}

// One Gaussian as a tile sees it: its parameters, its box's half-height `ey` and its box clipped to the tile, as
// tile-relative columns [xa, xb) and image rows [ya, yb).
struct TileGaussian {
  float mx, my, a, b, c, o, ey;
  const float* f;
  int xa, xb;
  int64_t ya, yb;
};

inline TileGaussian tile_gaussian(const Inputs& in, int g, int64_t x0, int64_t x1, int64_t y0, int64_t y1) {
  const float* rec = in.records + static_cast<int64_t>(g) * in.record_stride;
  TileGaussian t{rec[0], rec[1], rec[2], rec[3], rec[4], rec[5], rec[7], rec + kRecordHeader, 0, 0, 0, 0};
  int64_t xa, xb;
  box_range(t.mx, rec[6], x0, x1, xa, xb);
  box_range(t.my, t.ey, y0, y1, t.ya, t.yb);
  t.xa = static_cast<int>(xa - x0);
  t.xb = static_cast<int>(xb - x0);
  return t;
}

// `records` [N, record_stride(C)]: the forward allocates it (64-byte aligned: torch's CPU allocator's alignment)
// and packs it (pack_records); the backward is given the forward's.
Inputs make_inputs(const torch::Tensor& means2d, const torch::Tensor& conics, const torch::Tensor& opacities,
                   const torch::Tensor& features, const torch::Tensor& extents, const torch::Tensor& offsets,
                   const torch::Tensor& ids, int64_t width, int64_t height, int64_t tile,
                   const torch::Tensor& records) {
  TORCH_CHECK(means2d.dtype() == torch::kFloat32 && conics.dtype() == torch::kFloat32 &&
                  opacities.dtype() == torch::kFloat32 && features.dtype() == torch::kFloat32 &&
                  extents.dtype() == torch::kFloat32,
              "composite_cpu: float32 inputs expected");
  TORCH_CHECK(offsets.dtype() == torch::kInt32 && ids.dtype() == torch::kInt32, "composite_cpu: int32 bins expected");
  TORCH_CHECK(means2d.is_contiguous() && conics.is_contiguous() && opacities.is_contiguous() &&
                  features.is_contiguous() && extents.is_contiguous() && offsets.is_contiguous() && ids.is_contiguous(),
              "composite_cpu: contiguous inputs expected");
  TORCH_CHECK(tile == kTile, "composite_cpu: tiles of ", kTile, " pixels expected, got ", tile);
  const int64_t tiles_x = (width + tile - 1) / tile, tiles_y = (height + tile - 1) / tile;
  TORCH_CHECK(offsets.numel() == tiles_x * tiles_y + 1, "composite_cpu: tile_offsets has the wrong length");
  const int64_t stride = record_stride(features.size(1));
  TORCH_CHECK(records.dtype() == torch::kFloat32 && records.is_contiguous() && records.dim() == 2 &&
                  records.size(0) == means2d.size(0) && records.size(1) == stride,
              "composite_cpu: the forward's packed records expected");
  return {means2d.data_ptr<float>(), conics.data_ptr<float>(), opacities.data_ptr<float>(),
          features.data_ptr<float>(), extents.data_ptr<float>(), offsets.data_ptr<int>(), ids.data_ptr<int>(),
          features.size(1), width, height, tiles_x, tiles_y, records.data_ptr<float>(), stride};
}

// Tile k's pixel rectangle [x0, x1) x [y0, y1).
struct TileRect {
  int64_t x0, y0, x1, y1;
};

inline TileRect tile_rect(const Inputs& in, int64_t k) {
  const int64_t x0 = (k % in.tiles_x) * kTile, y0 = (k / in.tiles_x) * kTile;
  return {x0, y0, std::min<int64_t>(x0 + kTile, in.width), std::min<int64_t>(y0 + kTile, in.height)};
}

// kLanes pixels of a row as one vector (lanes.h): every operation is written for all lanes, and every store writes
// whole vectors.
inline int count_lanes(Ints mask) { return __builtin_popcount(static_cast<unsigned>(lane_bits(mask))); }
inline bool any_lane(Ints mask) { return lane_bits(mask) != 0; }

// exp(x) for x <= 0 on every lane: Cephes' expf, about 1 ulp. x = n ln2 + r, |r| <= ln2 / 2, e^r by a
// degree-6 polynomial, times 2^n built in the exponent bits. n = round(x / ln2) is taken by adding 1.5 2^23: the sum
// lies in [2^23, 2^24), where floats are the integers, so the addition rounds to n and the sum's low bits hold it
// (no conversion instructions: they were a third of the backward's time with the exp).
constexpr float kRoundingShift = 12582912.0f;  // 1.5 2^23
inline Floats fast_exp(Floats x) {
  x = max(x, Floats{} - 87.0f);  // keeps 2^n a normal float
  const Floats shifted = x * 1.44269504088896341f + kRoundingShift;
  const Floats n = shifted - kRoundingShift;
  const Floats r = x - n * 0.693359375f + n * 2.12194440e-4f;
  Floats p = Floats{} + 1.9875691500e-4f;
  p = p * r + 1.3981999507e-3f;
  p = p * r + 8.3334519073e-3f;
  p = p * r + 4.1665795894e-2f;
  p = p * r + 1.6666665459e-1f;
  p = p * r + 5.0000001201e-1f;
  p = p * r * r + r + 1.0f;
  // the sum's bits are those of 1.5 2^23 plus n: shifted left by 23, the constant's bits leave the word (its lowest
  // set bit is bit 22), and n + 127 lands in the exponent
  Ints bits;
  std::memcpy(&bits, &shifted, sizeof bits);
  bits = (bits + 127) << 23;
  Floats scale;
  std::memcpy(&scale, &bits, sizeof scale);
  return p * scale;
}

// The Gaussian's exponent -0.5 (a dx^2 + c dy^2) - b dx dy at dx = mean_x - pixel_x, dy = mean_y - pixel_y.
inline Floats gaussian_power(const TileGaussian& t, Floats dx, float dy) {
  return -0.5f * (t.a * dx * dx + t.c * dy * dy) - t.b * dx * dy;
}

// A row's alpha over kLanes pixels at dx = mean_x - pixel_x: min(0.999, o exp(power)), 0 where power > 0 (the
// reference skips those pixels; 0 is below kAlphaMin, so they fail the same test).
inline Floats gaussian_alpha(const TileGaussian& t, Floats dx, float dy) {
  const Floats power = gaussian_power(t, dx, dy);
  const Floats alpha = min(Floats{} + kAlphaMax, t.o * fast_exp(min(power, Floats{})));
  return power <= 0.0f ? alpha : 0.0f;
}

// The steps of a Gaussian's walk through a tile: bit 2 row + g for each tile row `row` (0-15) and lane group g
// (columns 8g to 8g + 7) that holds a pixel of its box where alpha can reach 1/255. Every other lane group of the box
// would be computed for nothing: a quarter of them on a trained scene, a sixth on bench/raster.py's random one.
// That region is the ellipse 0.5 d^T Q d <= L, Q = [[a, b], [b, c]] the conic, L = ln(o / (1/255)), and the box's
// half-height is ey = sqrt(2 L a / q) (q = ac - b^2; the projection's, 1e-3 wider), so row y of it spans
//     x = mean_x + (b dy -+ sqrt(q (ey^2 - dy^2))) / a,   dy = mean_y - y,
// from the box alone (no logarithm); the widened ey and kSpanMargin keep every pixel the lanes' own test accepts.
// Bits go in row-major order, so the steps run in the order of a walk over the whole box.
constexpr float kSpanMargin = 0.01f;  // pixels added to each side of a row's span (rounding)
// smallest q / (ac) whose spans are computed (1 - q / (ac) = b^2 / (ac)): below it, float32's cancellation in q could
// shrink a span by more than the extents' 1e-3 slack covers (seen from q / (ac) of about 1e-5 on)
constexpr float kWellConditioned = 1e-4f;

inline uint32_t spread_bits(uint32_t x) {  // bit i of a 16-bit x to bit 2i
  x = (x | (x << 8)) & 0x00FF00FFu;
  x = (x | (x << 4)) & 0x0F0F0F0Fu;
  x = (x | (x << 2)) & 0x33333333u;
  return (x | (x << 1)) & 0x55555555u;
}

inline uint32_t reach_steps(const TileGaussian& t, int64_t x0, int64_t y0) {
  const float q = t.a * t.c - t.b * t.b;
  // a conic too ill-conditioned for float32 to place its rows' spans (q is a difference of near-equal products:
  // needles hundreds of pixels long), or a degenerate one: every row of the box is walked whole
  const bool spans = q > kWellConditioned * (t.a * t.c) && t.a > 0.0f;
  const float inv_a = 1.0f / t.a, slope = t.b * inv_a, cx = t.mx - static_cast<float>(x0),
              cy = t.my - static_cast<float>(y0), ey2 = t.ey * t.ey;
  const float first_row = static_cast<float>(t.ya - y0), end_row = static_cast<float>(t.yb - y0);
  uint32_t groups[2] = {0, 0};  // per lane group: bit `row`
  for (int half = 0; half < 2; ++half) {  // rows 0-7, then 8-15
    const Floats row = kLaneOffsets + static_cast<float>(half * kLanes);
    const Floats dy = cy - row;
    const Floats room = q * (ey2 - dy * dy);
    const Floats width = sqrt_lanes(max(room, Floats{})) * inv_a + kSpanMargin;
    const Floats lo = cx + slope * dy - width, hi = lo + 2.0f * width;
    const Ints rows = (row >= first_row) & (row < end_row);
    for (int g = 0; g < 2; ++g) {
      const float column = static_cast<float>(g * kLanes);  // the group's first column
      const Ints reach = spans ? rows & (room >= 0.0f) & (lo <= column + (kLanes - 1)) & (hi >= column) : rows;
      groups[g] |= static_cast<uint32_t>(lane_bits(reach)) << (half * kLanes);
    }
  }
  for (int g = 0; g < 2; ++g)  // the box's columns must meet the group's
    if (t.xa >= (g + 1) * kLanes || t.xb <= g * kLanes) groups[g] = 0;
  return spread_bits(groups[0]) | (spread_bits(groups[1]) << 1);
}
static_assert(kTile == 2 * kLanes, "reach_steps assumes two lane groups per tile row");

// A list entry of a tile: the Gaussian and the steps of its walk. The walks work out the next entry's before they
// walk the current one, so that its latency (a division, square roots, the bits' shuffle) overlaps that walk.
struct TileEntry {
  TileGaussian g;
  uint32_t steps;
};

inline TileEntry tile_entry(const Inputs& in, int g, const TileRect& r) {
  const TileGaussian t = tile_gaussian(in, g, r.x0, r.x1, r.y0, r.y1);
  return {t, reach_steps(t, r.x0, r.y0)};
}

// Step j (bit j of reach_steps) in the tile whose first pixel is (x0, y0): dy = mean_y - the row's y, the lane
// group's first column x8 (tile-relative), the group's offset in the per-tile arrays, and dx = mean_x - pixel_x on
// every lane.
struct BoxStep {
  float dy;
  int x8, base;
  Floats dx;
};

inline BoxStep box_step(const TileGaussian& t, int64_t x0, int64_t y0, int j) {
  const int x8 = (j & 1) * kLanes;
  return {t.my - static_cast<float>(y0 + (j >> 1)), x8, j * kLanes, t.mx - static_cast<float>(x0 + x8) - kLaneOffsets};
}

// The number of per-lane sums a Gaussian's backward keeps (6 for its geometry, one per active channel), padded to whole
// groups of eight for sum_lanes8.
inline int64_t sum_vectors(int64_t active) { return (6 + active + kLanes - 1) / kLanes * kLanes; }

// The sums of eight vectors' lanes, as one vector [sum v[0], ..., sum v[7]], each by a fixed tree of pairwise sums
// (lanes i and i + 4, then i and i + 2, then i and i + 1: the same sums on every build and run), in 14 shuffles and 7
// additions for all eight where one vector at a time takes 3 of each.
inline Floats sum_lanes8(const Floats* v) {
  Floats halves[4], quarters[2];
  for (int k = 0; k < 4; ++k)
    halves[k] = __builtin_shuffle(v[k], v[k + 4], Ints{0, 1, 2, 3, 8, 9, 10, 11}) +
                __builtin_shuffle(v[k], v[k + 4], Ints{4, 5, 6, 7, 12, 13, 14, 15});
  for (int k = 0; k < 2; ++k)
    quarters[k] = __builtin_shuffle(halves[2 * k], halves[2 * k + 1], Ints{0, 1, 8, 9, 4, 5, 12, 13}) +
                  __builtin_shuffle(halves[2 * k], halves[2 * k + 1], Ints{2, 3, 10, 11, 6, 7, 14, 15});
  return __builtin_shuffle(quarters[0], quarters[1], Ints{0, 2, 8, 10, 4, 6, 12, 14}) +
         __builtin_shuffle(quarters[0], quarters[1], Ints{1, 3, 9, 11, 5, 7, 13, 15});
}

// The backward's walk of one tile, back to front, from its state (T: final transmittances; behind: zeros; dL_tile:
// the image's gradient of the active channels), adding each Gaussian's gradients to `grads` [N, stride].
// sums [sum_vectors(A)] (vectors), totals [sum_vectors(A)] and f_active [A]: scratch for one Gaussian's per-lane
// sums, their totals and its active features (where their count is not compiled in).
//
// With the image's gradient dL, a Gaussian's alpha at a pixel gets dL . (f T - B / (1 - alpha)) (gsplat's form; B the
// colour of the contributors behind it, sum f_j alpha_j T_j): the walk keeps, per pixel, that colour already dotted
// with dL (one running sum instead of one per channel). Its exponent's gradient is o G d_alpha where alpha = o G is
// not clamped; the sums over the pixels of h = G d_alpha and of its moments dx h, dx^2 h, dy h, dx dy h, dy^2 h give,
// once the tile is walked, the opacity's, the mean's and the conic's gradients (power = -0.5 (a dx^2 + c dy^2) - b dx dy).
template <int kActive>  // the number of active channels, or 0: given by `active` at run time
void backward_tile(const Inputs& in, const TileRect& r, int start, int max_last, const std::vector<int64_t>& active,
                   float* __restrict T, const int* __restrict n_last, float* __restrict behind,
                   const float* __restrict dL_tile, float* __restrict grads, int64_t stride,
                   Floats* __restrict sums, float* __restrict totals, float* __restrict f_active) {
  const int64_t A = kActive > 0 ? kActive : static_cast<int64_t>(active.size());
  Floats local_lanes[kActive > 0 ? kActive : 1];  // with the count known, held in registers
  Floats* __restrict feature_lanes;  // per active channel: sum of w dL
  if constexpr (kActive > 0) feature_lanes = local_lanes; else feature_lanes = sums + 6;
  const int64_t sum_count = 6 + A, sum_count_padded = sum_vectors(A);
  TileEntry upcoming = max_last > 0 ? tile_entry(in, in.ids[start + max_last - 1], r) : TileEntry{};
  for (int e = start + max_last - 1; e >= start; --e) {  // back to front
    const int g = in.ids[e];
    if (e - kPrefetchAhead >= start) prefetch_record(in, in.ids[e - kPrefetchAhead]);
    const TileEntry now = upcoming;
    if (e > start) upcoming = tile_entry(in, in.ids[e - 1], r);
    const TileGaussian& tg = now.g;
    const int index = e - start;
    float* gg = grads + static_cast<int64_t>(g) * stride;
    // its row of sums is read and written once the tile is walked: fetched now, the load has long arrived
    __builtin_prefetch(gg, 1);
    __builtin_prefetch(gg + stride - 1, 1);
    bool touched = false;  // whether any lane of the box is hit
    // the lanes of the sums of h, dx h, dx^2 h, dy h, dx dy h, dy^2 h
    Floats s_h{}, s_xh{}, s_xxh{}, s_yh{}, s_xyh{}, s_yyh{};
    std::fill(feature_lanes, feature_lanes + A, Floats{});
    float f_local[kActive > 0 ? kActive : 1];  // the active features: with the count known, in registers
    for (int64_t i = 0; i < A; ++i) (kActive > 0 ? f_local[i] : f_active[i]) = tg.f[active[i]];
    const Ints columns[2] = {(kLaneIndices >= tg.xa) & (kLaneIndices < tg.xb),
                             (kLaneIndices + kLanes >= tg.xa) & (kLaneIndices + kLanes < tg.xb)};
    for (uint32_t steps = now.steps; steps != 0; steps &= steps - 1) {
      const int j = __builtin_ctz(steps);
      const auto [dy, x8, base, dx] = box_step(tg, r.x0, r.y0, j);
      const Floats power = gaussian_power(tg, dx, dy);
      const Floats G = fast_exp(min(power, Floats{}));
      const Floats alpha = min(Floats{} + kAlphaMax, tg.o * G);
      const Ints hit = columns[j & 1] & (index < load(n_last + base)) & (power <= 0.0f) & (alpha >= kAlphaMin);
      touched |= any_lane(hit);  // no branch: skipping a group that no lane hits was a mispredicted branch
      const Floats keep = 1.0f / (1.0f - alpha);
      const Floats t_behind = load(T + base);
      const Floats t = hit ? t_behind * keep : t_behind;  // transmittance in front of it
      store(T + base, t);
      const Floats w = hit ? alpha * t : 0.0f;
      Floats f_dot{};  // f . dL
      for (int64_t i = 0; i < A; ++i) {
        const Floats dLp = load(dL_tile + i * kTilePixels + base);
        f_dot += (kActive > 0 ? f_local[i] : f_active[i]) * dLp;
        feature_lanes[i] += w * dLp;
      }
      const Floats behind_now = load(behind + base);
      const Floats d_alpha = f_dot * t - behind_now * keep;  // lanes not hit are masked off below (`free`)
      store(behind + base, behind_now + w * f_dot);  // w = 0 where not hit: unchanged
      // a clamped alpha does not depend on o or the Gaussian
      const Floats h = hit & (tg.o * G <= kAlphaMax) ? G * d_alpha : 0.0f;
      const Floats xh = dx * h;
      s_h += h;
      s_xh += xh;
      s_xxh += dx * xh;
      s_yh += dy * h;
      s_xyh += dy * xh;
      s_yyh += (dy * dy) * h;
    }
    if (touched) {
      if constexpr (kActive > 0) std::copy(local_lanes, local_lanes + kActive, sums + 6);
      sums[0] = s_h, sums[1] = s_xh, sums[2] = s_xxh, sums[3] = s_yh, sums[4] = s_xyh, sums[5] = s_yyh;
      std::fill(sums + sum_count, sums + sum_count_padded, Floats{});
      for (int64_t k = 0; k < sum_count_padded; k += kLanes) store(totals + k, sum_lanes8(sums + k));
      const float o = tg.o, sh = totals[0], sxh = totals[1], sxxh = totals[2], syh = totals[3], sxyh = totals[4],
                  syyh = totals[5];
      gg[0] += -o * (tg.a * sxh + tg.b * syh);  // mean x: d power / d mx = -(a dx + b dy)
      gg[1] += -o * (tg.b * sxh + tg.c * syh);  // mean y
      gg[2] += -0.5f * o * sxxh;                 // conic a
      gg[3] += -o * sxyh;                        // conic b
      gg[4] += -0.5f * o * syyh;                 // conic c
      gg[5] += sh;                               // opacity: d alpha / d o = G
      for (int64_t i = 0; i < A; ++i) gg[6 + active[i]] += totals[6 + i];
    }
  }
}

}  // namespace

// Returns image [H, W, C], final transmittance [H, W], per pixel the number of list entries up to and
// including its last contributor [H, W] (int32), and the packed records: the backward needs the last three.
std::vector<torch::Tensor> composite_forward(torch::Tensor means2d, torch::Tensor conics, torch::Tensor opacities,
                                             torch::Tensor features, torch::Tensor extents,
                                             torch::Tensor tile_offsets, torch::Tensor gaussian_ids, int64_t width,
                                             int64_t height, int64_t tile) {
  const auto records = torch::empty({means2d.size(0), record_stride(features.size(1))}, features.options());
  const Inputs in = make_inputs(means2d, conics, opacities, features, extents, tile_offsets, gaussian_ids, width,
                                height, tile, records);
  const int64_t C = in.channels, N = means2d.size(0), tiles = in.tiles_x * in.tiles_y;
  // every pixel is written by its tile below: no fill needed
  auto image = torch::empty({height, width, C}, features.options());
  auto final_T = torch::empty({height, width}, features.options());
  auto last = torch::empty({height, width}, tile_offsets.options());
  float* image_ptr = image.data_ptr<float>();
  float* T_ptr = final_T.data_ptr<float>();
  int* last_ptr = last.data_ptr<int>();

#pragma omp parallel num_threads(at::get_num_threads())
  {
    // per-tile state, channel-major: acc[ch * kTilePixels + p]. T is the transmittance, negated once the pixel
    // has stopped (a live pixel's is above kTransmittanceMin > 0): one load and store instead of two arrays.
    alignas(64) float T[kTilePixels];
    alignas(64) int n_last[kTilePixels];
    std::vector<float> acc_storage(C * kTilePixels);
    float* __restrict acc = acc_storage.data();
    pack_records(in, N);
#pragma omp for schedule(dynamic, 1)
    for (int64_t k = 0; k < tiles; ++k) {
      const TileRect r = tile_rect(in, k);
      std::fill(T, T + kTilePixels, 1.0f);
      std::fill(n_last, n_last + kTilePixels, 0);
      std::fill(acc, acc + C * kTilePixels, 0.0f);
      int remaining = static_cast<int>((r.x1 - r.x0) * (r.y1 - r.y0));
      const int start = in.offsets[k], stop = in.offsets[k + 1];
      TileEntry upcoming = start < stop ? tile_entry(in, in.ids[start], r) : TileEntry{};
      for (int e = start; e < stop && remaining > 0; ++e) {
        if (e + kPrefetchAhead < stop) prefetch_record(in, in.ids[e + kPrefetchAhead]);
        const TileEntry now = upcoming;
        if (e + 1 < stop) upcoming = tile_entry(in, in.ids[e + 1], r);
        const TileGaussian& tg = now.g;
        const int entry = e - start + 1;
        for (uint32_t steps = now.steps; steps != 0; steps &= steps - 1) {
          const auto [dy, x8, base, dx] = box_step(tg, r.x0, r.y0, __builtin_ctz(steps));
          const Floats alpha = gaussian_alpha(tg, dx, dy);
          const Ints column = x8 + kLaneIndices;
          const Floats t = load(T + base);
          const Floats next = t * (1.0f - alpha);
          const Ints hit = (column >= tg.xa) & (column < tg.xb) & (alpha >= kAlphaMin) & (t > 0.0f);
          const Ints ends = hit & (next <= kTransmittanceMin);  // this pixel stops before this Gaussian
          const Ints adds = hit & ~ends;
          // whole vectors stored: a store of only some lanes compiles to a masked store, which is slow and
          // stalls the next Gaussian's loads of the same pixels (no store forwarding)
          const Floats w = adds ? alpha * t : 0.0f;
          store(T + base, adds ? next : ends ? -t : t);
          const Ints n_now = load(n_last + base);
          store(n_last + base, adds ? Ints{} + entry : n_now);  // entries only grow: the latest added is the last
          const int stopped = count_lanes(ends);
          remaining -= stopped;
          for (int64_t ch = 0; ch < C; ++ch) {
            float* out = acc + ch * kTilePixels + base;
            store(out, load(out) + w * tg.f[ch]);
          }
        }
      }
      for (int64_t y = r.y0; y < r.y1; ++y) {
        for (int64_t x = r.x0; x < r.x1; ++x) {
          const int p = static_cast<int>((y - r.y0) * kTile + (x - r.x0));
          const int64_t q = y * in.width + x;
          for (int64_t ch = 0; ch < C; ++ch) image_ptr[q * C + ch] = acc[ch * kTilePixels + p];
          T_ptr[q] = std::fabs(T[p]);
          last_ptr[q] = n_last[p];
        }
      }
    }
  }
  return {image, final_T, last, records};
}

// Gradients of a loss with respect to means2d [N, 2], conics [N, 3], opacities [N] and features [N, C],
// given its gradient with respect to the image [H, W, C].
std::vector<torch::Tensor> composite_backward(torch::Tensor means2d, torch::Tensor conics, torch::Tensor opacities,
                                              torch::Tensor features, torch::Tensor extents,
                                              torch::Tensor tile_offsets, torch::Tensor gaussian_ids,
                                              torch::Tensor final_T, torch::Tensor last, torch::Tensor records,
                                              torch::Tensor grad_image, int64_t width, int64_t height, int64_t tile) {
  const Inputs in = make_inputs(means2d, conics, opacities, features, extents, tile_offsets, gaussian_ids, width,
                                height, tile, records);
  grad_image = grad_image.contiguous();
  const int64_t C = in.channels, N = means2d.size(0), tiles = in.tiles_x * in.tiles_y;
  const int64_t stride = 6 + C;  // per Gaussian: mean (2), conic (3), opacity (1), features (C)
  const int threads = at::get_num_threads();
  // per-thread gradient sums, each zeroed by its own thread (no serial fill), then summed in parallel
  auto buffers = torch::empty({threads, N, stride}, features.options());
  float* buffer_ptr = buffers.data_ptr<float>();
  // the sums go straight into the four gradients (no copies out of one [N, 6 + C] table)
  auto v_means2d = torch::empty({N, 2}, features.options()), v_conics = torch::empty({N, 3}, features.options()),
       v_opacities = torch::empty({N}, features.options()), v_features = torch::empty({N, C}, features.options());
  float* const outputs[4] = {v_means2d.data_ptr<float>(), v_conics.data_ptr<float>(), v_opacities.data_ptr<float>(),
                             v_features.data_ptr<float>()};
  const int64_t output_width[4] = {2, 3, 1, C};
  const float* dL = grad_image.data_ptr<float>();
  const float* T_final = final_T.data_ptr<float>();
  const int* last_ptr = last.data_ptr<int>();
  // Channels whose gradient is zero everywhere (a loss that reads colour only leaves alpha and depth so) change no
  // gradient: the walk below skips them; their features' gradients stay 0.
  std::vector<int64_t> active;
  for (int64_t ch = 0; ch < C; ++ch) {
    bool any = false;
    for (int64_t q = 0; q < height * width && !any; ++q) any = dL[q * C + ch] != 0.0f;
    if (any) active.push_back(ch);
  }
  const int64_t A = static_cast<int64_t>(active.size());

#pragma omp parallel num_threads(threads)
  {
    const int team = omp_get_num_threads();  // may be fewer than asked (nested parallelism)
    float* grads = buffer_ptr + omp_get_thread_num() * N * stride;
    std::fill(grads, grads + N * stride, 0.0f);  // only this thread writes its sums until the tiles' loop ends
    // per-tile state; per-channel arrays are channel-major over the active channels ([i * kTilePixels + p] for
    // channel active[i])
    alignas(64) float T[kTilePixels];
    alignas(64) int n_last[kTilePixels];
    std::vector<float> storage((1 + A) * kTilePixels);
    float* __restrict behind = storage.data();       // colour of the contributors behind, dotted with dL
    float* __restrict dL_tile = behind + kTilePixels;  // the image's gradient
    std::vector<Floats> sums(sum_vectors(A));
    std::vector<float> totals(sum_vectors(A)), f_active(A);
// tiles dealt round-robin: balanced, and each thread's sums (hence the gradients) the same on every run
#pragma omp for schedule(static, 1)
    for (int64_t k = 0; k < tiles; ++k) {
      const TileRect r = tile_rect(in, k);
      int max_last = 0;
      std::fill(T, T + kTilePixels, 1.0f);
      std::fill(n_last, n_last + kTilePixels, 0);
      std::fill(storage.begin(), storage.end(), 0.0f);
      for (int64_t y = r.y0; y < r.y1; ++y) {
        for (int64_t x = r.x0; x < r.x1; ++x) {
          const int p = static_cast<int>((y - r.y0) * kTile + (x - r.x0));
          const int64_t q = y * in.width + x;
          T[p] = T_final[q];
          n_last[p] = last_ptr[q];
          max_last = std::max(max_last, n_last[p]);
          for (int64_t i = 0; i < A; ++i) dL_tile[i * kTilePixels + p] = dL[q * C + active[i]];
        }
      }
      const int start = in.offsets[k];
      // colour alone (3 channels) and colour over a background (its alpha too) get walks compiled for their count
      const auto walk = A == 3 ? backward_tile<3> : A == 4 ? backward_tile<4> : backward_tile<0>;
      walk(in, r, start, max_last, active, T, n_last, behind, dL_tile, grads, stride, sums.data(), totals.data(),
           f_active.data());
    }
#pragma omp for schedule(static)
    for (int64_t g = 0; g < N; ++g) {
      int64_t column = 0;
      for (int o = 0; o < 4; ++o) {
        for (int64_t j = 0; j < output_width[o]; ++j, ++column) {
          float sum = 0.0f;
          for (int t = 0; t < team; ++t) sum += buffer_ptr[(t * N + g) * stride + column];
          outputs[o][g * output_width[o] + j] = sum;
        }
      }
    }
  }
  return {v_means2d, v_conics, v_opacities, v_features};
}

// Tile binning (the rules of glimpse/render/binning.py): the visible Gaussians, sorted front to back by
// depth (ties by index: a stable LSD radix sort on the depths' bits), each appended to every tile its box
// (mean +- extents, pixels) overlaps, by counting sort, which keeps every tile's list in depth order.
// means2d [N, 2], extents [N, 2], depths [N] float32; visible [N] bool. Returns gaussian_ids [M] int32
// and tile_offsets [tiles + 1] int32.
//
// Threaded without changing a single entry: each thread takes one contiguous share of the Gaussians (of the
// index range, then of the sorted order) and counts into its own histograms; the scans give every thread the
// positions after those of the threads before it, so every scatter keeps the serial order.
std::vector<torch::Tensor> bin_gaussians(torch::Tensor means2d, torch::Tensor extents, torch::Tensor depths,
                                         torch::Tensor visible, int64_t width, int64_t height, int64_t tile) {
  TORCH_CHECK(means2d.dtype() == torch::kFloat32 && extents.dtype() == torch::kFloat32 &&
                  depths.dtype() == torch::kFloat32 && visible.dtype() == torch::kBool && means2d.is_contiguous() &&
                  extents.is_contiguous() && depths.is_contiguous() && visible.is_contiguous(),
              "bin_gaussians: contiguous float32 means2d, extents, depths and bool visible expected");
  const int64_t N = depths.numel(), tiles_x = (width + tile - 1) / tile, tiles_y = (height + tile - 1) / tile;
  const int64_t tiles = tiles_x * tiles_y;
  const float *m = means2d.data_ptr<float>(), *ex = extents.data_ptr<float>(), *z = depths.data_ptr<float>();
  const bool* vis = visible.data_ptr<bool>();
  constexpr int kRadixBits = 8, kBuckets = 1 << kRadixBits;
  const int threads = std::max(1, at::get_num_threads());
  std::vector<int64_t> before(threads + 1, 0);                    // per thread: visible Gaussians before its share
  std::vector<int64_t> histogram(static_cast<size_t>(threads) * kBuckets);  // [thread][bucket], then positions
  std::vector<int> tile_counts(static_cast<size_t>(threads) * tiles);     // [thread][tile], then cursors
  std::vector<uint32_t> keys, keys_tmp;
  std::vector<int> ids, ids_tmp, rects;
  int64_t V = 0;
  auto offsets = torch::zeros({tiles + 1}, torch::kInt32);
  int* off = offsets.data_ptr<int>();
  torch::Tensor entries;
  const float size = static_cast<float>(tile);
  auto clamp = [](int64_t value, int64_t hi) { return static_cast<int>(std::min(std::max<int64_t>(value, 0), hi)); };

#pragma omp parallel num_threads(threads)
  {
    const int t = omp_get_thread_num(), team = omp_get_num_threads();  // the team may be smaller than asked
    auto share = [&](int64_t n, int64_t& lo, int64_t& hi) { lo = n * t / team; hi = n * (t + 1) / team; };
    int64_t lo, hi;
    share(N, lo, hi);
    int64_t count = 0;
    for (int64_t n = lo; n < hi; ++n) count += vis[n];
    before[t + 1] = count;
#pragma omp barrier
#pragma omp single
    {
      for (int i = 0; i < team; ++i) before[i + 1] += before[i];
      V = before[team];
      keys.resize(V);
      keys_tmp.resize(V);
      ids.resize(V);
      ids_tmp.resize(V);
      rects.resize(4 * V);
    }
    // keys: the depth's bits made to order as the floats do (flip all bits of negatives, the sign of positives)
    for (int64_t n = lo, to = before[t]; n < hi; ++n) {
      if (!vis[n]) continue;
      uint32_t bits;
      std::memcpy(&bits, z + n, sizeof bits);
      keys[to] = bits & 0x80000000u ? ~bits : bits | 0x80000000u;
      ids[to++] = static_cast<int>(n);
    }
    share(V, lo, hi);
    int64_t* own = histogram.data() + static_cast<size_t>(t) * kBuckets;
    for (int shift = 0; shift < 32; shift += kRadixBits) {
#pragma omp barrier
      std::fill(own, own + kBuckets, 0);
      for (int64_t v = lo; v < hi; ++v) ++own[(keys[v] >> shift) & (kBuckets - 1)];
#pragma omp barrier
#pragma omp single
      {
        int64_t position = 0;  // bucket by bucket, thread by thread: a stable sort
        for (int b = 0; b < kBuckets; ++b)
          for (int i = 0; i < team; ++i) {
            const int64_t c = histogram[static_cast<size_t>(i) * kBuckets + b];
            histogram[static_cast<size_t>(i) * kBuckets + b] = position;
            position += c;
          }
      }
      for (int64_t v = lo; v < hi; ++v) {
        const int64_t to = own[(keys[v] >> shift) & (kBuckets - 1)]++;
        keys_tmp[to] = keys[v];
        ids_tmp[to] = ids[v];
      }
#pragma omp barrier
#pragma omp single
      {
        keys.swap(keys_tmp);
        ids.swap(ids_tmp);
      }
    }
    // each Gaussian's inclusive tile rectangle, computed as binning.py does (float32 division, floor, clamp)
    int* counts = tile_counts.data() + static_cast<size_t>(t) * tiles;
    std::fill(counts, counts + tiles, 0);
    for (int64_t v = lo; v < hi; ++v) {
      const int g = ids[v];
      int* r = rects.data() + 4 * v;
      r[0] = clamp(static_cast<int64_t>(std::floor((m[2 * g] - ex[2 * g]) / size)), tiles_x - 1);
      r[1] = clamp(static_cast<int64_t>(std::floor((m[2 * g + 1] - ex[2 * g + 1]) / size)), tiles_y - 1);
      r[2] = clamp(static_cast<int64_t>(std::floor((m[2 * g] + ex[2 * g]) / size)), tiles_x - 1);
      r[3] = clamp(static_cast<int64_t>(std::floor((m[2 * g + 1] + ex[2 * g + 1]) / size)), tiles_y - 1);
      for (int ty = r[1]; ty <= r[3]; ++ty)
        for (int tx = r[0]; tx <= r[2]; ++tx) ++counts[ty * tiles_x + tx];
    }
#pragma omp barrier
#pragma omp single
    {
      for (int64_t k = 0; k < tiles; ++k) {
        int position = off[k];
        for (int i = 0; i < team; ++i) {
          const int c = tile_counts[static_cast<size_t>(i) * tiles + k];
          tile_counts[static_cast<size_t>(i) * tiles + k] = position;
          position += c;
        }
        off[k + 1] = position;
      }
      entries = torch::empty({off[tiles]}, torch::kInt32);
    }
    int* out = entries.data_ptr<int>();
    for (int64_t v = lo; v < hi; ++v) {
      const int* r = rects.data() + 4 * v;
      for (int ty = r[1]; ty <= r[3]; ++ty)
        for (int tx = r[0]; tx <= r[2]; ++tx) out[counts[ty * tiles_x + tx]++] = ids[v];
    }
  }
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

// preprocess_cpu.cpp
torch::Tensor covariance_forward(torch::Tensor quats, torch::Tensor scales);
std::vector<torch::Tensor> covariance_backward(torch::Tensor quats, torch::Tensor scales, torch::Tensor v_cov);
torch::Tensor sh_forward(int64_t degree, torch::Tensor coeffs, torch::Tensor dirs);
std::vector<torch::Tensor> sh_backward(int64_t degree, torch::Tensor coeffs, torch::Tensor dirs, torch::Tensor v_rgb);

// ssim_cpu.cpp
std::vector<torch::Tensor> ssim_forward(torch::Tensor pred, torch::Tensor target, torch::Tensor taps, double c1,
                                        double c2);
torch::Tensor ssim_backward(torch::Tensor grad_map, torch::Tensor pred, torch::Tensor target, torch::Tensor moments,
                            torch::Tensor taps, double c1, double c2);

// pose_cpu.cpp
std::vector<torch::Tensor> pose_forward(torch::Tensor weights, torch::Tensor joint_transforms,
                                        torch::Tensor canonical_inverse, torch::Tensor means, torch::Tensor covariances,
                                        torch::Tensor sh, int64_t degree, torch::Tensor camera_centre);
torch::Tensor polar_rotations(torch::Tensor matrices);

// skinning_cpu.cpp
std::vector<torch::Tensor> skin_forward(torch::Tensor means, torch::Tensor covariances, torch::Tensor grid,
                                        torch::Tensor bounds, torch::Tensor posed, torch::Tensor canonical,
                                        torch::Tensor centre);
std::vector<torch::Tensor> skin_backward(torch::Tensor means, torch::Tensor covariances, torch::Tensor grid,
                                         torch::Tensor bounds, torch::Tensor posed, torch::Tensor canonical,
                                         torch::Tensor centre, torch::Tensor v_means, torch::Tensor v_cov,
                                         torch::Tensor v_dirs);

// mesh_raster_cpu.cpp
std::vector<torch::Tensor> mesh_raster_forward(torch::Tensor points, torch::Tensor faces, double fx, double fy,
                                               double cx, double cy, double near, int64_t width, int64_t height);

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  m.def("project_forward", &project_forward, "EWA projection, forward (CPU)");
  m.def("project_backward", &project_backward, "EWA projection, backward (CPU)");
  m.def("bin_gaussians", &bin_gaussians, "Tile binning: depth radix sort, then counting sort into tiles (CPU)");
  m.def("covariance_forward", &covariance_forward, "Covariances from quaternions and scales, forward (CPU)");
  m.def("covariance_backward", &covariance_backward, "Covariances from quaternions and scales, backward (CPU)");
  m.def("sh_forward", &sh_forward, "Colours from spherical harmonics, forward (CPU)");
  m.def("sh_backward", &sh_backward, "Colours from spherical harmonics, backward (CPU)");
  m.def("forward", &composite_forward, "Gaussian compositing, forward (CPU)");
  m.def("backward", &composite_backward, "Gaussian compositing, backward (CPU)");
  m.def("ssim_forward", &ssim_forward, "SSIM map and blurred moments, fused (CPU)");
  m.def("ssim_backward", &ssim_backward, "SSIM map's gradient with respect to the first image, fused (CPU)");
  m.def("pose_forward", &pose_forward, "Posing a frozen person's Gaussians, forward (CPU)");
  m.def("skin_forward", &skin_forward, "Posing canonical Gaussians for training, forward (CPU)");
  m.def("skin_backward", &skin_backward, "Posing canonical Gaussians for training, backward (CPU)");
  m.def("polar_rotations", &polar_rotations, "Closest rotations of 3x3 matrices, Newton's polar iteration (CPU)");
  m.def("mesh_raster", &mesh_raster_forward, "Nearest triangle and depth at each pixel centre, a z-buffer (CPU)");
}

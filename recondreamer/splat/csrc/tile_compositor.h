// Tile-based compositing of screen-space Gaussian splats on the CPU, forward and backward.
// Plain C++ (no torch types) so that it can be read, and compiled, on its own; the torch
// bindings live in rasterize_cpu.cpp.
//
// Input: packed splats (M, 10) = [mean_x, mean_y, conic_a, conic_b, conic_c, r, g, b, opacity,
// depth], in any order. The rules are those of recondreamer/splat/reference.py (the oracle):
//   sigma = 0.5 (a dx^2 + c dy^2) + b dx dy, (dx, dy) = pixel centre - mean;
//   alpha = min(0.99, opacity exp(-sigma)); skipped when sigma < 0 or alpha < 1/255;
//   front to back in depth order (stable); when T (1 - alpha) <= 1e-4 the splat is not
//   composited and the pixel is finished.
// Outputs: accumulated colour, accumulated depth, alpha = 1 - T_final.
//
// Binning is exact, not a truncation: a splat is listed in every 16x16 tile that its support
// box |dx| <= sqrt(2 ln(255 opacity) cov_xx) (same for y), plus a one-pixel margin, touches;
// outside that box alpha < 1/255, so nothing is lost. One stable radix sort by depth, then
// binning in that order, leaves every tile's list sorted front to back. Inside a tile a splat
// only visits the pixels of its support box, skips rows whose pixels are all finished, and skips
// a group of pixels once their sigmas show that none lies inside the ellipse
// sigma <= ln(255 opacity) (alpha < 1/255 outside it) or that all of them are finished.
//
// The pixel loops work on groups of pixels of one tile row at once with GCC/Clang vector
// extensions (one SIMD register: 4 floats with SSE2, 8 with AVX2), with lane masks instead of
// branches except for the skip of whole groups. The backward pass walks each tile's list back to
// front, recovering T by division, and accumulates gradients in one buffer per worker.

#pragma once

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <numeric>
#include <type_traits>
#include <vector>

#if defined(__SSE2__)
#include <immintrin.h>
#endif

namespace recondreamer_splat {

constexpr int kTile = 16;
constexpr int kTilePixels = kTile * kTile;
constexpr int kFields = 10;  // packed splat layout, see the header comment
constexpr double kAlphaMax = 0.99;
constexpr double kAlphaMin = 1.0 / 255.0;
constexpr double kTransmittanceMin = 1e-4;
constexpr double kSupportMargin = 1.0;
constexpr double kSkipMargin = 1e-3;  // in sigma: alpha is then below 1/255 by a factor e^-0.001

// Lanes<T>::V holds the pixels of one group: one SIMD register (32 bytes with AVX, else 16
// bytes); Lanes<T>::Mask is the integer vector that comparisons return (all bits set = true).
#if defined(__AVX__)
constexpr int kVectorBytes = 32;
#else
constexpr int kVectorBytes = 16;
#endif
template <typename T>
struct Lanes;
template <>
struct Lanes<float> {
  typedef float V __attribute__((vector_size(kVectorBytes)));
  typedef int32_t Mask __attribute__((vector_size(kVectorBytes)));
  static constexpr int kCount = kVectorBytes / 4;
};
template <>
struct Lanes<double> {
  typedef double V __attribute__((vector_size(kVectorBytes)));
  typedef int64_t Mask __attribute__((vector_size(kVectorBytes)));
  static constexpr int kCount = kVectorBytes / 8;
};

template <typename V, typename T>
inline V broadcast(T value) {
  return V{} + value;
}

template <typename V, typename T>
inline V load(const T* data) {
  V v;
  std::memcpy(&v, data, sizeof(V));
  return v;
}

template <typename V, typename T>
inline void store(T* data, const V& v) {
  std::memcpy(data, &v, sizeof(V));
}

template <typename V>
inline auto lane_sum(const V& v) {
  auto total = v[0];
  for (size_t i = 1; i < sizeof(V) / sizeof(v[0]); ++i) total += v[i];
  return total;
}

// Lane-wise min and max: one instruction on x86 (a ? b : c needs a compare and a blend). With a
// NaN in `a` they return `b`.
template <typename V>
inline V min_lanes(const V& a, const V& b) {
#if defined(__AVX__)
  if constexpr (sizeof(V) == 32 && sizeof(a[0]) == 4) return _mm256_min_ps(a, b);
  if constexpr (sizeof(V) == 32 && sizeof(a[0]) == 8) return _mm256_min_pd(a, b);
#elif defined(__SSE2__)
  if constexpr (sizeof(V) == 16 && sizeof(a[0]) == 4) return _mm_min_ps(a, b);
  if constexpr (sizeof(V) == 16 && sizeof(a[0]) == 8) return _mm_min_pd(a, b);
#endif
  return a < b ? a : b;
}

template <typename V>
inline V max_lanes(const V& a, const V& b) {
#if defined(__AVX__)
  if constexpr (sizeof(V) == 32 && sizeof(a[0]) == 4) return _mm256_max_ps(a, b);
  if constexpr (sizeof(V) == 32 && sizeof(a[0]) == 8) return _mm256_max_pd(a, b);
#elif defined(__SSE2__)
  if constexpr (sizeof(V) == 16 && sizeof(a[0]) == 4) return _mm_max_ps(a, b);
  if constexpr (sizeof(V) == 16 && sizeof(a[0]) == 8) return _mm_max_pd(a, b);
#endif
  return a > b ? a : b;
}

// True when no lane of the mask is set.
template <typename Mask>
inline bool no_lane(const Mask& mask) {
#if defined(__AVX__)
  if constexpr (sizeof(Mask) == 32) return _mm256_testz_si256(reinterpret_cast<__m256i>(mask), reinterpret_cast<__m256i>(mask));
#elif defined(__SSE4_1__)
  if constexpr (sizeof(Mask) == 16) return _mm_testz_si128(reinterpret_cast<__m128i>(mask), reinterpret_cast<__m128i>(mask));
#endif
  for (size_t i = 0; i < sizeof(Mask) / sizeof(mask[0]); ++i)
    if (mask[i]) return false;
  return true;
}

// Number of set lanes of the mask (a move-mask and a popcount on x86).
template <typename Mask>
inline int32_t set_lanes(const Mask& mask) {
#if defined(__AVX__)
  if constexpr (sizeof(Mask) == 32 && sizeof(mask[0]) == 4)
    return __builtin_popcount(_mm256_movemask_ps(reinterpret_cast<__m256>(mask)));
  if constexpr (sizeof(Mask) == 32 && sizeof(mask[0]) == 8)
    return __builtin_popcount(_mm256_movemask_pd(reinterpret_cast<__m256d>(mask)));
#elif defined(__SSE2__)
  if constexpr (sizeof(Mask) == 16 && sizeof(mask[0]) == 4)
    return __builtin_popcount(_mm_movemask_ps(reinterpret_cast<__m128>(mask)));
  if constexpr (sizeof(Mask) == 16 && sizeof(mask[0]) == 8)
    return __builtin_popcount(_mm_movemask_pd(reinterpret_cast<__m128d>(mask)));
#endif
  int32_t count = 0;
  for (size_t i = 0; i < sizeof(Mask) / sizeof(mask[0]); ++i) count += mask[i] != 0;
  return count;
}

// sigma = 0.5 (a dx^2 + c dy^2) + b dx dy on one pixel row, evaluated as
// (0.5 a dx + b dy) dx + 0.5 c dy^2: the row terms once, three operations per group of lanes.
// Forward and backward both use it, so they see bit-identical sigmas.
template <typename T>
struct RowSigma {
  T half_a, b_dy, half_c_dy2;
  RowSigma(T a, T b, T c, T dy) : half_a(T(0.5) * a), b_dy(b * dy), half_c_dy2(T(0.5) * c * dy * dy) {}
  template <typename V>
  V operator()(const V& dx) const {
    return (half_a * dx + b_dy) * dx + half_c_dy2;
  }
};

// exp(x) for float lanes to a few ulp, with no library call, so that the forward and backward
// passes compute bit-identical alphas on every machine.
inline Lanes<float>::V exp_lanes(Lanes<float>::V x) {
  using V = Lanes<float>::V;
  x = min_lanes(max_lanes(x, broadcast<V>(-87.0f)), broadcast<V>(88.0f));
  const float shifter = 12582912.0f;  // 1.5 * 2^23: adding and subtracting it rounds to an integer
  const V n = (x * 1.4426950408889634f + shifter) - shifter;
  const V r = (x - n * 0.693359375f) - n * -2.12194440e-4f;  // |r| <= ln(2)/2; ln 2 split hi+lo
  // Taylor series of e^r to degree 7, summed in Estrin's order: a chain of 6 dependent
  // operations instead of Horner's 14 (the forward pass was waiting on this latency).
  const V r2 = r * r;
  const V r4 = r2 * r2;
  const V low = (1.0f + r) + r2 * (0.5f + r * (1.0f / 6.0f));
  const V high = (1.0f / 24.0f + r * (1.0f / 120.0f)) + r2 * (1.0f / 720.0f + r * (1.0f / 5040.0f));
  const V p = low + r4 * high;
  const Lanes<float>::Mask bits = (__builtin_convertvector(n, Lanes<float>::Mask) + 127) << 23;  // 2^n
  return p * reinterpret_cast<const V&>(bits);
}

inline Lanes<double>::V exp_lanes(Lanes<double>::V x) {
  for (int i = 0; i < Lanes<double>::kCount; ++i) x[i] = std::exp(x[i]);
  return x;
}

// Stable order of the splats by depth: LSD radix sort on order-preserving integer keys.
template <typename scalar_t>
std::vector<int32_t> depth_order(const scalar_t* packed, int64_t count) {
  using key_t = std::conditional_t<sizeof(scalar_t) == 4, uint32_t, uint64_t>;
  constexpr key_t sign = key_t(1) << (8 * sizeof(key_t) - 1);
  std::vector<key_t> keys(count), keys_tmp(count);
  std::vector<int32_t> order(count), order_tmp(count);
  for (int64_t i = 0; i < count; ++i) {
    key_t bits;
    std::memcpy(&bits, &packed[i * kFields + 9], sizeof(bits));
    keys[i] = (bits & sign) ? ~bits : (bits | sign);
    order[i] = static_cast<int32_t>(i);
  }
  for (int shift = 0; shift < static_cast<int>(8 * sizeof(key_t)); shift += 8) {
    int64_t histogram[257] = {0};
    for (int64_t i = 0; i < count; ++i) ++histogram[((keys[i] >> shift) & 0xff) + 1];
    if (std::any_of(histogram + 1, histogram + 257, [&](int64_t h) { return h == count; })) continue;
    for (int d = 0; d < 256; ++d) histogram[d + 1] += histogram[d];
    for (int64_t i = 0; i < count; ++i) {
      const int64_t slot = histogram[(keys[i] >> shift) & 0xff]++;
      keys_tmp[slot] = keys[i];
      order_tmp[slot] = order[i];
    }
    keys.swap(keys_tmp);
    order.swap(order_tmp);
  }
  return order;
}

// Inclusive pixel box of a splat's support, empty (x0 > x1) when it never reaches alpha 1/255.
// max_sigma: ln(255 opacity) plus kSkipMargin; where sigma exceeds it, alpha < 1/255 even with
// the float exp's error, so a group of pixels whose sigmas all exceed it can be skipped.
struct PixelBox {
  int32_t x0, x1, y0, y1;
  float max_sigma;
  bool empty() const { return x0 > x1 || y0 > y1; }
};

template <typename scalar_t>
PixelBox support_box(const scalar_t* s, int64_t width, int64_t height) {
  const PixelBox nothing{1, 0, 1, 0, 0.0f};
  const double a = s[2], b = s[3], c = s[4], opacity = s[8];
  const double det = a * c - b * b;
  const double level = std::log(std::max(opacity * 255.0, 1e-30));
  if (!(level >= 0.0) || !(det > 0.0)) return nothing;
  const double reach = std::sqrt(2.0 * level);
  const double ext_x = reach * std::sqrt(c / det) + kSupportMargin;
  const double ext_y = reach * std::sqrt(a / det) + kSupportMargin;
  // Pixel x has its centre at x + 0.5: keep |x + 0.5 - mean_x| <= ext_x.
  const double fx0 = std::ceil(s[0] - ext_x - 0.5), fx1 = std::floor(s[0] + ext_x - 0.5);
  const double fy0 = std::ceil(s[1] - ext_y - 0.5), fy1 = std::floor(s[1] + ext_y - 0.5);
  if (fx1 < 0 || fy1 < 0 || fx0 > width - 1 || fy0 > height - 1) return nothing;
  return {static_cast<int32_t>(std::max(fx0, 0.0)), static_cast<int32_t>(std::min(fx1, width - 1.0)),
          static_cast<int32_t>(std::max(fy0, 0.0)), static_cast<int32_t>(std::min(fy1, height - 1.0)),
          static_cast<float>(level + kSkipMargin)};
}

// Support boxes of all splats; parallel_for(begin, end, grain, body(begin, end)).
template <typename scalar_t, typename ParallelFor>
std::vector<PixelBox> support_boxes(const scalar_t* packed, int64_t count, int64_t width, int64_t height,
                                    const ParallelFor& parallel_for) {
  std::vector<PixelBox> boxes(count);
  parallel_for(0, count, 2048, [&](int64_t begin, int64_t end) {
    for (int64_t i = begin; i < end; ++i) boxes[i] = support_box(packed + i * kFields, width, height);
  });
  return boxes;
}

// Per-tile lists: tile t owns ids[offsets[t] .. offsets[t+1]), splat indices front to back.
// boxes: support boxes of all splats, kept for the backward pass.
struct Binning {
  std::vector<int32_t> offsets;
  std::vector<int32_t> ids;
  std::vector<PixelBox> boxes;
};

// Calls visit(tile) for every tile that the box touches.
template <typename Visit>
inline void for_each_tile_of(const PixelBox& box, int64_t tiles_x, const Visit& visit) {
  for (int32_t ty = box.y0 / kTile; ty <= box.y1 / kTile; ++ty)
    for (int32_t tx = box.x0 / kTile; tx <= box.x1 / kTile; ++tx) visit(ty * tiles_x + tx);
}

// Binning in parallel: the depth order is cut into one contiguous chunk per worker; each worker
// counts its chunk's entries per tile, and then writes them behind those of the chunks in front,
// so every tile list stays in depth order (stable) whatever the number of workers.
template <typename scalar_t, typename ParallelFor>
Binning bin_splats(const scalar_t* packed, int64_t count, int64_t width, int64_t height,
                   const std::vector<PixelBox>& boxes, int64_t workers, const ParallelFor& parallel_for) {
  const int64_t tiles_x = (width + kTile - 1) / kTile, tiles_y = (height + kTile - 1) / kTile;
  const int64_t num_tiles = tiles_x * tiles_y;
  const std::vector<int32_t> order = depth_order(packed, count);
  std::vector<PixelBox> sorted_boxes(count);  // boxes in depth order: the passes below read them in sequence
  parallel_for(0, count, 4096, [&](int64_t begin, int64_t end) {
    for (int64_t k = begin; k < end; ++k) sorted_boxes[k] = boxes[order[k]];
  });
  const int64_t chunks = std::max<int64_t>(1, std::min<int64_t>(workers, count / 4096 + 1));
  const int64_t chunk_size = (count + chunks - 1) / chunks;
  std::vector<int32_t> cursors(chunks * num_tiles, 0);  // per chunk and tile: count, then write position
  parallel_for(0, chunks, 1, [&](int64_t begin, int64_t end) {
    for (int64_t chunk = begin; chunk < end; ++chunk) {
      int32_t* counts = cursors.data() + chunk * num_tiles;
      for (int64_t k = chunk * chunk_size; k < std::min(count, (chunk + 1) * chunk_size); ++k)
        if (!sorted_boxes[k].empty()) for_each_tile_of(sorted_boxes[k], tiles_x, [&](int64_t t) { ++counts[t]; });
    }
  });
  Binning binning;
  binning.offsets.assign(num_tiles + 1, 0);
  for (int64_t t = 0; t < num_tiles; ++t) {
    int32_t position = binning.offsets[t];
    for (int64_t chunk = 0; chunk < chunks; ++chunk) {
      const int32_t entries = cursors[chunk * num_tiles + t];
      cursors[chunk * num_tiles + t] = position;
      position += entries;
    }
    binning.offsets[t + 1] = position;
  }
  binning.ids.resize(binning.offsets.back());
  parallel_for(0, chunks, 1, [&](int64_t begin, int64_t end) {
    for (int64_t chunk = begin; chunk < end; ++chunk) {
      int32_t* cursor = cursors.data() + chunk * num_tiles;
      for (int64_t k = chunk * chunk_size; k < std::min(count, (chunk + 1) * chunk_size); ++k)
        if (!sorted_boxes[k].empty())
          for_each_tile_of(sorted_boxes[k], tiles_x, [&](int64_t t) { binning.ids[cursor[t]++] = order[k]; });
    }
  });
  return binning;
}

// The tile loops visit splats in depth order, scattered over arrays far larger than the cache:
// without a prefetch, every splat of every tile starts with a cache miss (measured: a quarter of
// the forward time went to the load of its first field).
constexpr int32_t kPrefetchAhead = 2;

template <typename scalar_t>
inline void prefetch_splat(const scalar_t* packed, const std::vector<PixelBox>& boxes, int32_t id) {
  const scalar_t* s = packed + static_cast<int64_t>(id) * kFields;
  __builtin_prefetch(s);
  __builtin_prefetch(s + kFields - 1);  // the record may straddle two cache lines
  __builtin_prefetch(&boxes[id]);
}

// Runs body(tile, worker) for every tile on `workers` workers that take tiles from a shared
// counter, longest lists first, so that uneven tiles do not leave a core idle.
template <typename ParallelFor, typename Body>
void for_each_tile(const std::vector<int32_t>& offsets, int64_t workers, const ParallelFor& parallel_for,
                   const Body& body) {
  const int64_t num_tiles = static_cast<int64_t>(offsets.size()) - 1;
  std::vector<int32_t> schedule(num_tiles);
  std::iota(schedule.begin(), schedule.end(), 0);
  std::stable_sort(schedule.begin(), schedule.end(), [&](int32_t p, int32_t q) {
    return offsets[p + 1] - offsets[p] > offsets[q + 1] - offsets[q];
  });
  std::atomic<int64_t> next{0};
  parallel_for(0, workers, 1, [&](int64_t begin, int64_t end) {
    for (int64_t worker = begin; worker < end; ++worker)
      for (int64_t k = next++; k < num_tiles; k = next++) body(schedule[k], worker);
  });
}

// Pixel rectangle [x0, x1] x [y0, y1] (inclusive) of one tile, clipped to the image.
struct TileRect {
  int32_t x0, x1, y0, y1;
  TileRect(int64_t tile, int64_t width, int64_t height) {
    const int64_t tiles_x = (width + kTile - 1) / kTile;
    x0 = static_cast<int32_t>((tile % tiles_x) * kTile);
    y0 = static_cast<int32_t>((tile / tiles_x) * kTile);
    x1 = static_cast<int32_t>(std::min<int64_t>(x0 + kTile, width) - 1);
    y1 = static_cast<int32_t>(std::min<int64_t>(y0 + kTile, height) - 1);
  }
};

// Image outputs (H,W,...) row-major.
template <typename scalar_t>
struct ForwardOutputs {
  scalar_t* rgb;            // (H,W,3) accumulated colour
  scalar_t* depth;          // (H,W) accumulated depth
  scalar_t* alpha;          // (H,W) 1 - T_final
  scalar_t* transmittance;  // (H,W) T_final
  int32_t* last;            // (H,W) list position of the last composited splat, -1 if none
};

template <typename scalar_t>
void forward_tile(const scalar_t* packed, const Binning& binning, const std::vector<PixelBox>& boxes,
                  int64_t tile, int64_t width, int64_t height, const ForwardOutputs<scalar_t>& out) {
  using T = scalar_t;
  using V = typename Lanes<T>::V;
  using Mask = typename Lanes<T>::Mask;
  constexpr int kLanes = Lanes<T>::kCount;
  const TileRect rect(tile, width, height);
  // Per-pixel state over the tile, row stride kTile; pixels outside the image stay inactive.
  alignas(64) T trans[kTilePixels], acc_r[kTilePixels], acc_g[kTilePixels], acc_b[kTilePixels];
  alignas(64) T acc_z[kTilePixels], active[kTilePixels], last[kTilePixels];
  int32_t active_in_row[kTile] = {0};
  for (int p = 0; p < kTilePixels; ++p) {
    trans[p] = 1;
    acc_r[p] = acc_g[p] = acc_b[p] = acc_z[p] = active[p] = 0;
    last[p] = -1;  // list position held as a float: exact, and comparable in lanes
  }
  for (int32_t y = rect.y0; y <= rect.y1; ++y) {
    active_in_row[y - rect.y0] = rect.x1 - rect.x0 + 1;
    for (int32_t x = rect.x0; x <= rect.x1; ++x) active[(y - rect.y0) * kTile + (x - rect.x0)] = 1;
  }
  int32_t remaining = (rect.x1 - rect.x0 + 1) * (rect.y1 - rect.y0 + 1);
  V lane_centre;  // pixel-centre offset of each lane in a group
  for (int i = 0; i < kLanes; ++i) lane_centre[i] = T(i) + T(0.5);

  const T alpha_max = T(kAlphaMax), alpha_min = T(kAlphaMin), t_min = T(kTransmittanceMin);
  const int32_t begin = binning.offsets[tile], end = binning.offsets[tile + 1];
  for (int32_t k = begin; k < end && remaining > 0; ++k) {
    const int32_t id = binning.ids[k];
    if (k + kPrefetchAhead < end) prefetch_splat(packed, boxes, binning.ids[k + kPrefetchAhead]);
    const T* s = packed + static_cast<int64_t>(id) * kFields;
    const T mx = s[0], my = s[1], a = s[2], b = s[3], c = s[4];
    const T cr = s[5], cg = s[6], cb = s[7], opacity = s[8], z = s[9];
    const PixelBox& box = boxes[id];
    const T max_sigma = T(box.max_sigma);
    // Tile-local columns, the first one rounded down to a whole group.
    const int32_t gx0 = (std::max(box.x0, rect.x0) - rect.x0) & ~(kLanes - 1);
    const int32_t gx1 = std::min(box.x1, rect.x1) - rect.x0;
    const int32_t y0 = std::max(box.y0, rect.y0), y1 = std::min(box.y1, rect.y1);
    const V position = broadcast<V>(T(k - begin));
    for (int32_t y = y0; y <= y1; ++y) {
      if (active_in_row[y - rect.y0] == 0) continue;
      const T dy = T(y) + T(0.5) - my;
      const RowSigma<T> row_sigma(a, b, c, dy);
      const int32_t row = (y - rect.y0) * kTile;
      int32_t stopped = 0;  // pixels that finished on this row
      for (int32_t gx = gx0; gx <= gx1; gx += kLanes) {
        const int32_t p = row + gx;
        const V dx = (T(rect.x0 + gx) + lane_centre) - mx;
        const V sigma = row_sigma(dx);
        const V was_active = load<V>(active + p);
        const Mask reachable = (sigma <= max_sigma) & (was_active != T(0));
        // Outside the support ellipse (a third of the groups of the box) or finished: no change.
        if (no_lane(reachable)) continue;
        const V al = min_lanes(opacity * exp_lanes(-sigma), broadcast<V>(alpha_max));
        const V t = load<V>(trans + p);
        Mask use = (sigma >= T(0)) & (al >= alpha_min) & reachable;
        const V next = t * (T(1) - al);
        const Mask stop = use & (next <= t_min);
        use &= ~stop;
        const V w = use ? al * t : V{};
        store(acc_r + p, load<V>(acc_r + p) + w * cr);
        store(acc_g + p, load<V>(acc_g + p) + w * cg);
        store(acc_b + p, load<V>(acc_b + p) + w * cb);
        store(acc_z + p, load<V>(acc_z + p) + w * z);
        store(trans + p, use ? next : t);
        store(active + p, stop ? V{} : was_active);
        store(last + p, use ? position : load<V>(last + p));
        stopped += set_lanes(stop);
      }
      active_in_row[y - rect.y0] -= stopped;
      remaining -= stopped;
    }
  }
  for (int32_t y = rect.y0; y <= rect.y1; ++y) {
    for (int32_t x = rect.x0; x <= rect.x1; ++x) {
      const int32_t p = (y - rect.y0) * kTile + (x - rect.x0);
      const int64_t q = static_cast<int64_t>(y) * width + x;
      out.rgb[3 * q] = acc_r[p];
      out.rgb[3 * q + 1] = acc_g[p];
      out.rgb[3 * q + 2] = acc_b[p];
      out.depth[q] = acc_z[p];
      out.alpha[q] = T(1) - trans[p];
      out.transmittance[q] = trans[p];
      out.last[q] = static_cast<int32_t>(last[p]);
    }
  }
}

// Forward state and incoming image gradients, (H,W,...) row-major.
template <typename scalar_t>
struct BackwardInputs {
  const scalar_t* transmittance;  // (H,W) T_final from the forward pass
  const int32_t* last;            // (H,W) from the forward pass
  const scalar_t* grad_rgb;       // (H,W,3)
  const scalar_t* grad_depth;     // (H,W)
  const scalar_t* grad_alpha;     // (H,W)
};

template <typename scalar_t>
void backward_tile(const scalar_t* packed, const Binning& binning, const std::vector<PixelBox>& boxes,
                   int64_t tile, int64_t width, int64_t height, const BackwardInputs<scalar_t>& in,
                   scalar_t* grad_packed) {
  using T = scalar_t;
  using V = typename Lanes<T>::V;
  using Mask = typename Lanes<T>::Mask;
  constexpr int kLanes = Lanes<T>::kCount;
  const TileRect rect(tile, width, height);
  alignas(64) T trans[kTilePixels], final_trans[kTilePixels], last[kTilePixels];
  alignas(64) T g_r[kTilePixels], g_g[kTilePixels], g_b[kTilePixels], g_z[kTilePixels], g_a[kTilePixels];
  alignas(64) T behind_r[kTilePixels], behind_g[kTilePixels], behind_b[kTilePixels], behind_z[kTilePixels];
  int32_t row_last[kTile];  // largest `last` in each tile row
  for (int p = 0; p < kTilePixels; ++p) {
    trans[p] = final_trans[p] = 1;
    g_r[p] = g_g[p] = g_b[p] = g_z[p] = g_a[p] = 0;
    behind_r[p] = behind_g[p] = behind_b[p] = behind_z[p] = 0;
    last[p] = -1;
  }
  int32_t max_last = -1;
  for (int32_t y = rect.y0; y <= rect.y1; ++y) {
    row_last[y - rect.y0] = -1;
    for (int32_t x = rect.x0; x <= rect.x1; ++x) {
      const int32_t p = (y - rect.y0) * kTile + (x - rect.x0);
      const int64_t q = static_cast<int64_t>(y) * width + x;
      trans[p] = final_trans[p] = in.transmittance[q];
      last[p] = T(in.last[q]);
      row_last[y - rect.y0] = std::max(row_last[y - rect.y0], in.last[q]);
      g_r[p] = in.grad_rgb[3 * q];
      g_g[p] = in.grad_rgb[3 * q + 1];
      g_b[p] = in.grad_rgb[3 * q + 2];
      g_z[p] = in.grad_depth[q];
      g_a[p] = in.grad_alpha[q];
    }
    max_last = std::max(max_last, row_last[y - rect.y0]);
  }
  V lane_centre;
  for (int i = 0; i < kLanes; ++i) lane_centre[i] = T(i) + T(0.5);

  const T alpha_max = T(kAlphaMax), alpha_min = T(kAlphaMin);
  const int32_t begin = binning.offsets[tile];
  for (int32_t position = max_last; position >= 0; --position) {
    const int32_t id = binning.ids[begin + position];
    if (position >= kPrefetchAhead) {
      const int32_t ahead = binning.ids[begin + position - kPrefetchAhead];
      prefetch_splat(packed, boxes, ahead);
      __builtin_prefetch(grad_packed + static_cast<int64_t>(ahead) * kFields, 1);
    }
    const T* s = packed + static_cast<int64_t>(id) * kFields;
    const T mx = s[0], my = s[1], a = s[2], b = s[3], c = s[4];
    const T cr = s[5], cg = s[6], cb = s[7], opacity = s[8], z = s[9];
    const PixelBox& box = boxes[id];
    const T max_sigma = T(box.max_sigma);
    const int32_t gx0 = (std::max(box.x0, rect.x0) - rect.x0) & ~(kLanes - 1);
    const int32_t gx1 = std::min(box.x1, rect.x1) - rect.x0;
    const int32_t y0 = std::max(box.y0, rect.y0), y1 = std::min(box.y1, rect.y1);
    const V position_lanes = broadcast<V>(T(position));
    V d_mx{}, d_my{}, d_a{}, d_b{}, d_c{}, d_r{}, d_g{}, d_bl{}, d_op{}, d_z{};
    for (int32_t y = y0; y <= y1; ++y) {
      if (row_last[y - rect.y0] < position) continue;
      const T dy = T(y) + T(0.5) - my;
      const RowSigma<T> row_sigma(a, b, c, dy);
      const int32_t row = (y - rect.y0) * kTile;
      // dy is constant on the row: the shape gradients need only sum(g), sum(g dx), sum(g dx^2)
      // of g = dL/dsigma over the row, combined with dy once per row below.
      V sum_g{}, sum_g_dx{}, sum_g_dx2{};
      for (int32_t gx = gx0; gx <= gx1; gx += kLanes) {
        const int32_t p = row + gx;
        const V dx = (T(rect.x0 + gx) + lane_centre) - mx;
        const V sigma = row_sigma(dx);
        const Mask reachable = (sigma <= max_sigma) & (position_lanes <= load<V>(last + p));
        if (no_lane(reachable)) continue;  // outside the support ellipse, or behind the pixels' last splat
        const V gauss = exp_lanes(-sigma);
        const V raw = opacity * gauss;
        const V al = min_lanes(raw, broadcast<V>(alpha_max));
        const Mask used = (sigma >= T(0)) & (al >= alpha_min) & reachable;
        const V al_used = used ? al : V{};  // 0 where the splat was not composited: no change below
        const V inv_one_minus = T(1) / (T(1) - al);
        const V t_after = load<V>(trans + p);
        const V t_before = t_after * inv_one_minus;  // transmittance in front of this splat
        const V w = al_used * t_before;
        const V gr = load<V>(g_r + p), gg = load<V>(g_g + p), gb = load<V>(g_b + p), gz = load<V>(g_z + p);
        d_r += w * gr;
        d_g += w * gg;
        d_bl += w * gb;
        d_z += w * gz;
        // d(outputs)/d(alpha): colour and depth through the splats behind, alpha through T_final.
        // Behind-colour update: behind' = alpha c + (1 - alpha) behind = behind + alpha (c - behind).
        const V br = load<V>(behind_r + p), bg = load<V>(behind_g + p);
        const V bb = load<V>(behind_b + p), bz = load<V>(behind_z + p);
        const V diff_r = cr - br, diff_g = cg - bg, diff_b = cb - bb, diff_z = z - bz;
        const V d_alpha = t_before * (diff_r * gr + diff_g * gg + diff_b * gb + diff_z * gz) +
                          load<V>(final_trans + p) * inv_one_minus * load<V>(g_a + p);
        store(behind_r + p, br + al_used * diff_r);
        store(behind_g + p, bg + al_used * diff_g);
        store(behind_b + p, bb + al_used * diff_b);
        store(behind_z + p, bz + al_used * diff_z);
        store(trans + p, used ? t_before : t_after);
        // The clamp at alpha_max cuts the gradient to opacity and sigma (as torch.clamp does).
        const V through = (used & (raw <= alpha_max)) ? d_alpha : V{};
        const V d_sigma = -al * through;
        d_op += gauss * through;
        const V g_dx = d_sigma * dx;
        sum_g += d_sigma;
        sum_g_dx += g_dx;
        sum_g_dx2 += g_dx * dx;
      }
      // sigma = 0.5 a dx^2 + b dx dy + 0.5 c dy^2 with dx = px - mean_x, dy = py - mean_y.
      d_a += T(0.5) * sum_g_dx2;
      d_b += dy * sum_g_dx;
      d_c += (T(0.5) * dy * dy) * sum_g;
      d_mx -= a * sum_g_dx + (b * dy) * sum_g;
      d_my -= b * sum_g_dx + (c * dy) * sum_g;
    }
    T* g = grad_packed + static_cast<int64_t>(id) * kFields;
    g[0] += lane_sum(d_mx);
    g[1] += lane_sum(d_my);
    g[2] += lane_sum(d_a);
    g[3] += lane_sum(d_b);
    g[4] += lane_sum(d_c);
    g[5] += lane_sum(d_r);
    g[6] += lane_sum(d_g);
    g[7] += lane_sum(d_bl);
    g[8] += lane_sum(d_op);
    g[9] += lane_sum(d_z);
  }
}

// Forward pass over all tiles; returns the binning that the backward pass needs.
template <typename scalar_t, typename ParallelFor>
Binning composite_forward(const scalar_t* packed, int64_t count, int64_t width, int64_t height, int64_t workers,
                          const ParallelFor& parallel_for, const ForwardOutputs<scalar_t>& out) {
  std::vector<PixelBox> boxes = support_boxes(packed, count, width, height, parallel_for);
  Binning binning = bin_splats(packed, count, width, height, boxes, workers, parallel_for);
  binning.boxes = std::move(boxes);
  for_each_tile(binning.offsets, workers, parallel_for, [&](int64_t tile, int64_t) {
    forward_tile(packed, binning, binning.boxes, tile, width, height, out);
  });
  return binning;
}

// Backward pass: grad_buffers holds `workers` zeroed (M,10) buffers, to be summed by the caller.
template <typename scalar_t, typename ParallelFor>
void composite_backward(const scalar_t* packed, int64_t count, int64_t width, int64_t height, int64_t workers,
                        const ParallelFor& parallel_for, const Binning& binning,
                        const BackwardInputs<scalar_t>& in, scalar_t* grad_buffers) {
  for_each_tile(binning.offsets, workers, parallel_for, [&](int64_t tile, int64_t worker) {
    backward_tile(packed, binning, binning.boxes, tile, width, height, in, grad_buffers + worker * count * kFields);
  });
}

}  // namespace recondreamer_splat

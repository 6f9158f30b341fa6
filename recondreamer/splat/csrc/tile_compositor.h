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
// outside that box alpha < 1/255, so nothing is lost. One stable radix sort by depth of the
// splats with a non-empty box, then binning in that order, leaves every tile's list sorted front
// to back.
//
// The pixel loops work on groups of pixels (one SIMD register: 2x4 pixels with AVX, else one
// row of 4 floats or 2-4 doubles) with GCC/Clang vector extensions and lane masks. For each splat
// of a tile, the forward pass first lists the groups of its support box that have a lane inside
// the ellipse sigma <= ln(255 opacity) (alpha < 1/255 outside it) and not yet finished, using
// sigma alone, and then composites the listed groups in a loop without data-dependent branches,
// whose iterations (different pixels) the CPU overlaps. It records the listed groups of every
// (splat, tile) entry as a bit mask. The backward pass walks each tile's list back to front from
// the last splat any pixel used, visits only the groups in the entry's mask, recovers T by
// division, and writes each entry's gradient contribution to its own row; a second pass sums
// every splat's rows in one fixed order (the tiles' schedule), so that the gradients are
// bit-identical for any number of threads and any order in which the threads take the tiles.

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

// Lane sums of eight vectors: sums[i] = lane_sum(v[i]). For 8-float AVX vectors, three rounds of
// horizontal adds instead of eight separate reductions (the backward pass reduces its gradient
// accumulators once per splat and tile).
template <typename V, typename T>
inline void lane_sums(const V (&v)[8], T* sums) {
#if defined(__AVX__)
  if constexpr (sizeof(V) == 32 && sizeof(T) == 4) {
    const __m256 s01 = _mm256_hadd_ps(v[0], v[1]), s23 = _mm256_hadd_ps(v[2], v[3]);
    const __m256 s45 = _mm256_hadd_ps(v[4], v[5]), s67 = _mm256_hadd_ps(v[6], v[7]);
    // Lanes 0-3: quarter sums of v[0..3] (low 128 bits) and v[4..7]; lanes 4-7: the other halves.
    const __m256 s0123 = _mm256_hadd_ps(s01, s23), s4567 = _mm256_hadd_ps(s45, s67);
    _mm256_storeu_ps(sums, _mm256_add_ps(_mm256_permute2f128_ps(s0123, s4567, 0x20),
                                         _mm256_permute2f128_ps(s0123, s4567, 0x31)));
    return;
  }
#endif
  for (int i = 0; i < 8; ++i) sums[i] = lane_sum(v[i]);
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

// a * b + c with one rounding (an FMA instruction) where the build targets FMA (AVX2 and
// AVX-512 builds, see cpu_kernel.py), else two. Forward and backward run the same code on the
// same values, so they still see bit-identical sigmas and alphas.
template <typename V>
inline V mul_add(const V& a, const V& b, const V& c) {
#if defined(__FMA__)
  if constexpr (sizeof(V) == 32 && sizeof(a[0]) == 4) return _mm256_fmadd_ps(a, b, c);
  if constexpr (sizeof(V) == 32 && sizeof(a[0]) == 8) return _mm256_fmadd_pd(a, b, c);
  if constexpr (sizeof(V) == 16 && sizeof(a[0]) == 4) return _mm_fmadd_ps(a, b, c);
  if constexpr (sizeof(V) == 16 && sizeof(a[0]) == 8) return _mm_fmadd_pd(a, b, c);
#endif
  return a * b + c;
}

template <typename V, typename T, typename = std::enable_if_t<std::is_arithmetic_v<T>>>
inline V mul_add(const V& a, T b, const V& c) {
  return mul_add(a, broadcast<V>(b), c);
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

// The pixels of a tile are processed in groups of one SIMD register: kRows rows by kCols
// columns (2 rows of 4 for 8 lanes; one row otherwise). A splat covers a roughly round patch,
// which 2 rows of 4 fit with fewer wasted lanes than one row of 8 (measured: 17 % fewer groups
// reach a splat's support in the benchmark's scene). The per-tile pixel arrays are stored group
// by group (slot = group * lanes + lane), so that a group is one aligned load.
template <typename T>
struct Groups {
  using V = typename Lanes<T>::V;
  static constexpr int kLanes = Lanes<T>::kCount;
  static constexpr int kRows = kLanes >= 8 ? 2 : 1;
  static constexpr int kCols = kLanes / kRows;
  static constexpr int kAcross = kTile / kCols;  // groups per band of kRows tile rows
  static constexpr int kBands = kTile / kRows;
  static constexpr int kCount = kAcross * kBands;  // groups per tile
  // Groups per bit of a 64-bit group mask: 1, except 2 for the 128 two-lane groups of SSE2 doubles.
  static constexpr int kPerBit = kCount > 64 ? kCount / 64 : 1;
  static_assert(kTile % kCols == 0 && kTile % kRows == 0, "groups must tile a tile");
  static_assert(kCount <= 64 * kPerBit, "a 64-bit mask must cover the groups of a tile");

  // Slot of the tile-local pixel (x, y) in a per-tile array.
  static int32_t slot(int32_t x, int32_t y) {
    return ((y / kRows) * kAcross + x / kCols) * kLanes + (y % kRows) * kCols + x % kCols;
  }
  // Pixel-centre offsets of the lanes from the group's top-left pixel corner.
  static V lane_x() {
    V v;
    for (int i = 0; i < kLanes; ++i) v[i] = T(i % kCols) + T(0.5);
    return v;
  }
  static V lane_y() {
    V v;
    for (int i = 0; i < kLanes; ++i) v[i] = T(i / kCols) + T(0.5);
    return v;
  }
};

// sigma = 0.5 (a dx^2 + c dy^2) + b dx dy on one band of groups (dy fixed per lane), evaluated as
// (0.5 a dx + b dy) dx + 0.5 c dy^2: the band terms once, two multiply-adds per group. Forward
// and backward both use it, so they see bit-identical sigmas.
template <typename V, typename T>
struct BandSigma {
  V half_a, b_dy, half_c_dy2;
  BandSigma(T a, T b, T c, const V& dy)
      : half_a(broadcast<V>(T(0.5) * a)), b_dy(b * dy), half_c_dy2((T(0.5) * c) * dy * dy) {}
  V operator()(const V& dx) const { return mul_add(mul_add(half_a, dx, b_dy), dx, half_c_dy2); }
};

// exp(x) for float lanes to a few ulp, with no library call, so that the forward and backward
// passes compute bit-identical alphas on every machine.
inline Lanes<float>::V exp_lanes(Lanes<float>::V x) {
  using V = Lanes<float>::V;
  x = min_lanes(max_lanes(x, broadcast<V>(-87.0f)), broadcast<V>(88.0f));
  const float shifter = 12582912.0f;  // 1.5 * 2^23: adding and subtracting it rounds to an integer
  const V n = mul_add(x, 1.4426950408889634f, broadcast<V>(shifter)) - shifter;
  const V r = mul_add(n, 2.12194440e-4f, mul_add(n, -0.693359375f, x));  // |r| <= ln(2)/2; ln 2 split hi+lo
  // Taylor series of e^r to degree 7, summed in Estrin's order: a chain of 4 dependent
  // operations instead of Horner's 7 (the forward pass was waiting on this latency).
  const V r2 = r * r;
  const V r4 = r2 * r2;
  const V low = mul_add(r2, mul_add(r, 1.0f / 6.0f, broadcast<V>(0.5f)), 1.0f + r);
  const V high = mul_add(r2, mul_add(r, 1.0f / 5040.0f, broadcast<V>(1.0f / 720.0f)),
                         mul_add(r, 1.0f / 120.0f, broadcast<V>(1.0f / 24.0f)));
  const V p = mul_add(r4, high, low);
  const Lanes<float>::Mask bits = (__builtin_convertvector(n, Lanes<float>::Mask) + 127) << 23;  // 2^n
  return p * load<V>(&bits);
}

inline Lanes<double>::V exp_lanes(Lanes<double>::V x) {
  for (int i = 0; i < Lanes<double>::kCount; ++i) x[i] = std::exp(x[i]);
  return x;
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

// Indices of the splats with a non-empty support box, stably ordered by depth: LSD radix sort on
// order-preserving integer keys, 11 bits a pass (3 passes for float depths).
template <typename scalar_t>
std::vector<int32_t> depth_order(const scalar_t* packed, const std::vector<PixelBox>& boxes) {
  using key_t = std::conditional_t<sizeof(scalar_t) == 4, uint32_t, uint64_t>;
  constexpr key_t sign = key_t(1) << (8 * sizeof(key_t) - 1);
  constexpr int kDigitBits = 11, kBuckets = 1 << kDigitBits;
  std::vector<key_t> keys, keys_tmp;
  std::vector<int32_t> order, order_tmp;
  keys.reserve(boxes.size());
  order.reserve(boxes.size());
  for (int64_t i = 0; i < static_cast<int64_t>(boxes.size()); ++i) {
    if (boxes[i].empty()) continue;  // off screen, behind the camera or too faint: never drawn
    key_t bits;
    std::memcpy(&bits, &packed[i * kFields + 9], sizeof(bits));
    keys.push_back((bits & sign) ? ~bits : (bits | sign));
    order.push_back(static_cast<int32_t>(i));
  }
  const int64_t count = static_cast<int64_t>(keys.size());
  keys_tmp.resize(count);
  order_tmp.resize(count);
  for (int shift = 0; shift < static_cast<int>(8 * sizeof(key_t)); shift += kDigitBits) {
    std::vector<int64_t> histogram(kBuckets + 1, 0);
    for (int64_t i = 0; i < count; ++i) ++histogram[((keys[i] >> shift) & (kBuckets - 1)) + 1];
    if (std::any_of(histogram.begin() + 1, histogram.end(), [&](int64_t h) { return h == count; })) continue;
    for (int d = 0; d < kBuckets; ++d) histogram[d + 1] += histogram[d];
    for (int64_t i = 0; i < count; ++i) {
      const int64_t slot = histogram[(keys[i] >> shift) & (kBuckets - 1)]++;
      keys_tmp[slot] = keys[i];
      order_tmp[slot] = order[i];
    }
    keys.swap(keys_tmp);
    order.swap(order_tmp);
  }
  return order;
}

// Per-tile lists: tile t owns ids[offsets[t] .. offsets[t+1]), splat indices front to back.
// boxes: support boxes of all splats. reached: per list entry, the groups of pixels of the tile
// that the forward pass listed for the splat (bit g / kPerBit for group g, see Groups), so that
// the backward pass visits only those. All four are kept for the backward pass.
struct Binning {
  std::vector<int32_t> offsets;
  std::vector<int32_t> ids;
  std::vector<PixelBox> boxes;
  std::vector<uint64_t> reached;
};

// Read-only view of a Binning, or of the tensors that hold it between the passes.
struct TileLists {
  const int32_t* offsets;  // (tiles + 1)
  const int32_t* ids;      // (entries)
  const PixelBox* boxes;   // (M)
  const uint64_t* reached;  // (entries)
  int64_t num_tiles;
  explicit TileLists(const Binning& binning)
      : offsets(binning.offsets.data()), ids(binning.ids.data()), boxes(binning.boxes.data()),
        reached(binning.reached.data()), num_tiles(static_cast<int64_t>(binning.offsets.size()) - 1) {}
  TileLists(const int32_t* offsets_, const int32_t* ids_, const PixelBox* boxes_, const uint64_t* reached_,
            int64_t num_tiles_)
      : offsets(offsets_), ids(ids_), boxes(boxes_), reached(reached_), num_tiles(num_tiles_) {}
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
Binning bin_splats(const scalar_t* packed, int64_t width, int64_t height,
                   const std::vector<PixelBox>& boxes, int64_t workers, const ParallelFor& parallel_for) {
  const int64_t tiles_x = (width + kTile - 1) / kTile, tiles_y = (height + kTile - 1) / kTile;
  const int64_t num_tiles = tiles_x * tiles_y;
  const std::vector<int32_t> order = depth_order(packed, boxes);
  const int64_t listed = static_cast<int64_t>(order.size());
  std::vector<PixelBox> sorted_boxes(listed);  // boxes in depth order: the passes below read them in sequence
  parallel_for(0, listed, 4096, [&](int64_t begin, int64_t end) {
    for (int64_t k = begin; k < end; ++k) sorted_boxes[k] = boxes[order[k]];
  });
  const int64_t chunks = std::max<int64_t>(1, std::min<int64_t>(workers, listed / 4096 + 1));
  const int64_t chunk_size = (listed + chunks - 1) / chunks;
  std::vector<int32_t> cursors(chunks * num_tiles, 0);  // per chunk and tile: count, then write position
  parallel_for(0, chunks, 1, [&](int64_t begin, int64_t end) {
    for (int64_t chunk = begin; chunk < end; ++chunk) {
      int32_t* counts = cursors.data() + chunk * num_tiles;
      for (int64_t k = chunk * chunk_size; k < std::min(listed, (chunk + 1) * chunk_size); ++k)
        for_each_tile_of(sorted_boxes[k], tiles_x, [&](int64_t t) { ++counts[t]; });
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
      for (int64_t k = chunk * chunk_size; k < std::min(listed, (chunk + 1) * chunk_size); ++k)
        for_each_tile_of(sorted_boxes[k], tiles_x, [&](int64_t t) { binning.ids[cursor[t]++] = order[k]; });
    }
  });
  return binning;
}

// The tile loops visit splats in depth order, scattered over arrays far larger than the cache:
// without a prefetch, every splat of every tile starts with a cache miss (measured: a quarter of
// the forward time went to the load of its first field).
constexpr int32_t kPrefetchAhead = 2;

// Splats per task of the gradient sum: every task scans all entries, so few tasks.
constexpr int64_t kSplatsPerSum = 8192;

template <typename scalar_t>
inline void prefetch_splat(const scalar_t* packed, const PixelBox* boxes, int32_t id) {
  const scalar_t* s = packed + static_cast<int64_t>(id) * kFields;
  __builtin_prefetch(s);
  __builtin_prefetch(s + kFields - 1);  // the record may straddle two cache lines
  __builtin_prefetch(&boxes[id]);
}

// The tiles, longest lists first (ties by tile index): the order in which workers take them, so
// that uneven tiles do not leave a core idle, and the order in which the backward pass sums a
// splat's gradient contributions.
inline std::vector<int32_t> tile_schedule(const int32_t* offsets, int64_t num_tiles) {
  std::vector<int32_t> schedule(num_tiles);
  std::iota(schedule.begin(), schedule.end(), 0);
  std::stable_sort(schedule.begin(), schedule.end(), [&](int32_t p, int32_t q) {
    return offsets[p + 1] - offsets[p] > offsets[q + 1] - offsets[q];
  });
  return schedule;
}

// Runs body(tile) for every tile of the schedule on `workers` workers that take tiles from a
// shared counter. Which worker runs a tile depends on timing, so a body must write only to
// memory of its own tile.
template <typename ParallelFor, typename Body>
void for_each_tile(const std::vector<int32_t>& schedule, int64_t workers, const ParallelFor& parallel_for,
                   const Body& body) {
  const int64_t num_tiles = static_cast<int64_t>(schedule.size());
  std::atomic<int64_t> next{0};
  parallel_for(0, workers, 1, [&](int64_t begin, int64_t end) {
    for (int64_t worker = begin; worker < end; ++worker)
      for (int64_t k = next++; k < num_tiles; k = next++) body(schedule[k]);
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
void forward_tile(const scalar_t* packed, const TileLists& lists, int64_t tile, int64_t width, int64_t height,
                  const ForwardOutputs<scalar_t>& out, uint64_t* reached) {
  using T = scalar_t;
  using G = Groups<T>;
  using V = typename Lanes<T>::V;
  using Mask = typename Lanes<T>::Mask;
  constexpr int kLanes = G::kLanes;
  const TileRect rect(tile, width, height);
  // Per-pixel state over the tile, in slot order; pixels outside the image stay inactive.
  alignas(64) T trans[kTilePixels], acc_r[kTilePixels], acc_g[kTilePixels], acc_b[kTilePixels];
  alignas(64) T acc_z[kTilePixels], active[kTilePixels], last[kTilePixels];
  int32_t active_in_band[G::kBands] = {0};
  for (int p = 0; p < kTilePixels; ++p) {
    trans[p] = 1;
    acc_r[p] = acc_g[p] = acc_b[p] = acc_z[p] = active[p] = 0;
    last[p] = -1;  // list position held as a float: exact, and comparable in lanes
  }
  for (int32_t y = 0; y <= rect.y1 - rect.y0; ++y) {
    active_in_band[y / G::kRows] += rect.x1 - rect.x0 + 1;
    for (int32_t x = 0; x <= rect.x1 - rect.x0; ++x) active[G::slot(x, y)] = 1;
  }
  int32_t remaining = (rect.x1 - rect.x0 + 1) * (rect.y1 - rect.y0 + 1);
  const V lane_x = G::lane_x(), lane_y = G::lane_y();

  const T alpha_max = T(kAlphaMax), alpha_min = T(kAlphaMin), t_min = T(kTransmittanceMin);
  // Groups of the current splat that some lane of it reaches: first found with sigma alone, then
  // composited in a second loop whose iterations are independent of each other (different
  // pixels) and free of data-dependent branches, so the CPU overlaps their long exp chains.
  alignas(64) T group_sigma[kTilePixels];
  int32_t group_slot[G::kCount];
  const int32_t begin = lists.offsets[tile], end = lists.offsets[tile + 1];
  for (int32_t k = begin; k < end && remaining > 0; ++k) {
    const int32_t id = lists.ids[k];
    if (k + kPrefetchAhead < end) prefetch_splat(packed, lists.boxes, lists.ids[k + kPrefetchAhead]);
    const T* s = packed + static_cast<int64_t>(id) * kFields;
    const T mx = s[0], my = s[1], a = s[2], b = s[3], c = s[4];
    const PixelBox& box = lists.boxes[id];
    const T max_sigma = T(box.max_sigma);
    // Tile-local group columns and bands of the box.
    const int32_t col0 = (std::max(box.x0, rect.x0) - rect.x0) / G::kCols;
    const int32_t col1 = (std::min(box.x1, rect.x1) - rect.x0) / G::kCols;
    const int32_t band0 = (std::max(box.y0, rect.y0) - rect.y0) / G::kRows;
    const int32_t band1 = (std::min(box.y1, rect.y1) - rect.y0) / G::kRows;
    int32_t groups = 0;
    uint64_t reached_groups = 0;
    for (int32_t band = band0; band <= band1; ++band) {
      if (active_in_band[band] == 0) continue;
      const V dy = (T(rect.y0 + band * G::kRows) + lane_y) - my;
      const BandSigma<V, T> band_sigma(a, b, c, dy);
      for (int32_t col = col0; col <= col1; ++col) {
        const int32_t p = (band * G::kAcross + col) * kLanes;
        const V sigma = band_sigma((T(rect.x0 + col * G::kCols) + lane_x) - mx);
        const Mask reachable = (sigma <= max_sigma) & (load<V>(active + p) != T(0));
        store(group_sigma + groups * kLanes, sigma);
        group_slot[groups] = p;
        const bool listed = !no_lane(reachable);  // not when outside the support ellipse or finished
        groups += listed;
        reached_groups |= uint64_t(listed) << ((band * G::kAcross + col) / G::kPerBit);
      }
    }
    reached[k] = reached_groups;
    const T cr = s[5], cg = s[6], cb = s[7], opacity = s[8], z = s[9];
    const V position = broadcast<V>(T(k - begin));
    for (int32_t g = 0; g < groups; ++g) {
      const int32_t p = group_slot[g];
      const V sigma = load<V>(group_sigma + g * kLanes);
      const V was_active = load<V>(active + p);
      const Mask reachable = (sigma <= max_sigma) & (was_active != T(0));
      const V al = min_lanes(opacity * exp_lanes(-sigma), broadcast<V>(alpha_max));
      const V t = load<V>(trans + p);
      Mask use = (sigma >= T(0)) & (al >= alpha_min) & reachable;
      const V next = t * (T(1) - al);
      const Mask stop = use & (next <= t_min);
      use &= ~stop;
      const V w = use ? al * t : V{};
      store(acc_r + p, mul_add(w, cr, load<V>(acc_r + p)));
      store(acc_g + p, mul_add(w, cg, load<V>(acc_g + p)));
      store(acc_b + p, mul_add(w, cb, load<V>(acc_b + p)));
      store(acc_z + p, mul_add(w, z, load<V>(acc_z + p)));
      store(trans + p, use ? next : t);
      store(active + p, stop ? V{} : was_active);
      store(last + p, use ? position : load<V>(last + p));
      const int32_t stopped = set_lanes(stop);
      active_in_band[p / (kLanes * G::kAcross)] -= stopped;
      remaining -= stopped;
    }
  }
  for (int32_t y = rect.y0; y <= rect.y1; ++y) {
    for (int32_t x = rect.x0; x <= rect.x1; ++x) {
      const int32_t p = G::slot(x - rect.x0, y - rect.y0);
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

// Writes the gradient contribution of each entry of the tile's list, up to the last splat that a
// pixel of the tile composited, to its row of entry_grads (entries, 10), in the packed layout.
// Returns the number of entries written (the splats behind them have no gradient from this tile).
template <typename scalar_t>
int32_t backward_tile(const scalar_t* packed, const TileLists& lists, int64_t tile, int64_t width, int64_t height,
                      const BackwardInputs<scalar_t>& in, scalar_t* entry_grads) {
  using T = scalar_t;
  using G = Groups<T>;
  using V = typename Lanes<T>::V;
  using Mask = typename Lanes<T>::Mask;
  constexpr int kLanes = G::kLanes;
  const TileRect rect(tile, width, height);
  // final_trans_g_a: T_final dL/dalpha_out; d(alpha_out)/d(alpha_i) = T_final / (1 - alpha_i).
  alignas(64) T trans[kTilePixels], final_trans_g_a[kTilePixels], last[kTilePixels];
  alignas(64) T g_r[kTilePixels], g_g[kTilePixels], g_b[kTilePixels], g_z[kTilePixels];
  alignas(64) T behind_r[kTilePixels], behind_g[kTilePixels], behind_b[kTilePixels], behind_z[kTilePixels];
  for (int p = 0; p < kTilePixels; ++p) {
    trans[p] = 1;
    final_trans_g_a[p] = g_r[p] = g_g[p] = g_b[p] = g_z[p] = 0;
    behind_r[p] = behind_g[p] = behind_b[p] = behind_z[p] = 0;
    last[p] = -1;
  }
  int32_t max_last = -1;
  for (int32_t y = rect.y0; y <= rect.y1; ++y) {
    for (int32_t x = rect.x0; x <= rect.x1; ++x) {
      const int32_t p = G::slot(x - rect.x0, y - rect.y0);
      const int64_t q = static_cast<int64_t>(y) * width + x;
      trans[p] = in.transmittance[q];
      final_trans_g_a[p] = in.transmittance[q] * in.grad_alpha[q];
      last[p] = T(in.last[q]);
      max_last = std::max(max_last, in.last[q]);
      g_r[p] = in.grad_rgb[3 * q];
      g_g[p] = in.grad_rgb[3 * q + 1];
      g_b[p] = in.grad_rgb[3 * q + 2];
      g_z[p] = in.grad_depth[q];
    }
  }
  const V lane_x = G::lane_x(), lane_y = G::lane_y();

  const T alpha_max = T(kAlphaMax), alpha_min = T(kAlphaMin);
  const int32_t begin = lists.offsets[tile];
  for (int32_t position = max_last; position >= 0; --position) {
    const int32_t id = lists.ids[begin + position];
    if (position >= kPrefetchAhead) prefetch_splat(packed, lists.boxes, lists.ids[begin + position - kPrefetchAhead]);
    const T* s = packed + static_cast<int64_t>(id) * kFields;
    const T mx = s[0], my = s[1], a = s[2], b = s[3], c = s[4];
    const T cr = s[5], cg = s[6], cb = s[7], opacity = s[8], z = s[9];
    const T max_sigma = T(lists.boxes[id].max_sigma);
    const V position_lanes = broadcast<V>(T(position));
    // Shape gradients from the moments of g = dL/dsigma: sum(g dx), sum(g dx^2), ... below.
    V d_r{}, d_g{}, d_bl{}, d_op{}, d_z{};
    V sum_g_dx{}, sum_g_dy{}, sum_g_dx2{}, sum_g_dxdy{}, sum_g_dy2{};
    // Only the groups that the forward pass listed for this splat: the others have no lane that
    // it composited. The loop has no data-dependent branch but its exit, so the CPU overlaps
    // the groups' long dependency chains (different pixels, independent).
    for (uint64_t bits = lists.reached[begin + position]; bits != 0; bits &= bits - 1) {
      const int32_t first = __builtin_ctzll(bits) * G::kPerBit;
      for (int32_t index = first; index < first + G::kPerBit; ++index) {
        const int32_t p = index * kLanes;
        // dx, dy and sigma exactly as in the forward pass.
        const V dy = (T(rect.y0 + (index / G::kAcross) * G::kRows) + lane_y) - my;
        const V dx = (T(rect.x0 + (index % G::kAcross) * G::kCols) + lane_x) - mx;
        const V sigma = BandSigma<V, T>(a, b, c, dy)(dx);
        const Mask reachable = (sigma <= max_sigma) & (position_lanes <= load<V>(last + p));
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
        d_r = mul_add(w, gr, d_r);
        d_g = mul_add(w, gg, d_g);
        d_bl = mul_add(w, gb, d_bl);
        d_z = mul_add(w, gz, d_z);
        // d(outputs)/d(alpha): colour and depth through the splats behind, alpha through T_final.
        // Behind-colour update: behind' = alpha c + (1 - alpha) behind = behind + alpha (c - behind).
        const V br = load<V>(behind_r + p), bg = load<V>(behind_g + p);
        const V bb = load<V>(behind_b + p), bz = load<V>(behind_z + p);
        const V diff_r = cr - br, diff_g = cg - bg, diff_b = cb - bb, diff_z = z - bz;
        const V behind_dot_g = mul_add(diff_z, gz, mul_add(diff_b, gb, mul_add(diff_g, gg, diff_r * gr)));
        const V d_alpha = mul_add(t_before, behind_dot_g, load<V>(final_trans_g_a + p) * inv_one_minus);
        store(behind_r + p, mul_add(al_used, diff_r, br));
        store(behind_g + p, mul_add(al_used, diff_g, bg));
        store(behind_b + p, mul_add(al_used, diff_b, bb));
        store(behind_z + p, mul_add(al_used, diff_z, bz));
        store(trans + p, used ? t_before : t_after);
        // The clamp at alpha_max cuts the gradient to opacity and sigma (as torch.clamp does).
        const V through = (used & (raw <= alpha_max)) ? d_alpha : V{};
        const V d_sigma = -al * through;
        d_op = mul_add(gauss, through, d_op);
        const V g_dx = d_sigma * dx, g_dy = d_sigma * dy;
        sum_g_dx += g_dx;
        sum_g_dy += g_dy;
        sum_g_dx2 = mul_add(g_dx, dx, sum_g_dx2);
        sum_g_dxdy = mul_add(g_dx, dy, sum_g_dxdy);
        sum_g_dy2 = mul_add(g_dy, dy, sum_g_dy2);
      }
    }
    // sigma = 0.5 a dx^2 + b dx dy + 0.5 c dy^2 with dx = px - mean_x, dy = py - mean_y.
    const V accumulators[8] = {sum_g_dx, sum_g_dy, sum_g_dx2, sum_g_dxdy, sum_g_dy2, d_r, d_g, d_bl};
    T sums[8];
    lane_sums(accumulators, sums);
    // Negation is exact: adding row[0] later is subtracting a * sums[0] + b * sums[1].
    T* row = entry_grads + static_cast<int64_t>(begin + position) * kFields;
    row[0] = -(a * sums[0] + b * sums[1]);
    row[1] = -(b * sums[0] + c * sums[1]);
    row[2] = T(0.5) * sums[2];
    row[3] = sums[3];
    row[4] = T(0.5) * sums[4];
    row[5] = sums[5];
    row[6] = sums[6];
    row[7] = sums[7];
    row[8] = lane_sum(d_op);
    row[9] = lane_sum(d_z);
  }
  return max_last + 1;
}

// sum[f] += row[f] for the kFields fields, in SIMD registers where they fit (each lane is still
// one addition, rounded alone).
template <typename scalar_t>
inline void add_row(scalar_t* sum, const scalar_t* row) {
  using V = typename Lanes<scalar_t>::V;
  constexpr int kLanes = Lanes<scalar_t>::kCount;
  int f = 0;
  for (; f + kLanes <= kFields; f += kLanes) store(sum + f, load<V>(sum + f) + load<V>(row + f));
  for (; f < kFields; ++f) sum[f] += row[f];
}

// grad_packed (M,10), zeroed by the caller, += the rows of entry_grads, the first written[t]
// entries of each tile t; each splat's rows in the order of the tiles in `schedule` (a splat has
// at most one entry per tile). That order does not depend on the number of workers: each worker
// owns a contiguous range of splats and scans every entry, adding those of its own splats, so a
// splat's sum is always the same sequence of additions, starting from zero.
template <typename scalar_t, typename ParallelFor>
void sum_entry_gradients(const TileLists& lists, const std::vector<int32_t>& schedule,
                         const std::vector<int32_t>& written, const scalar_t* entry_grads, int64_t count,
                         const ParallelFor& parallel_for, scalar_t* grad_packed) {
  parallel_for(0, count, kSplatsPerSum, [&](int64_t first, int64_t stop) {
    for (const int32_t tile : schedule) {
      const int32_t begin = lists.offsets[tile], end = begin + written[tile];
      for (int32_t k = begin; k < end; ++k) {
        // The sums of the splats a few entries ahead, scattered in depth order (measured: 4-12 % off the
        // backward pass).
        if (k + kPrefetchAhead < end) __builtin_prefetch(grad_packed + int64_t(lists.ids[k + kPrefetchAhead]) * kFields, 1);
        const int32_t id = lists.ids[k];
        if (id < first || id >= stop) continue;
        add_row(grad_packed + static_cast<int64_t>(id) * kFields, entry_grads + static_cast<int64_t>(k) * kFields);
      }
    }
  });
}

// Forward pass over all tiles; returns the binning that the backward pass needs.
template <typename scalar_t, typename ParallelFor>
Binning composite_forward(const scalar_t* packed, int64_t count, int64_t width, int64_t height, int64_t workers,
                          const ParallelFor& parallel_for, const ForwardOutputs<scalar_t>& out) {
  std::vector<PixelBox> boxes = support_boxes(packed, count, width, height, parallel_for);
  Binning binning = bin_splats(packed, width, height, boxes, workers, parallel_for);
  binning.boxes = std::move(boxes);
  binning.reached.assign(binning.ids.size(), 0);
  const TileLists lists(binning);
  uint64_t* reached = binning.reached.data();
  for_each_tile(tile_schedule(lists.offsets, lists.num_tiles), workers, parallel_for, [&](int64_t tile) {
    forward_tile(packed, lists, tile, width, height, out, reached);
  });
  return binning;
}

// Backward pass: grad_packed (M,10), zeroed by the caller, receives the splats' gradients;
// entry_grads (entries, 10) is scratch space, one row per (splat, tile) entry.
template <typename scalar_t, typename ParallelFor>
void composite_backward(const scalar_t* packed, int64_t count, int64_t width, int64_t height, int64_t workers,
                        const ParallelFor& parallel_for, const TileLists& lists,
                        const BackwardInputs<scalar_t>& in, scalar_t* entry_grads, scalar_t* grad_packed) {
  const std::vector<int32_t> schedule = tile_schedule(lists.offsets, lists.num_tiles);
  std::vector<int32_t> written(lists.num_tiles);
  for_each_tile(schedule, workers, parallel_for, [&](int64_t tile) {
    written[tile] = backward_tile(packed, lists, tile, width, height, in, entry_grads);
  });
  sum_entry_gradients(lists, schedule, written, entry_grads, count, parallel_for, grad_packed);
}

}  // namespace recondreamer_splat

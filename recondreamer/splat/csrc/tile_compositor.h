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
// only visits the pixels of its support box, and skips rows whose pixels are all finished.
//
// The pixel loops work on groups of pixels of one tile row at once with GCC/Clang vector
// extensions (one SIMD register: 4 floats with SSE2, 8 with AVX2), branch-free with lane
// masks. The backward pass walks each tile's list back to front, recovering T by division,
// and accumulates gradients in one buffer per worker.

#pragma once

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <numeric>
#include <type_traits>
#include <vector>

namespace recondreamer_splat {

constexpr int kTile = 16;
constexpr int kTilePixels = kTile * kTile;
constexpr int kFields = 10;  // packed splat layout, see the header comment
constexpr double kAlphaMax = 0.99;
constexpr double kAlphaMin = 1.0 / 255.0;
constexpr double kTransmittanceMin = 1e-4;
constexpr double kSupportMargin = 1.0;

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

// exp(x) for float lanes to a few ulp, with no library call, so that the forward and backward
// passes compute bit-identical alphas on every machine.
inline Lanes<float>::V exp_lanes(Lanes<float>::V x) {
  using V = Lanes<float>::V;
  x = x < -87.0f ? broadcast<V>(-87.0f) : x;
  x = x > 88.0f ? broadcast<V>(88.0f) : x;
  const float shifter = 12582912.0f;  // 1.5 * 2^23: adding and subtracting it rounds to an integer
  const V n = (x * 1.4426950408889634f + shifter) - shifter;
  const V r = (x - n * 0.693359375f) - n * -2.12194440e-4f;  // |r| <= ln(2)/2; ln 2 split hi+lo
  V p = broadcast<V>(1.0f / 5040.0f);  // Taylor series of e^r to degree 7
  p = p * r + 1.0f / 720.0f;
  p = p * r + 1.0f / 120.0f;
  p = p * r + 1.0f / 24.0f;
  p = p * r + 1.0f / 6.0f;
  p = p * r + 0.5f;
  p = p * r + 1.0f;
  p = p * r + 1.0f;
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
struct PixelBox {
  int32_t x0, x1, y0, y1;
  bool empty() const { return x0 > x1 || y0 > y1; }
};

template <typename scalar_t>
PixelBox support_box(const scalar_t* s, int64_t width, int64_t height) {
  const PixelBox nothing{1, 0, 1, 0};
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
          static_cast<int32_t>(std::max(fy0, 0.0)), static_cast<int32_t>(std::min(fy1, height - 1.0))};
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
struct Binning {
  std::vector<int32_t> offsets;
  std::vector<int32_t> ids;
};

template <typename scalar_t>
Binning bin_splats(const scalar_t* packed, int64_t count, int64_t width, int64_t height,
                   const std::vector<PixelBox>& boxes) {
  const int64_t tiles_x = (width + kTile - 1) / kTile, tiles_y = (height + kTile - 1) / kTile;
  Binning binning;
  binning.offsets.assign(tiles_x * tiles_y + 1, 0);
  for (int64_t i = 0; i < count; ++i) {
    const PixelBox& box = boxes[i];
    if (box.empty()) continue;
    for (int32_t ty = box.y0 / kTile; ty <= box.y1 / kTile; ++ty)
      for (int32_t tx = box.x0 / kTile; tx <= box.x1 / kTile; ++tx) ++binning.offsets[ty * tiles_x + tx + 1];
  }
  std::partial_sum(binning.offsets.begin(), binning.offsets.end(), binning.offsets.begin());
  binning.ids.resize(binning.offsets.back());
  std::vector<int32_t> cursor(binning.offsets.begin(), binning.offsets.end() - 1);
  for (const int32_t i : depth_order(packed, count)) {
    const PixelBox& box = boxes[i];
    if (box.empty()) continue;
    for (int32_t ty = box.y0 / kTile; ty <= box.y1 / kTile; ++ty)
      for (int32_t tx = box.x0 / kTile; tx <= box.x1 / kTile; ++tx) binning.ids[cursor[ty * tiles_x + tx]++] = i;
  }
  return binning;
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
    const T* s = packed + static_cast<int64_t>(id) * kFields;
    const T mx = s[0], my = s[1], a = s[2], b = s[3], c = s[4];
    const T cr = s[5], cg = s[6], cb = s[7], opacity = s[8], z = s[9];
    const PixelBox& box = boxes[id];
    // Tile-local columns, the first one rounded down to a whole group.
    const int32_t gx0 = (std::max(box.x0, rect.x0) - rect.x0) & ~(kLanes - 1);
    const int32_t gx1 = std::min(box.x1, rect.x1) - rect.x0;
    const int32_t y0 = std::max(box.y0, rect.y0), y1 = std::min(box.y1, rect.y1);
    const V position = broadcast<V>(T(k - begin));
    for (int32_t y = y0; y <= y1; ++y) {
      if (active_in_row[y - rect.y0] == 0) continue;
      const T dy = T(y) + T(0.5) - my;
      const int32_t row = (y - rect.y0) * kTile;
      Mask stops{};  // per lane: minus the number of pixels that finished on this row
      for (int32_t gx = gx0; gx <= gx1; gx += kLanes) {
        const int32_t p = row + gx;
        const V dx = (T(rect.x0 + gx) + lane_centre) - mx;
        const V sigma = T(0.5) * (a * dx * dx + c * dy * dy) + b * dx * dy;
        V al = opacity * exp_lanes(-sigma);
        al = al > alpha_max ? broadcast<V>(alpha_max) : al;
        const V was_active = load<V>(active + p), t = load<V>(trans + p);
        Mask use = (sigma >= T(0)) & (al >= alpha_min) & (was_active != T(0));
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
        stops += stop;  // true lanes are -1
      }
      const int32_t stopped = -static_cast<int32_t>(lane_sum(stops));
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
    const T* s = packed + static_cast<int64_t>(id) * kFields;
    const T mx = s[0], my = s[1], a = s[2], b = s[3], c = s[4];
    const T cr = s[5], cg = s[6], cb = s[7], opacity = s[8], z = s[9];
    const PixelBox& box = boxes[id];
    const int32_t gx0 = (std::max(box.x0, rect.x0) - rect.x0) & ~(kLanes - 1);
    const int32_t gx1 = std::min(box.x1, rect.x1) - rect.x0;
    const int32_t y0 = std::max(box.y0, rect.y0), y1 = std::min(box.y1, rect.y1);
    const V position_lanes = broadcast<V>(T(position));
    V d_mx{}, d_my{}, d_a{}, d_b{}, d_c{}, d_r{}, d_g{}, d_bl{}, d_op{}, d_z{};
    for (int32_t y = y0; y <= y1; ++y) {
      if (row_last[y - rect.y0] < position) continue;
      const T dy = T(y) + T(0.5) - my;
      const int32_t row = (y - rect.y0) * kTile;
      for (int32_t gx = gx0; gx <= gx1; gx += kLanes) {
        const int32_t p = row + gx;
        const V dx = (T(rect.x0 + gx) + lane_centre) - mx;
        const V sigma = T(0.5) * (a * dx * dx + c * dy * dy) + b * dx * dy;
        const V gauss = exp_lanes(-sigma);
        const V raw = opacity * gauss;
        const V al = raw > alpha_max ? broadcast<V>(alpha_max) : raw;
        const Mask used = (sigma >= T(0)) & (al >= alpha_min) & (position_lanes <= load<V>(last + p));
        const V one_minus = T(1) - al;
        const V t_after = load<V>(trans + p);
        const V t_before = t_after / one_minus;  // transmittance in front of this splat
        const V w = used ? al * t_before : V{};
        const V gr = load<V>(g_r + p), gg = load<V>(g_g + p), gb = load<V>(g_b + p), gz = load<V>(g_z + p);
        d_r += w * gr;
        d_g += w * gg;
        d_bl += w * gb;
        d_z += w * gz;
        // d(outputs)/d(alpha): colour and depth through the splats behind, alpha through T_final.
        const V br = load<V>(behind_r + p), bg = load<V>(behind_g + p);
        const V bb = load<V>(behind_b + p), bz = load<V>(behind_z + p);
        V d_alpha = t_before * ((cr - br) * gr + (cg - bg) * gg + (cb - bb) * gb + (z - bz) * gz) +
                    load<V>(final_trans + p) / one_minus * load<V>(g_a + p);
        d_alpha = used ? d_alpha : V{};
        store(behind_r + p, used ? al * cr + one_minus * br : br);
        store(behind_g + p, used ? al * cg + one_minus * bg : bg);
        store(behind_b + p, used ? al * cb + one_minus * bb : bb);
        store(behind_z + p, used ? al * z + one_minus * bz : bz);
        store(trans + p, used ? t_before : t_after);
        // The clamp at alpha_max cuts the gradient to opacity and sigma (as torch.clamp does).
        const V through = raw <= alpha_max ? d_alpha : V{};
        const V d_sigma = -al * through;
        d_op += gauss * through;
        d_a += T(0.5) * dx * dx * d_sigma;
        d_b += dx * dy * d_sigma;
        d_c += T(0.5) * dy * dy * d_sigma;
        d_mx -= (a * dx + b * dy) * d_sigma;
        d_my -= (b * dx + c * dy) * d_sigma;
      }
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
  const std::vector<PixelBox> boxes = support_boxes(packed, count, width, height, parallel_for);
  Binning binning = bin_splats(packed, count, width, height, boxes);
  for_each_tile(binning.offsets, workers, parallel_for, [&](int64_t tile, int64_t) {
    forward_tile(packed, binning, boxes, tile, width, height, out);
  });
  return binning;
}

// Backward pass: grad_buffers holds `workers` zeroed (M,10) buffers, to be summed by the caller.
template <typename scalar_t, typename ParallelFor>
void composite_backward(const scalar_t* packed, int64_t count, int64_t width, int64_t height, int64_t workers,
                        const ParallelFor& parallel_for, const Binning& binning,
                        const BackwardInputs<scalar_t>& in, scalar_t* grad_buffers) {
  const std::vector<PixelBox> boxes = support_boxes(packed, count, width, height, parallel_for);
  for_each_tile(binning.offsets, workers, parallel_for, [&](int64_t tile, int64_t worker) {
    backward_tile(packed, binning, boxes, tile, width, height, in, grad_buffers + worker * count * kFields);
  });
}

}  // namespace recondreamer_splat

// Torch bindings of the projection (projection.h) and the tile compositor (tile_compositor.h),
// forward and backward passes, each parallel over Gaussians or tiles with at::parallel_for.

#include <torch/extension.h>

#include <ATen/Parallel.h>

#include "projection.h"
#include "tile_compositor.h"

namespace {

namespace rs = recondreamer_splat;

struct AtenParallelFor {
  template <typename Body>
  void operator()(int64_t begin, int64_t end, int64_t grain, const Body& body) const {
    at::parallel_for(begin, end, grain, body);
  }
};

void check_packed(const at::Tensor& packed) {
  TORCH_CHECK(packed.device().is_cpu() && packed.is_contiguous(), "packed splats must be contiguous on the CPU");
  TORCH_CHECK(packed.dim() == 2 && packed.size(1) == rs::kFields, "packed splats must have shape (M, 10)");
  TORCH_CHECK(packed.scalar_type() == at::kFloat || packed.scalar_type() == at::kDouble,
              "packed splats must be float32 or float64");
  TORCH_CHECK(packed.size(0) < (int64_t(1) << 31), "too many splats");
}

constexpr int64_t kSplatsPerTask = 4096;

// The splats' fields side by side, (M,10) = [mean (2), conic (3), rgb (3), opacity, depth], with
// the opacity of the splats outside `keep` set to 0 (the compositor then leaves them out).
at::Tensor pack_splats(const at::Tensor& means2d, const at::Tensor& conics, const at::Tensor& colors,
                       const at::Tensor& opacities, const at::Tensor& depths, const at::Tensor& keep) {
  const int64_t m = means2d.size(0);
  const auto dtype = means2d.scalar_type();
  TORCH_CHECK(dtype == at::kFloat || dtype == at::kDouble, "splats must be float32 or float64");
  TORCH_CHECK(m < (int64_t(1) << 31), "too many splats");
  TORCH_CHECK(means2d.sizes() == at::IntArrayRef({m, 2}) && conics.sizes() == at::IntArrayRef({m, 3}) &&
                  colors.sizes() == at::IntArrayRef({m, 3}) && opacities.sizes() == at::IntArrayRef({m}) &&
                  depths.sizes() == at::IntArrayRef({m}) && keep.sizes() == at::IntArrayRef({m}),
              "splat fields must have shapes (M,2), (M,3), (M,3), (M,), (M,), (M,)");
  TORCH_CHECK(keep.scalar_type() == at::kBool, "keep must be a bool tensor");
  at::Tensor packed = at::empty({m, rs::kFields}, means2d.options());
  const at::Tensor fields[5] = {means2d.contiguous(), conics.contiguous(), colors.contiguous(),
                                opacities.contiguous(), depths.contiguous()};
  const at::Tensor kept = keep.contiguous();
  for (const at::Tensor& field : fields)
    TORCH_CHECK(field.device().is_cpu() && field.scalar_type() == dtype,
                "splat fields must be CPU tensors of one dtype");
  AT_DISPATCH_FLOATING_TYPES(dtype, "pack_splats", [&] {
    const scalar_t *mean = fields[0].data_ptr<scalar_t>(), *conic = fields[1].data_ptr<scalar_t>();
    const scalar_t *rgb = fields[2].data_ptr<scalar_t>(), *opacity = fields[3].data_ptr<scalar_t>();
    const scalar_t* depth = fields[4].data_ptr<scalar_t>();
    const bool* is_kept = kept.data_ptr<bool>();
    scalar_t* out = packed.data_ptr<scalar_t>();
    at::parallel_for(0, m, kSplatsPerTask, [&](int64_t begin, int64_t end) {
      for (int64_t i = begin; i < end; ++i) {
        scalar_t* s = out + i * rs::kFields;
        s[0] = mean[2 * i], s[1] = mean[2 * i + 1];
        s[2] = conic[3 * i], s[3] = conic[3 * i + 1], s[4] = conic[3 * i + 2];
        s[5] = rgb[3 * i], s[6] = rgb[3 * i + 1], s[7] = rgb[3 * i + 2];
        s[8] = is_kept[i] ? opacity[i] : scalar_t(0);
        s[9] = depth[i];
      }
    });
  });
  return packed;
}

constexpr int64_t kGaussiansPerTask = 1024;

void check_gaussians(const at::Tensor& means, const at::Tensor& quats, const at::Tensor& scales,
                     const at::Tensor& sh, const at::Tensor& viewmat, const at::Tensor& K) {
  const int64_t n = means.size(0);
  for (const at::Tensor* t : {&means, &quats, &scales, &sh, &viewmat, &K}) {
    TORCH_CHECK(t->device().is_cpu() && t->is_contiguous() && t->scalar_type() == means.scalar_type(),
                "projection inputs must be contiguous CPU tensors of one dtype");
  }
  TORCH_CHECK(means.dim() == 2 && means.size(1) == 3, "means must have shape (N,3)");
  TORCH_CHECK(quats.sizes() == at::IntArrayRef({n, 4}) && scales.sizes() == at::IntArrayRef({n, 3}),
              "quats and scales must have shapes (N,4) and (N,3)");
  TORCH_CHECK(sh.numel() == 0 || (sh.dim() == 3 && sh.size(0) == n && sh.size(2) == 3 && sh.size(1) <= 16),
              "sh must be empty or have shape (N,C,3), C <= 16");
  TORCH_CHECK(viewmat.sizes() == at::IntArrayRef({4, 4}) && K.sizes() == at::IntArrayRef({3, 3}),
              "viewmat and K must have shapes (4,4) and (3,3)");
}

}  // namespace

// Returns means2d (N,2), conics (N,3), depths (N,), rgb (N,3) (empty without SH), radii (N,)
// int32, in_front (N,) bool, visible (N,) bool.
std::vector<at::Tensor> project_forward(const at::Tensor& means, const at::Tensor& quats, const at::Tensor& scales,
                                        const at::Tensor& sh, const at::Tensor& viewmat, const at::Tensor& K,
                                        int64_t width, int64_t height) {
  check_gaussians(means, quats, scales, sh, viewmat, K);
  const int64_t n = means.size(0);
  const auto options = means.options();
  const bool has_sh = sh.numel() > 0;
  at::Tensor means2d = at::empty({n, 2}, options), conics = at::empty({n, 3}, options);
  at::Tensor depths = at::empty({n}, options), rgb = at::empty({has_sh ? n : 0, 3}, options);
  at::Tensor radii = at::empty({n}, options.dtype(at::kInt));
  at::Tensor in_front = at::empty({n}, options.dtype(at::kBool)), visible = at::empty({n}, options.dtype(at::kBool));
  AT_DISPATCH_FLOATING_TYPES(means.scalar_type(), "project_forward", [&] {
    const rs::Camera<scalar_t> camera(viewmat.data_ptr<scalar_t>(), K.data_ptr<scalar_t>(), width, height);
    const rs::ProjectionOutputs<scalar_t> out{means2d.data_ptr<scalar_t>(), conics.data_ptr<scalar_t>(),
                                              depths.data_ptr<scalar_t>(),  has_sh ? rgb.data_ptr<scalar_t>() : nullptr,
                                              radii.data_ptr<int32_t>(),    in_front.data_ptr<bool>(),
                                              visible.data_ptr<bool>()};
    const scalar_t *m = means.data_ptr<scalar_t>(), *q = quats.data_ptr<scalar_t>(), *s = scales.data_ptr<scalar_t>();
    const scalar_t* coefficients = has_sh ? sh.data_ptr<scalar_t>() : nullptr;
    const int sh_count = has_sh ? static_cast<int>(sh.size(1)) : 0;
    at::parallel_for(0, n, kGaussiansPerTask, [&](int64_t begin, int64_t end) {
      for (int64_t i = begin; i < end; ++i) rs::project_forward_one(camera, i, m, q, s, coefficients, sh_count, out);
    });
  });
  return {means2d, conics, depths, rgb, radii, in_front, visible};
}

// Gradients of means (N,3), quats (N,4), scales (N,3) and SH coefficients (N,C,3) (empty without SH).
std::vector<at::Tensor> project_backward(const at::Tensor& means, const at::Tensor& quats, const at::Tensor& scales,
                                         const at::Tensor& sh, const at::Tensor& viewmat, const at::Tensor& K,
                                         int64_t width, int64_t height, const at::Tensor& grad_means2d_in,
                                         const at::Tensor& grad_conics_in, const at::Tensor& grad_depths_in,
                                         const at::Tensor& grad_rgb_in) {
  check_gaussians(means, quats, scales, sh, viewmat, K);
  const int64_t n = means.size(0);
  const bool has_sh = sh.numel() > 0;
  const auto dtype = means.scalar_type();
  const at::Tensor grad_means2d = grad_means2d_in.to(dtype).contiguous();
  const at::Tensor grad_conics = grad_conics_in.to(dtype).contiguous();
  const at::Tensor grad_depths = grad_depths_in.to(dtype).contiguous();
  const at::Tensor grad_rgb = grad_rgb_in.to(dtype).contiguous();
  TORCH_CHECK(grad_means2d.sizes() == at::IntArrayRef({n, 2}) && grad_conics.sizes() == at::IntArrayRef({n, 3}) &&
                  grad_depths.sizes() == at::IntArrayRef({n}) &&
                  (!has_sh || grad_rgb.sizes() == at::IntArrayRef({n, 3})),
              "projection gradients have the wrong shapes");
  at::Tensor grad_means = at::empty_like(means), grad_quats = at::empty_like(quats);
  at::Tensor grad_scales = at::empty_like(scales), grad_sh = at::empty_like(sh);
  AT_DISPATCH_FLOATING_TYPES(dtype, "project_backward", [&] {
    const rs::Camera<scalar_t> camera(viewmat.data_ptr<scalar_t>(), K.data_ptr<scalar_t>(), width, height);
    const rs::ProjectionGradients<scalar_t> grad{grad_means2d.data_ptr<scalar_t>(), grad_conics.data_ptr<scalar_t>(),
                                                 grad_depths.data_ptr<scalar_t>(),
                                                 has_sh ? grad_rgb.data_ptr<scalar_t>() : nullptr};
    const rs::InputGradients<scalar_t> out{grad_means.data_ptr<scalar_t>(), grad_quats.data_ptr<scalar_t>(),
                                           grad_scales.data_ptr<scalar_t>(),
                                           has_sh ? grad_sh.data_ptr<scalar_t>() : nullptr};
    const scalar_t *m = means.data_ptr<scalar_t>(), *q = quats.data_ptr<scalar_t>(), *s = scales.data_ptr<scalar_t>();
    const scalar_t* coefficients = has_sh ? sh.data_ptr<scalar_t>() : nullptr;
    const int sh_count = has_sh ? static_cast<int>(sh.size(1)) : 0;
    at::parallel_for(0, n, kGaussiansPerTask, [&](int64_t begin, int64_t end) {
      for (int64_t i = begin; i < end; ++i)
        rs::project_backward_one(camera, i, m, q, s, coefficients, sh_count, grad, out);
    });
  });
  return {grad_means, grad_quats, grad_scales, grad_sh};
}

// A PixelBox travels to the backward pass as 5 int32 of a (M,5) tensor.
static_assert(sizeof(rs::PixelBox) == 5 * sizeof(int32_t), "PixelBox must be five 4-byte fields");

namespace {

// A tensor that takes over a vector's memory (no copy); the vector is freed with the tensor.
template <typename T>
at::Tensor adopt(std::vector<T>&& values, at::IntArrayRef sizes, at::ScalarType dtype) {
  const auto options = at::TensorOptions().dtype(dtype);
  if (values.empty()) return at::empty(sizes, options);
  auto* owner = new std::vector<T>(std::move(values));
  return at::from_blob(owner->data(), sizes, [owner](void*) { delete owner; }, options);
}

}  // namespace

// Composites the splats with keep[i] true. Returns rgb (H,W,3), depth (H,W) accumulated, alpha
// (H,W), and for the backward pass: packed splats (M,10), transmittance (H,W), last (H,W) int32,
// tile offsets (tiles+1) int32, tile ids (entries) int32, support boxes (M,5) int32, reached groups
// (entries) int64.
std::vector<at::Tensor> composite_forward(const at::Tensor& means2d, const at::Tensor& conics,
                                          const at::Tensor& colors, const at::Tensor& opacities,
                                          const at::Tensor& depths, const at::Tensor& keep, int64_t width,
                                          int64_t height) {
  TORCH_CHECK(width > 0 && height > 0, "width and height must be positive");
  const at::Tensor packed = pack_splats(means2d, conics, colors, opacities, depths, keep);
  const auto options = packed.options();
  at::Tensor rgb = at::empty({height, width, 3}, options);
  at::Tensor depth = at::empty({height, width}, options);
  at::Tensor alpha = at::empty({height, width}, options);
  at::Tensor transmittance = at::empty({height, width}, options);
  at::Tensor last = at::empty({height, width}, options.dtype(at::kInt));
  at::Tensor offsets, ids, boxes, reached;
  AT_DISPATCH_FLOATING_TYPES(packed.scalar_type(), "composite_forward", [&] {
    const rs::ForwardOutputs<scalar_t> out{rgb.data_ptr<scalar_t>(), depth.data_ptr<scalar_t>(),
                                           alpha.data_ptr<scalar_t>(), transmittance.data_ptr<scalar_t>(),
                                           last.data_ptr<int32_t>()};
    rs::Binning binning = rs::composite_forward(packed.data_ptr<scalar_t>(), packed.size(0), width, height,
                                                at::get_num_threads(), AtenParallelFor(), out);
    const int64_t entries = static_cast<int64_t>(binning.ids.size());
    const int64_t tiles = static_cast<int64_t>(binning.offsets.size()) - 1;
    offsets = adopt(std::move(binning.offsets), {tiles + 1}, at::kInt);
    ids = adopt(std::move(binning.ids), {entries}, at::kInt);
    boxes = adopt(std::move(binning.boxes), {packed.size(0), 5}, at::kInt);
    reached = adopt(std::move(binning.reached), {entries}, at::kLong);
  });
  return {rgb, depth, alpha, packed, transmittance, last, offsets, ids, boxes, reached};
}

// Gradients of the loss with respect to the splats' means2d (M,2), conics (M,3), colors (M,3),
// opacities (M,) and depths (M,), written field by field; bit-identical for any thread count.
std::vector<at::Tensor> composite_backward(const at::Tensor& packed, int64_t width, int64_t height,
                                           const at::Tensor& transmittance_in, const at::Tensor& last_in,
                                           const at::Tensor& offsets_in, const at::Tensor& ids_in,
                                           const at::Tensor& boxes_in, const at::Tensor& reached_in,
                                           const at::Tensor& grad_rgb_in, const at::Tensor& grad_depth_in,
                                           const at::Tensor& grad_alpha_in) {
  check_packed(packed);
  const auto dtype = packed.scalar_type();
  const at::Tensor transmittance = transmittance_in.contiguous();
  const at::Tensor last = last_in.contiguous(), offsets = offsets_in.contiguous(), ids = ids_in.contiguous();
  const at::Tensor boxes = boxes_in.contiguous(), reached = reached_in.contiguous();
  TORCH_CHECK(boxes.sizes() == at::IntArrayRef({packed.size(0), 5}) && boxes.scalar_type() == at::kInt,
              "boxes must be the (M,5) int32 tensor of the forward pass");
  TORCH_CHECK(offsets.scalar_type() == at::kInt && ids.scalar_type() == at::kInt &&
                  reached.scalar_type() == at::kLong && reached.numel() == ids.numel() && offsets.numel() >= 1,
              "tile lists must be the tensors of the forward pass");
  const at::Tensor grad_rgb = grad_rgb_in.to(dtype).contiguous();
  const at::Tensor grad_depth = grad_depth_in.to(dtype).contiguous();
  const at::Tensor grad_alpha = grad_alpha_in.to(dtype).contiguous();
  TORCH_CHECK(grad_rgb.sizes() == at::IntArrayRef({height, width, 3}), "grad_rgb must have shape (H,W,3)");
  TORCH_CHECK(grad_depth.sizes() == at::IntArrayRef({height, width}), "grad_depth must have shape (H,W)");
  TORCH_CHECK(grad_alpha.sizes() == at::IntArrayRef({height, width}), "grad_alpha must have shape (H,W)");
  const int64_t count = packed.size(0);
  at::Tensor entry_grads = at::empty({ids.numel(), rs::kFields}, packed.options());
  at::Tensor packed_grads = at::zeros({count, rs::kFields}, packed.options());
  const auto options = packed.options();
  at::Tensor grad_means2d = at::empty({count, 2}, options), grad_conics = at::empty({count, 3}, options);
  at::Tensor grad_colors = at::empty({count, 3}, options), grad_opacities = at::empty({count}, options);
  at::Tensor grad_depths = at::empty({count}, options);
  AT_DISPATCH_FLOATING_TYPES(dtype, "composite_backward", [&] {
    const rs::TileLists lists(offsets.data_ptr<int32_t>(), ids.data_ptr<int32_t>(),
                              reinterpret_cast<const rs::PixelBox*>(boxes.data_ptr<int32_t>()),
                              reinterpret_cast<const uint64_t*>(reached.data_ptr<int64_t>()), offsets.numel() - 1);
    const rs::BackwardInputs<scalar_t> in{transmittance.data_ptr<scalar_t>(), last.data_ptr<int32_t>(),
                                          grad_rgb.data_ptr<scalar_t>(), grad_depth.data_ptr<scalar_t>(),
                                          grad_alpha.data_ptr<scalar_t>()};
    scalar_t* sums = packed_grads.data_ptr<scalar_t>();
    rs::composite_backward(packed.data_ptr<scalar_t>(), count, width, height, at::get_num_threads(),
                           AtenParallelFor(), lists, in, entry_grads.data_ptr<scalar_t>(), sums);
    scalar_t *mean = grad_means2d.data_ptr<scalar_t>(), *conic = grad_conics.data_ptr<scalar_t>();
    scalar_t *rgb = grad_colors.data_ptr<scalar_t>(), *opacity = grad_opacities.data_ptr<scalar_t>();
    scalar_t* depth = grad_depths.data_ptr<scalar_t>();
    at::parallel_for(0, count, kSplatsPerTask, [&](int64_t begin, int64_t end) {
      for (int64_t i = begin; i < end; ++i) {
        const scalar_t* g = sums + i * rs::kFields;
        mean[2 * i] = g[0], mean[2 * i + 1] = g[1];
        conic[3 * i] = g[2], conic[3 * i + 1] = g[3], conic[3 * i + 2] = g[4];
        rgb[3 * i] = g[5], rgb[3 * i + 1] = g[6], rgb[3 * i + 2] = g[7];
        opacity[i] = g[8];
        depth[i] = g[9];
      }
    });
  });
  return {grad_means2d, grad_conics, grad_colors, grad_opacities, grad_depths};
}

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  m.def("project_forward", &project_forward, "EWA projection and SH colour of 3D Gaussians (forward)");
  m.def("project_backward", &project_backward, "EWA projection and SH colour of 3D Gaussians (backward)");
  m.def("composite_forward", &composite_forward, "Tile compositing of splats (forward)");
  m.def("composite_backward", &composite_backward, "Tile compositing of splats (backward)");
}

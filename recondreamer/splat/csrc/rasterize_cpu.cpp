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
  TORCH_CHECK(packed.device().is_cpu(), "packed splats must be on the CPU");
  TORCH_CHECK(packed.dim() == 2 && packed.size(1) == rs::kFields, "packed splats must have shape (M, 10)");
  TORCH_CHECK(packed.scalar_type() == at::kFloat || packed.scalar_type() == at::kDouble,
              "packed splats must be float32 or float64");
  TORCH_CHECK(packed.size(0) < (int64_t(1) << 31), "too many splats");
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

// Returns rgb (H,W,3), depth (H,W) accumulated, alpha (H,W), and for the backward pass:
// transmittance (H,W), last (H,W) int32, tile offsets (tiles+1) int32, tile ids (pairs) int32,
// support boxes (M,5) int32.
std::vector<at::Tensor> composite_forward(const at::Tensor& packed_in, int64_t width, int64_t height) {
  check_packed(packed_in);
  TORCH_CHECK(width > 0 && height > 0, "width and height must be positive");
  const at::Tensor packed = packed_in.contiguous();
  const auto options = packed.options();
  at::Tensor rgb = at::empty({height, width, 3}, options);
  at::Tensor depth = at::empty({height, width}, options);
  at::Tensor alpha = at::empty({height, width}, options);
  at::Tensor transmittance = at::empty({height, width}, options);
  at::Tensor last = at::empty({height, width}, options.dtype(at::kInt));
  at::Tensor offsets, ids, boxes = at::empty({packed.size(0), 5}, options.dtype(at::kInt));
  AT_DISPATCH_FLOATING_TYPES(packed.scalar_type(), "composite_forward", [&] {
    const rs::ForwardOutputs<scalar_t> out{rgb.data_ptr<scalar_t>(), depth.data_ptr<scalar_t>(),
                                           alpha.data_ptr<scalar_t>(), transmittance.data_ptr<scalar_t>(),
                                           last.data_ptr<int32_t>()};
    const rs::Binning binning = rs::composite_forward(packed.data_ptr<scalar_t>(), packed.size(0), width, height,
                                                      at::get_num_threads(), AtenParallelFor(), out);
    offsets = at::tensor(binning.offsets, options.dtype(at::kInt));
    ids = at::tensor(binning.ids, options.dtype(at::kInt));
    std::memcpy(boxes.data_ptr<int32_t>(), binning.boxes.data(), binning.boxes.size() * sizeof(rs::PixelBox));
  });
  return {rgb, depth, alpha, transmittance, last, offsets, ids, boxes};
}

// Gradient (M,10) of the loss with respect to the packed splats.
at::Tensor composite_backward(const at::Tensor& packed_in, int64_t width, int64_t height,
                              const at::Tensor& transmittance_in, const at::Tensor& last_in,
                              const at::Tensor& offsets_in, const at::Tensor& ids_in, const at::Tensor& boxes_in,
                              const at::Tensor& grad_rgb_in, const at::Tensor& grad_depth_in,
                              const at::Tensor& grad_alpha_in) {
  check_packed(packed_in);
  const at::Tensor packed = packed_in.contiguous();
  const auto dtype = packed.scalar_type();
  const at::Tensor transmittance = transmittance_in.contiguous();
  const at::Tensor last = last_in.contiguous(), offsets = offsets_in.contiguous(), ids = ids_in.contiguous();
  const at::Tensor boxes = boxes_in.contiguous();
  TORCH_CHECK(boxes.sizes() == at::IntArrayRef({packed.size(0), 5}) && boxes.scalar_type() == at::kInt,
              "boxes must be the (M,5) int32 tensor of the forward pass");
  const at::Tensor grad_rgb = grad_rgb_in.to(dtype).contiguous();
  const at::Tensor grad_depth = grad_depth_in.to(dtype).contiguous();
  const at::Tensor grad_alpha = grad_alpha_in.to(dtype).contiguous();
  TORCH_CHECK(grad_rgb.sizes() == at::IntArrayRef({height, width, 3}), "grad_rgb must have shape (H,W,3)");
  TORCH_CHECK(grad_depth.sizes() == at::IntArrayRef({height, width}), "grad_depth must have shape (H,W)");
  TORCH_CHECK(grad_alpha.sizes() == at::IntArrayRef({height, width}), "grad_alpha must have shape (H,W)");
  const int64_t count = packed.size(0);
  const int64_t workers = at::get_num_threads();
  at::Tensor buffers = at::zeros({workers, count, rs::kFields}, packed.options());
  AT_DISPATCH_FLOATING_TYPES(dtype, "composite_backward", [&] {
    rs::Binning binning;
    binning.offsets.assign(offsets.data_ptr<int32_t>(), offsets.data_ptr<int32_t>() + offsets.numel());
    binning.ids.assign(ids.data_ptr<int32_t>(), ids.data_ptr<int32_t>() + ids.numel());
    binning.boxes.resize(boxes.size(0));
    std::memcpy(binning.boxes.data(), boxes.data_ptr<int32_t>(), binning.boxes.size() * sizeof(rs::PixelBox));
    const rs::BackwardInputs<scalar_t> in{transmittance.data_ptr<scalar_t>(), last.data_ptr<int32_t>(),
                                          grad_rgb.data_ptr<scalar_t>(), grad_depth.data_ptr<scalar_t>(),
                                          grad_alpha.data_ptr<scalar_t>()};
    rs::composite_backward(packed.data_ptr<scalar_t>(), count, width, height, workers, AtenParallelFor(), binning,
                           in, buffers.data_ptr<scalar_t>());
  });
  return workers == 1 ? buffers[0] : buffers.sum(0);
}

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  m.def("project_forward", &project_forward, "EWA projection and SH colour of 3D Gaussians (forward)");
  m.def("project_backward", &project_backward, "EWA projection and SH colour of 3D Gaussians (backward)");
  m.def("composite_forward", &composite_forward, "Tile compositing of packed splats (forward)");
  m.def("composite_backward", &composite_backward, "Tile compositing of packed splats (backward)");
}

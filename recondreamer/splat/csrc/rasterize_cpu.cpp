// Torch bindings of the tile compositor in tile_compositor.h (forward and backward passes).

#include <torch/extension.h>

#include <ATen/Parallel.h>

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

}  // namespace

// Returns rgb (H,W,3), depth (H,W) accumulated, alpha (H,W), and for the backward pass:
// transmittance (H,W), last (H,W) int32, tile offsets (tiles+1) int32, tile ids (pairs) int32.
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
  at::Tensor offsets, ids;
  AT_DISPATCH_FLOATING_TYPES(packed.scalar_type(), "composite_forward", [&] {
    const rs::ForwardOutputs<scalar_t> out{rgb.data_ptr<scalar_t>(), depth.data_ptr<scalar_t>(),
                                           alpha.data_ptr<scalar_t>(), transmittance.data_ptr<scalar_t>(),
                                           last.data_ptr<int32_t>()};
    const rs::Binning binning = rs::composite_forward(packed.data_ptr<scalar_t>(), packed.size(0), width, height,
                                                      at::get_num_threads(), AtenParallelFor(), out);
    offsets = at::tensor(binning.offsets, options.dtype(at::kInt));
    ids = at::tensor(binning.ids, options.dtype(at::kInt));
  });
  return {rgb, depth, alpha, transmittance, last, offsets, ids};
}

// Gradient (M,10) of the loss with respect to the packed splats.
at::Tensor composite_backward(const at::Tensor& packed_in, int64_t width, int64_t height,
                              const at::Tensor& transmittance_in, const at::Tensor& last_in,
                              const at::Tensor& offsets_in, const at::Tensor& ids_in,
                              const at::Tensor& grad_rgb_in, const at::Tensor& grad_depth_in,
                              const at::Tensor& grad_alpha_in) {
  check_packed(packed_in);
  const at::Tensor packed = packed_in.contiguous();
  const auto dtype = packed.scalar_type();
  const at::Tensor transmittance = transmittance_in.contiguous();
  const at::Tensor last = last_in.contiguous(), offsets = offsets_in.contiguous(), ids = ids_in.contiguous();
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
    const rs::BackwardInputs<scalar_t> in{transmittance.data_ptr<scalar_t>(), last.data_ptr<int32_t>(),
                                          grad_rgb.data_ptr<scalar_t>(), grad_depth.data_ptr<scalar_t>(),
                                          grad_alpha.data_ptr<scalar_t>()};
    rs::composite_backward(packed.data_ptr<scalar_t>(), count, width, height, workers, AtenParallelFor(), binning,
                           in, buffers.data_ptr<scalar_t>());
  });
  return workers == 1 ? buffers[0] : buffers.sum(0);
}

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  m.def("composite_forward", &composite_forward, "Tile compositing of packed splats (forward)");
  m.def("composite_backward", &composite_backward, "Tile compositing of packed splats (backward)");
}

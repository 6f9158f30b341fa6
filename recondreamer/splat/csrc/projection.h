// EWA projection of 3D Gaussians to screen-space splats, with SH colour, forward and backward,
// one Gaussian at a time (no torch types). The rules and the order of operations are those of
// recondreamer/splat/projection.py and recondreamer/splat/sh.py (the oracle):
//   camera-space mean p = R m + t; culled when z <= kNearPlane (a safe depth 1 keeps the values
//   of culled Gaussians finite); mean2d = (fx x/z + cx, fy y/z + cy);
//   scaled axes a_k = s_k R R_q[:, k]; J rows evaluated at the view-angle-clamped (tx, ty, z);
//   cov2d = sum_k (J a_k)(J a_k)^T + kLowPass I; conic = cov2d^-1 as (a, b, c);
//   radii = ceil(3 sqrt(largest eigenvalue)), 0 when not visible;
//   SH colour max(sum_k c_k Y_k(d) + 0.5, 0), d the unit direction from the camera centre.
// The backward pass recomputes the forward values of its Gaussian and applies the chain rule by
// hand; gradients follow torch's conventions at kinks (clamp passes the gradient at its bounds).

#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>

namespace recondreamer_splat {

constexpr double kNearPlane = 0.01;
constexpr double kLowPass = 0.3;

constexpr double kShC0 = 0.28209479177387814;
constexpr double kShC1 = 0.4886025119029199;
constexpr double kShC2[5] = {1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792,
                             0.5462742152960396};
constexpr double kShC3[7] = {-0.5900435899266435, 2.890611442640554,  -0.4570457994644658, 0.3731763325901154,
                             -0.4570457994644658, 1.445305721320277,  -0.5900435899266435};

// Camera shared by all Gaussians of one call.
template <typename T>
struct Camera {
  T rotation[9];  // world-to-camera R, row-major
  T translation[3];
  T fx, fy, cx, cy;
  T centre[3];  // camera centre in world coordinates, -R^T t
  T clamp_x_lo, clamp_x_hi, clamp_y_lo, clamp_y_hi;  // bounds of x/z and y/z for the Jacobian
  int64_t width, height;

  Camera(const T* viewmat, const T* K, int64_t width_, int64_t height_) : width(width_), height(height_) {
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) rotation[3 * r + c] = viewmat[4 * r + c];
      translation[r] = viewmat[4 * r + 3];
    }
    fx = K[0];
    fy = K[4];
    cx = K[2];
    cy = K[5];
    for (int c = 0; c < 3; ++c)
      centre[c] = -(rotation[c] * translation[0] + rotation[3 + c] * translation[1] + rotation[6 + c] * translation[2]);
    const T half_tan_x = T(0.5) * T(width) / fx, half_tan_y = T(0.5) * T(height) / fy;
    clamp_x_lo = -(cx / fx + T(0.3) * half_tan_x);
    clamp_x_hi = (T(width) - cx) / fx + T(0.3) * half_tan_x;
    clamp_y_lo = -(cy / fy + T(0.3) * half_tan_y);
    clamp_y_hi = (T(height) - cy) / fy + T(0.3) * half_tan_y;
  }
};

// Forward values of one Gaussian that the backward pass needs again.
template <typename T>
struct Projected {
  T cam[3];          // camera-space mean
  T z_safe;          // z if in front, else 1
  bool in_front;
  T tx, ty;          // view-angle-clamped camera x, y
  bool tx_free, ty_free;  // the clamp passed x/z (y/z) through
  T unit_quat[4];    // w, x, y, z
  T quat_norm;
  T rotation_q[9];   // R(q), row-major: column k is world axis k
  T axes[3][3];      // axes[k] = s_k R R(q)[:, k], camera space
  T jx[3], jy[3];    // J row 0 . a_k, J row 1 . a_k
  T a, b, c, det;    // dilated 2D covariance [[a, b], [b, c]] and its determinant
};

template <typename T>
void project_one(const Camera<T>& camera, const T* mean, const T* quat, const T* scale, Projected<T>& p) {
  const T* R = camera.rotation;
  for (int r = 0; r < 3; ++r)
    p.cam[r] = (mean[0] * R[3 * r] + mean[1] * R[3 * r + 1] + mean[2] * R[3 * r + 2]) + camera.translation[r];
  p.in_front = p.cam[2] > T(kNearPlane);
  p.z_safe = p.in_front ? p.cam[2] : T(1);
  const T z = p.z_safe;
  const T x_over_z = p.cam[0] / z, y_over_z = p.cam[1] / z;
  p.tx_free = x_over_z >= camera.clamp_x_lo && x_over_z <= camera.clamp_x_hi;
  p.ty_free = y_over_z >= camera.clamp_y_lo && y_over_z <= camera.clamp_y_hi;
  p.tx = z * std::min(std::max(x_over_z, camera.clamp_x_lo), camera.clamp_x_hi);
  p.ty = z * std::min(std::max(y_over_z, camera.clamp_y_lo), camera.clamp_y_hi);

  p.quat_norm = std::sqrt(quat[0] * quat[0] + quat[1] * quat[1] + quat[2] * quat[2] + quat[3] * quat[3]);
  for (int i = 0; i < 4; ++i) p.unit_quat[i] = quat[i] / p.quat_norm;
  const T w = p.unit_quat[0], x = p.unit_quat[1], y = p.unit_quat[2], zq = p.unit_quat[3];
  T* Q = p.rotation_q;
  Q[0] = 1 - 2 * (y * y + zq * zq), Q[1] = 2 * (x * y - w * zq), Q[2] = 2 * (x * zq + w * y);
  Q[3] = 2 * (x * y + w * zq), Q[4] = 1 - 2 * (x * x + zq * zq), Q[5] = 2 * (y * zq - w * x);
  Q[6] = 2 * (x * zq - w * y), Q[7] = 2 * (y * zq + w * x), Q[8] = 1 - 2 * (x * x + y * y);
  const T jx_diag = camera.fx / z, jx_z = camera.fx * p.tx / (z * z);
  const T jy_diag = camera.fy / z, jy_z = camera.fy * p.ty / (z * z);
  for (int k = 0; k < 3; ++k) {
    for (int r = 0; r < 3; ++r)
      p.axes[k][r] = (Q[k] * R[3 * r] + Q[3 + k] * R[3 * r + 1] + Q[6 + k] * R[3 * r + 2]) * scale[k];
    p.jx[k] = jx_diag * p.axes[k][0] - jx_z * p.axes[k][2];
    p.jy[k] = jy_diag * p.axes[k][1] - jy_z * p.axes[k][2];
  }
  p.a = (p.jx[0] * p.jx[0] + p.jx[1] * p.jx[1] + p.jx[2] * p.jx[2]) + T(kLowPass);
  p.b = p.jx[0] * p.jy[0] + p.jx[1] * p.jy[1] + p.jx[2] * p.jy[2];
  p.c = (p.jy[0] * p.jy[0] + p.jy[1] * p.jy[1] + p.jy[2] * p.jy[2]) + T(kLowPass);
  p.det = p.a * p.c - p.b * p.b;
}

// Unit direction from the camera centre to the mean, and the length before normalising
// (torch.nn.functional.normalize: divided by max(length, 1e-12)).
template <typename T>
void view_direction(const Camera<T>& camera, const T* mean, T direction[3], T& length) {
  T v[3];
  for (int i = 0; i < 3; ++i) v[i] = mean[i] - camera.centre[i];
  length = std::max(std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]), T(1e-12));
  for (int i = 0; i < 3; ++i) direction[i] = v[i] / length;
}

// Real SH basis (C values) at the unit direction d, and when `gradient` is given, its partial
// derivatives: gradient[k] = dY_k/d(x, y, z).
template <typename T>
void sh_basis(const T d[3], int count, T* basis, T (*gradient)[3]) {
  const T x = d[0], y = d[1], z = d[2];
  basis[0] = T(kShC0);
  if (gradient) gradient[0][0] = gradient[0][1] = gradient[0][2] = 0;
  if (count <= 1) return;
  const T c1 = T(kShC1);
  basis[1] = -c1 * y, basis[2] = c1 * z, basis[3] = -c1 * x;
  if (gradient) {
    const T g[3][3] = {{0, -c1, 0}, {0, 0, c1}, {-c1, 0, 0}};
    for (int k = 0; k < 3; ++k) std::copy(g[k], g[k] + 3, gradient[1 + k]);
  }
  if (count <= 4) return;
  const T xx = x * x, yy = y * y, zz = z * z;
  const T c2[5] = {T(kShC2[0]), T(kShC2[1]), T(kShC2[2]), T(kShC2[3]), T(kShC2[4])};
  basis[4] = c2[0] * x * y;
  basis[5] = c2[1] * y * z;
  basis[6] = c2[2] * (2 * zz - xx - yy);
  basis[7] = c2[3] * x * z;
  basis[8] = c2[4] * (xx - yy);
  if (gradient) {
    const T g[5][3] = {{y, x, 0}, {0, z, y}, {-2 * x, -2 * y, 4 * z}, {z, 0, x}, {2 * x, -2 * y, 0}};
    for (int k = 0; k < 5; ++k)
      for (int i = 0; i < 3; ++i) gradient[4 + k][i] = c2[k] * g[k][i];
  }
  if (count <= 9) return;
  const T c3[7] = {T(kShC3[0]), T(kShC3[1]), T(kShC3[2]), T(kShC3[3]), T(kShC3[4]), T(kShC3[5]), T(kShC3[6])};
  basis[9] = c3[0] * y * (3 * xx - yy);
  basis[10] = c3[1] * x * y * z;
  basis[11] = c3[2] * y * (4 * zz - xx - yy);
  basis[12] = c3[3] * z * (2 * zz - 3 * xx - 3 * yy);
  basis[13] = c3[4] * x * (4 * zz - xx - yy);
  basis[14] = c3[5] * z * (xx - yy);
  basis[15] = c3[6] * x * (xx - 3 * yy);
  if (gradient) {
    const T g[7][3] = {{6 * x * y, 3 * xx - 3 * yy, 0},
                       {y * z, x * z, x * y},
                       {-2 * x * y, 4 * zz - xx - 3 * yy, 8 * y * z},
                       {-6 * x * z, -6 * y * z, 6 * zz - 3 * xx - 3 * yy},
                       {4 * zz - 3 * xx - yy, -2 * x * y, 8 * x * z},
                       {2 * x * z, -2 * y * z, xx - yy},
                       {3 * xx - 3 * yy, -6 * x * y, 0}};
    for (int k = 0; k < 7; ++k)
      for (int i = 0; i < 3; ++i) gradient[9 + k][i] = c3[k] * g[k][i];
  }
}

// Per-Gaussian outputs of the forward pass, (N,...) row-major.
template <typename T>
struct ProjectionOutputs {
  T* means2d;        // (N,2)
  T* conics;         // (N,3)
  T* depths;         // (N,) camera z
  T* rgb;            // (N,3) SH colour; unused (nullptr) without SH
  int32_t* radii;    // (N,)
  bool* in_front;    // (N,)
  bool* visible;     // (N,)
};

// sh: (N,C,3) coefficients or nullptr; C = sh_count.
template <typename T>
void project_forward_one(const Camera<T>& camera, int64_t i, const T* means, const T* quats, const T* scales,
                         const T* sh, int sh_count, const ProjectionOutputs<T>& out) {
  const T* mean = means + 3 * i;
  Projected<T> p;
  project_one(camera, mean, quats + 4 * i, scales + 3 * i, p);
  const T u = camera.fx * p.cam[0] / p.z_safe + camera.cx;
  const T v = camera.fy * p.cam[1] / p.z_safe + camera.cy;
  out.means2d[2 * i] = u;
  out.means2d[2 * i + 1] = v;
  out.conics[3 * i] = p.c / p.det;
  out.conics[3 * i + 1] = -p.b / p.det;
  out.conics[3 * i + 2] = p.a / p.det;
  out.depths[i] = p.cam[2];
  out.in_front[i] = p.in_front;

  const T mid = T(0.5) * (p.a + p.c);
  const T largest_eigenvalue = mid + std::sqrt(std::max(mid * mid - p.det, T(0)));
  const T radius = std::ceil(T(3) * std::sqrt(largest_eigenvalue));
  const bool overlaps = (u + radius > 0) && (u - radius < T(camera.width)) && (v + radius > 0) &&
                        (v - radius < T(camera.height));
  const bool visible = p.in_front && overlaps && radius > 0;
  out.visible[i] = visible;
  out.radii[i] = visible ? static_cast<int32_t>(radius) : 0;

  if (sh == nullptr) return;
  T direction[3], length, basis[16];
  view_direction(camera, mean, direction, length);
  sh_basis(direction, sh_count, basis, static_cast<T(*)[3]>(nullptr));
  const T* coefficients = sh + static_cast<int64_t>(sh_count) * 3 * i;
  for (int channel = 0; channel < 3; ++channel) {
    T total = 0;
    for (int k = 0; k < sh_count; ++k) total += basis[k] * coefficients[3 * k + channel];
    out.rgb[3 * i + channel] = std::max(total + T(0.5), T(0));
  }
}

// Incoming gradients (N,...) of the forward outputs; grad_rgb is nullptr without SH.
template <typename T>
struct ProjectionGradients {
  const T* means2d;  // (N,2)
  const T* conics;   // (N,3)
  const T* depths;   // (N,)
  const T* rgb;      // (N,3)
};

// Gradients with respect to the inputs, written (not accumulated) for Gaussian i.
template <typename T>
struct InputGradients {
  T* means;   // (N,3)
  T* quats;   // (N,4)
  T* scales;  // (N,3)
  T* sh;      // (N,C,3) or nullptr
};

template <typename T>
void project_backward_one(const Camera<T>& camera, int64_t i, const T* means, const T* quats, const T* scales,
                          const T* sh, int sh_count, const ProjectionGradients<T>& grad,
                          const InputGradients<T>& out) {
  // The backward pass is linear in the incoming gradients: a Gaussian that no output depends on
  // (off screen, hidden behind opaque splats, too faint: a quarter of them in the benchmark's
  // scene) gets exact zeros without recomputing its projection.
  bool no_gradient = grad.depths[i] == T(0);
  for (int k = 0; k < 2; ++k) no_gradient &= grad.means2d[2 * i + k] == T(0);
  for (int k = 0; k < 3; ++k)
    no_gradient &= grad.conics[3 * i + k] == T(0) && (sh == nullptr || grad.rgb[3 * i + k] == T(0));
  if (no_gradient) {
    std::fill(out.means + 3 * i, out.means + 3 * i + 3, T(0));
    std::fill(out.quats + 4 * i, out.quats + 4 * i + 4, T(0));
    std::fill(out.scales + 3 * i, out.scales + 3 * i + 3, T(0));
    if (sh != nullptr) std::fill(out.sh + int64_t(sh_count) * 3 * i, out.sh + int64_t(sh_count) * 3 * (i + 1), T(0));
    return;
  }
  const T* mean = means + 3 * i;
  const T* scale = scales + 3 * i;
  Projected<T> p;
  project_one(camera, mean, quats + 4 * i, scale, p);
  const T z = p.z_safe;
  const T* R = camera.rotation;

  // conic = (c, -b, a) / det
  const T g_p = grad.conics[3 * i], g_q = grad.conics[3 * i + 1], g_r = grad.conics[3 * i + 2];
  const T det2 = p.det * p.det;
  const T g_det = -(g_p * p.c - g_q * p.b + g_r * p.a) / det2;
  const T g_a = g_r / p.det + g_det * p.c;
  const T g_c = g_p / p.det + g_det * p.a;
  const T g_b = -g_q / p.det - T(2) * g_det * p.b;

  // jx_k = fx/z a_kx - fx tx/z^2 a_kz, jy_k = fy/z a_ky - fy ty/z^2 a_kz
  const T jx_diag = camera.fx / z, jx_z = camera.fx * p.tx / (z * z);
  const T jy_diag = camera.fy / z, jy_z = camera.fy * p.ty / (z * z);
  T g_axes[3][3];
  T g_jx_diag = 0, g_jx_z = 0, g_jy_diag = 0, g_jy_z = 0;
  for (int k = 0; k < 3; ++k) {
    const T g_jx = T(2) * g_a * p.jx[k] + g_b * p.jy[k];
    const T g_jy = T(2) * g_c * p.jy[k] + g_b * p.jx[k];
    g_axes[k][0] = g_jx * jx_diag;
    g_axes[k][1] = g_jy * jy_diag;
    g_axes[k][2] = -g_jx * jx_z - g_jy * jy_z;
    g_jx_diag += g_jx * p.axes[k][0];
    g_jx_z -= g_jx * p.axes[k][2];
    g_jy_diag += g_jy * p.axes[k][1];
    g_jy_z -= g_jy * p.axes[k][2];
  }
  // Through z_safe (only in front) and the clamped tx, ty.
  T g_cam[3] = {0, 0, grad.depths[i]};
  T g_z = -g_jx_diag * camera.fx / (z * z) - g_jy_diag * camera.fy / (z * z);
  g_z += -T(2) * g_jx_z * camera.fx * p.tx / (z * z * z) - T(2) * g_jy_z * camera.fy * p.ty / (z * z * z);
  const T g_tx = g_jx_z * camera.fx / (z * z), g_ty = g_jy_z * camera.fy / (z * z);
  // tx = z clamp(x/z): d/dx = 1, d/dz = 0 where the clamp passes; d/dz = the bound where it clamps.
  if (p.tx_free) {
    g_cam[0] += g_tx;
  } else {
    g_z += g_tx * (p.tx / z);
  }
  if (p.ty_free) {
    g_cam[1] += g_ty;
  } else {
    g_z += g_ty * (p.ty / z);
  }
  // means2d = (fx x/z + cx, fy y/z + cy)
  const T g_u = grad.means2d[2 * i], g_v = grad.means2d[2 * i + 1];
  g_cam[0] += g_u * camera.fx / z;
  g_cam[1] += g_v * camera.fy / z;
  g_z -= (g_u * camera.fx * p.cam[0] + g_v * camera.fy * p.cam[1]) / (z * z);
  if (p.in_front) g_cam[2] += g_z;

  // axes[k] = s_k R Q[:, k]
  T g_rotation_q[9];
  for (int k = 0; k < 3; ++k) {
    T world_axis_grad[3];  // R^T g_axes[k]
    for (int c = 0; c < 3; ++c)
      world_axis_grad[c] = R[c] * g_axes[k][0] + R[3 + c] * g_axes[k][1] + R[6 + c] * g_axes[k][2];
    const T* Q = p.rotation_q;
    out.scales[3 * i + k] = world_axis_grad[0] * Q[k] + world_axis_grad[1] * Q[3 + k] + world_axis_grad[2] * Q[6 + k];
    for (int r = 0; r < 3; ++r) g_rotation_q[3 * r + k] = world_axis_grad[r] * scale[k];
  }
  const T* G = g_rotation_q;
  const T w = p.unit_quat[0], x = p.unit_quat[1], y = p.unit_quat[2], zq = p.unit_quat[3];
  T g_unit[4];
  g_unit[0] = T(2) * (-zq * G[1] + y * G[2] + zq * G[3] - x * G[5] - y * G[6] + x * G[7]);
  g_unit[1] = T(2) * (y * G[1] + zq * G[2] + y * G[3] - T(2) * x * G[4] - w * G[5] + zq * G[6] + w * G[7] -
                      T(2) * x * G[8]);
  g_unit[2] = T(2) * (-T(2) * y * G[0] + x * G[1] + w * G[2] + x * G[3] + zq * G[5] - w * G[6] + zq * G[7] -
                      T(2) * y * G[8]);
  g_unit[3] = T(2) * (-T(2) * zq * G[0] - w * G[1] + x * G[2] + w * G[3] - T(2) * zq * G[4] + y * G[5] +
                      x * G[6] + y * G[7]);
  const T radial = g_unit[0] * w + g_unit[1] * x + g_unit[2] * y + g_unit[3] * zq;
  for (int j = 0; j < 4; ++j) out.quats[4 * i + j] = (g_unit[j] - radial * p.unit_quat[j]) / p.quat_norm;

  // cam = R mean + t
  T g_mean[3];
  for (int c = 0; c < 3; ++c) g_mean[c] = R[c] * g_cam[0] + R[3 + c] * g_cam[1] + R[6 + c] * g_cam[2];

  if (sh != nullptr) {
    T direction[3], length, basis[16], basis_gradient[16][3];
    view_direction(camera, mean, direction, length);
    sh_basis(direction, sh_count, basis, basis_gradient);
    const T* coefficients = sh + static_cast<int64_t>(sh_count) * 3 * i;
    T* g_coefficients = out.sh + static_cast<int64_t>(sh_count) * 3 * i;
    T g_rgb[3];
    for (int channel = 0; channel < 3; ++channel) {
      T total = 0;
      for (int k = 0; k < sh_count; ++k) total += basis[k] * coefficients[3 * k + channel];
      // clamp_min(., 0) passes the gradient where its input is >= 0.
      g_rgb[channel] = total + T(0.5) >= T(0) ? grad.rgb[3 * i + channel] : T(0);
    }
    T g_direction[3] = {0, 0, 0};
    for (int k = 0; k < sh_count; ++k) {
      T g_basis = 0;
      for (int channel = 0; channel < 3; ++channel) {
        g_coefficients[3 * k + channel] = basis[k] * g_rgb[channel];
        g_basis += coefficients[3 * k + channel] * g_rgb[channel];
      }
      for (int j = 0; j < 3; ++j) g_direction[j] += g_basis * basis_gradient[k][j];
    }
    // Below the 1e-12 floor the length is a constant and only the division remains.
    const bool floored = length <= T(1e-12);
    const T along = floored ? T(0) : g_direction[0] * direction[0] + g_direction[1] * direction[1] +
                                         g_direction[2] * direction[2];
    for (int j = 0; j < 3; ++j) g_mean[j] += (g_direction[j] - along * direction[j]) / length;
  }
  for (int c = 0; c < 3; ++c) out.means[3 * i + c] = g_mean[c];
}

}  // namespace recondreamer_splat

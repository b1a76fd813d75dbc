// Rendering a scene into tensors (synth/render.cpp): one ray per pixel centre
// (optionally n x n sub-pixel rays averaged for colour; depth always from the
// centre ray), depth as metric z-depth along the optical axis. A camera with
// lens distortion casts, for each pixel, the ray that the distortion model
// maps onto that pixel (LensRays), so images and depth are what the real
// distorted camera records. Images are identical for any thread count.
// LensRays' constructor needs OpenCV (long3r_synth_cv: cv/lens_rays.cpp).
#pragma once

#include <ATen/core/Tensor.h>

#include <Eigen/Geometry>

#include <cstddef>
#include <vector>

#include "long3r/geometry/pinhole_intrinsics.hpp"
#include "long3r/synth/geometry.hpp"

namespace long3r::synth {

// Lens distortion of the rendered camera: OpenCV's / ROS's plumb_bob.
struct LensDistortion {
  double k1 = 0.0, k2 = 0.0, p1 = 0.0, p2 = 0.0, k3 = 0.0;
  bool any() const { return k1 != 0.0 || k2 != 0.0 || p1 != 0.0 || p2 != 0.0 || k3 != 0.0; }
  std::vector<double> coefficients() const { return {k1, k2, p1, p2, k3}; }  // OpenCV's order
};

struct RenderOptions {
  int threads = 2;      // rows are split among this many std::threads
  int supersample = 1;  // n: n x n colour rays per pixel
  float gain = 1.0f;    // exposure: scales the linear radiance before encoding
};

// CPU tensors, row-major (the memory layout of the OpenCV images of the same
// content: cv/sensor_image.hpp makes those).
struct RenderedFrame {
  at::Tensor bgr;         // [H, W, 3] uint8, BGR order, sRGB-encoded
  at::Tensor depth;       // [H, W] float32, z-depth in metres (0 where no surface)
  at::Tensor surface_id;  // [H, W] int32, Hit::surface_id (-1 where no surface)
};
RenderedFrame render_frame(const Scene& scene, const Eigen::Isometry3d& T_W_C,
                           const PinholeIntrinsics& intrinsics, const RenderOptions& options = {});

// The rays of a camera with lens distortion: for every pixel centre (and the
// n x n sub-pixel samples of supersampling) the normalised ray (x, y, 1) that
// the plumb_bob model maps onto it, found with cv::undistortPoints (iterated
// to convergence and checked by projecting back), once per camera. The
// constructor is OpenCV's side (long3r_synth_cv); rendering with the table
// is not.
class LensRays {
 public:
  // Throws std::invalid_argument when the model cannot be inverted over the
  // image (a back-projected ray misses its pixel by more than 1e-6 px).
  LensRays(const PinholeIntrinsics& intrinsics, const LensDistortion& distortion,
           int supersample = 1);
  const PinholeIntrinsics& intrinsics() const { return k_; }
  int supersample() const { return n_; }
  // Normalised ray through pixel (u, v); sample s in [0, n*n) of its n x n grid.
  const Eigen::Vector2d& centre(int u, int v) const { return centre_[index(u, v)]; }
  const Eigen::Vector2d& sample(int u, int v, int s) const {
    return samples_[index(u, v) * n_ * n_ + s];
  }
  // Size of the pixel in normalised coordinates (sqrt of the Jacobian's
  // determinant; 1/f for a pinhole), for the texture filter footprint.
  double pixel_size(int u, int v) const { return pixel_size_[index(u, v)]; }

 private:
  size_t index(int u, int v) const { return static_cast<size_t>(v) * k_.width + u; }
  PinholeIntrinsics k_;
  int n_ = 1;
  std::vector<Eigen::Vector2d> centre_, samples_;
  std::vector<double> pixel_size_;
};
// Renders through a distorted lens: pixel (u, v) shows, and its depth is the
// z-depth of, what lies along rays.centre(u, v). options.supersample must
// equal rays.supersample().
RenderedFrame render_frame(const Scene& scene, const Eigen::Isometry3d& T_W_C, const LensRays& rays,
                           const RenderOptions& options = {});

}  // namespace long3r::synth

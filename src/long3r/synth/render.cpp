// CPU ray caster, rendering into tensors.
#include <ATen/ATen.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <stdexcept>
#include <thread>

#include "long3r/synth/geometry.hpp"
#include "long3r/synth/render.hpp"
#include "long3r/synth/texture.hpp"

namespace long3r::synth {

namespace {

// Linear [0, 1] -> sRGB-like 8-bit (gamma 2.2), tabulated.
const std::array<uint8_t, 4096>& gamma_table() {
  static const std::array<uint8_t, 4096> table = [] {
    std::array<uint8_t, 4096> t{};
    for (int i = 0; i < 4096; ++i) {
      t[i] = static_cast<uint8_t>(std::lround(255.0 * std::pow(i / 4095.0, 1.0 / 2.2)));
    }
    return t;
  }();
  return table;
}
inline uint8_t encode(float linear) {
  const int i = static_cast<int>(std::clamp(linear, 0.0f, 1.0f) * 4095.0f + 0.5f);
  return gamma_table()[i];
}

// Where pixels look. Pinhole: computed per pixel, as the renderer always has
// (the arithmetic is kept as it was, so its images stay bit-identical).
struct PinholeCamera {
  const PinholeIntrinsics& k;
  int width() const { return k.width; }
  int height() const { return k.height; }
  Eigen::Vector3d centre(int u, int v) const { return {(u - k.cx) / k.fx, (v - k.cy) / k.fy, 1.0}; }
  Eigen::Vector3d sample(int u, int v, int sx, int sy, int n) const {
    const double du = (sx + 0.5) / n - 0.5, dv = (sy + 0.5) / n - 0.5;
    return {(u + du - k.cx) / k.fx, (v + dv - k.cy) / k.fy, 1.0};
  }
  // Metres per pixel at z-depth t (per sub-pixel with n x n samples).
  double footprint(int, int, double t) const { return t / k.fx; }
  double sample_footprint(int, int, double t, int n) const { return t / (k.fx * n); }
};

// Distorted lens: rays from the table.
struct LensCamera {
  const LensRays& rays;
  int width() const { return rays.intrinsics().width; }
  int height() const { return rays.intrinsics().height; }
  Eigen::Vector3d centre(int u, int v) const { return rays.centre(u, v).homogeneous(); }
  Eigen::Vector3d sample(int u, int v, int sx, int sy, int n) const {
    return rays.sample(u, v, sy * n + sx).homogeneous();
  }
  double footprint(int u, int v, double t) const { return t * rays.pixel_size(u, v); }
  double sample_footprint(int u, int v, double t, int n) const {
    return t * rays.pixel_size(u, v) / n;
  }
};

template <class Camera>
void render_rows(const Scene& scene, const Eigen::Isometry3d& T, const Camera& cam,
                 const RenderOptions& options, int row_begin, int row_step, RenderedFrame* out) {
  const Eigen::Matrix3d R = T.linear();
  const Eigen::Vector3d o = T.translation();
  const int n = std::max(1, options.supersample);
  const float gain = options.gain;
  const int64_t width = cam.width();
  for (int v = row_begin; v < cam.height(); v += row_step) {
    uint8_t* bgr = out->bgr.data_ptr<uint8_t>() + 3 * width * v;
    float* depth = out->depth.data_ptr<float>() + width * v;
    int32_t* sid = out->surface_id.data_ptr<int32_t>() + width * v;
    for (int u = 0; u < cam.width(); ++u) {
      Hit hit;
      Eigen::Vector3f colour = Eigen::Vector3f::Zero();
      const Eigen::Vector3d d = R * cam.centre(u, v);
      if (intersect(scene, o, d, &hit)) {
        depth[u] = static_cast<float>(hit.t);  // t along R * (x, y, 1) is the z-depth
        sid[u] = hit.surface_id;
      } else {
        depth[u] = 0.0f;
        sid[u] = -1;
      }
      if (n == 1) {
        if (sid[u] >= 0) {
          const double cos_inc = std::max(0.25, std::abs(hit.normal.dot(d.normalized())));
          colour = shade(scene, hit, cam.footprint(u, v, hit.t) / cos_inc);
        }
      } else {
        for (int sy = 0; sy < n; ++sy) {
          for (int sx = 0; sx < n; ++sx) {
            const Eigen::Vector3d ds = R * cam.sample(u, v, sx, sy, n);
            Hit h;
            if (!intersect(scene, o, ds, &h)) continue;
            const double cos_inc = std::max(0.25, std::abs(h.normal.dot(ds.normalized())));
            colour += shade(scene, h, cam.sample_footprint(u, v, h.t, n) / cos_inc);
          }
        }
        colour /= static_cast<float>(n * n);
      }
      colour *= gain;  // exposure; exact for the default gain 1
      bgr[3 * u] = encode(colour.z());
      bgr[3 * u + 1] = encode(colour.y());
      bgr[3 * u + 2] = encode(colour.x());
    }
  }
}

void check_scene(const Scene& scene) {
  for (const Shape& s : scene.shapes) {
    if (s.material < 0 || s.material >= static_cast<int>(scene.materials.size())) {
      throw std::invalid_argument("render_frame: shape material out of range");
    }
  }
  for (int m : scene.room_material) {
    if (m < 0 || m >= static_cast<int>(scene.materials.size())) {
      throw std::invalid_argument("render_frame: room material out of range");
    }
  }
}

template <class Camera>
RenderedFrame render_with(const Scene& scene, const Eigen::Isometry3d& T_W_C, const Camera& cam,
                          const RenderOptions& options) {
  check_scene(scene);
  RenderedFrame out;
  out.bgr = at::empty({cam.height(), cam.width(), 3}, at::kByte);
  out.depth = at::empty({cam.height(), cam.width()}, at::kFloat);
  out.surface_id = at::empty({cam.height(), cam.width()}, at::kInt);
  gamma_table();  // build before the threads start
  const int threads = std::clamp(options.threads, 1, std::max(1, cam.height()));
  if (threads == 1) {
    render_rows(scene, T_W_C, cam, options, 0, 1, &out);
    return out;
  }
  // Interleaved rows balance the load (the top and bottom of a view differ in cost).
  std::vector<std::thread> pool;
  for (int t = 0; t < threads; ++t) {
    pool.emplace_back([&, t] { render_rows(scene, T_W_C, cam, options, t, threads, &out); });
  }
  for (auto& th : pool) th.join();
  return out;
}

}  // namespace

RenderedFrame render_frame(const Scene& scene, const Eigen::Isometry3d& T_W_C,
                           const PinholeIntrinsics& k, const RenderOptions& options) {
  if (!k.valid() || k.width < 1 || k.height < 1) {
    throw std::invalid_argument("render_frame: invalid intrinsics");
  }
  return render_with(scene, T_W_C, PinholeCamera{k}, options);
}

RenderedFrame render_frame(const Scene& scene, const Eigen::Isometry3d& T_W_C, const LensRays& rays,
                           const RenderOptions& options) {
  if (std::max(1, options.supersample) != rays.supersample()) {
    throw std::invalid_argument("render_frame: the lens rays were made for another supersample");
  }
  return render_with(scene, T_W_C, LensCamera{rays}, options);
}

}  // namespace long3r::synth

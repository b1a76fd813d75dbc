// Lens distortion as the rays each pixel sees (OpenCV's plumb_bob inverse).
#include <opencv2/calib3d.hpp>

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "long3r/synth/render.hpp"

namespace long3r::synth {

namespace {

// Normalised rays (x, y) of pixel positions, by inverting plumb_bob: OpenCV's
// fixed-point iteration run until the reprojection error is below 1e-10 px,
// then every ray projected back with cv::projectPoints as the check.
std::vector<Eigen::Vector2d> undistort(const std::vector<cv::Point2d>& pixels, const cv::Matx33d& K,
                                       const std::vector<double>& D) {
  std::vector<cv::Point2d> rays;
  cv::undistortPoints(
      pixels, rays, K, D, cv::noArray(), cv::noArray(),
      cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 1000, 1e-10));
  std::vector<cv::Point3d> points(rays.size());
  for (size_t i = 0; i < rays.size(); ++i) points[i] = cv::Point3d(rays[i].x, rays[i].y, 1.0);
  std::vector<cv::Point2d> back;
  cv::projectPoints(points, cv::Vec3d::zeros(), cv::Vec3d::zeros(), K, D, back);
  std::vector<Eigen::Vector2d> out(rays.size());
  for (size_t i = 0; i < rays.size(); ++i) {
    const double err = cv::norm(back[i] - pixels[i]);
    if (!(err < 1e-6)) {
      throw std::invalid_argument("LensRays: the plumb_bob model cannot be inverted at pixel (" +
                                  std::to_string(pixels[i].x) + ", " + std::to_string(pixels[i].y) +
                                  "): its ray projects " + std::to_string(err) +
                                  " px away (distortion too strong)");
    }
    out[i] = Eigen::Vector2d(rays[i].x, rays[i].y);
  }
  return out;
}

}  // namespace

LensRays::LensRays(const PinholeIntrinsics& k, const LensDistortion& distortion, int supersample)
    : k_(k), n_(std::max(1, supersample)) {
  if (!k.valid() || k.width < 1 || k.height < 1) {
    throw std::invalid_argument("LensRays: invalid intrinsics");
  }
  const cv::Matx33d K(k.fx, 0, k.cx, 0, k.fy, k.cy, 0, 0, 1);
  const std::vector<double> D = distortion.coefficients();
  std::vector<cv::Point2d> pixels;
  pixels.reserve(static_cast<size_t>(k.width) * k.height);
  for (int v = 0; v < k.height; ++v) {
    for (int u = 0; u < k.width; ++u) pixels.emplace_back(u, v);
  }
  centre_ = undistort(pixels, K, D);
  if (n_ > 1) {
    // Sub-pixel sample positions as the pinhole renderer places them.
    std::vector<cv::Point2d> sub;
    sub.reserve(pixels.size() * n_ * n_);
    for (const cv::Point2d& p : pixels) {
      for (int sy = 0; sy < n_; ++sy) {
        for (int sx = 0; sx < n_; ++sx) {
          sub.emplace_back(p.x + (sx + 0.5) / n_ - 0.5, p.y + (sy + 0.5) / n_ - 0.5);
        }
      }
    }
    samples_ = undistort(sub, K, D);
  }
  // Pixel footprint from the Jacobian of pixel -> ray (central differences;
  // one-sided at the border; the pinhole value in a one-pixel dimension).
  pixel_size_.resize(centre_.size());
  for (int v = 0; v < k.height; ++v) {
    for (int u = 0; u < k.width; ++u) {
      Eigen::Vector2d du(1.0 / k.fx, 0.0), dv(0.0, 1.0 / k.fy);
      if (k.width > 1) {
        const int a = std::max(0, u - 1), b = std::min(k.width - 1, u + 1);
        du = (centre(b, v) - centre(a, v)) / (b - a);
      }
      if (k.height > 1) {
        const int a = std::max(0, v - 1), b = std::min(k.height - 1, v + 1);
        dv = (centre(u, b) - centre(u, a)) / (b - a);
      }
      pixel_size_[index(u, v)] = std::sqrt(std::abs(du.x() * dv.y() - du.y() * dv.x()));
    }
  }
}

}  // namespace long3r::synth

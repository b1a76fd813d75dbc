// What a real camera adds to the ideal render: lens distortion (as the rays
// each pixel sees), exposure changes and sensor noise, mono output.
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "long3r/synth/synth.hpp"

namespace long3r::synth {

namespace {

// derived_seed streams (arbitrary distinct constants).
constexpr uint64_t kExposureStream = 0x6578706f73757265ull;  // "exposure"
constexpr uint64_t kNoiseStream = 0x6e6f697365000000ull;     // "noise" + frame index

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

cv::Mat apply_sensor(const cv::Mat& bgr, const SensorConfig& sensor, uint64_t seed, int index) {
  if (!sensor.mono && !sensor.noise()) return bgr;
  cv::Mat out;
  if (sensor.mono) {
    cv::cvtColor(bgr, out, cv::COLOR_BGR2GRAY);
  } else {
    out = bgr.clone();
  }
  if (sensor.noise()) {
    Rng rng(derived_seed(seed, kNoiseStream + static_cast<uint64_t>(index)));
    const double read2 = sensor.read_noise * sensor.read_noise;
    const int values = out.cols * out.channels();
    for (int r = 0; r < out.rows; ++r) {
      uint8_t* p = out.ptr<uint8_t>(r);
      for (int i = 0; i < values; ++i) {
        const double sigma = std::sqrt(read2 + sensor.shot_noise * p[i]);
        const double noisy = p[i] + sigma * rng.normal();
        p[i] = static_cast<uint8_t>(std::clamp(std::lround(noisy), 0L, 255L));
      }
    }
  }
  return out;
}

std::vector<double> exposure_gains(const SensorConfig& sensor, uint64_t seed,
                                   const std::vector<double>& stamps) {
  std::vector<double> gains(stamps.size(), 1.0);
  if (!sensor.exposure() || stamps.empty()) return gains;
  Rng rng(derived_seed(seed, kExposureStream));
  const double w1 = 2 * M_PI / rng.uniform(6.0, 12.0), p1 = rng.uniform(0.0, 2 * M_PI);
  const double w2 = 2 * M_PI / rng.uniform(2.5, 5.0), p2 = rng.uniform(0.0, 2 * M_PI);
  const double log_step = std::log1p(sensor.exposure_step);
  double step = 1.0;
  for (size_t i = 0; i < stamps.size(); ++i) {
    if (sensor.exposure_step_prob > 0.0 && rng.bernoulli(sensor.exposure_step_prob)) {
      step = std::exp(rng.uniform(-1.0, 1.0) * log_step);
    }
    const double t = stamps[i] - stamps[0];
    const double wave = 0.6 * std::sin(w1 * t + p1) + 0.4 * std::sin(w2 * t + p2);
    gains[i] = (1.0 + sensor.exposure_drift * wave) * step;
  }
  return gains;
}

}  // namespace long3r::synth

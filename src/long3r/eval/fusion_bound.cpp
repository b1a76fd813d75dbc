#include "long3r/eval/fusion_bound.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "long3r/geometry/statistics.hpp"

namespace long3r {

namespace {

// 21 bits per axis, biased: voxel indices within +-2^20 (20 km at 2 cm).
std::uint64_t voxel_key(const Eigen::Vector3d& p, double voxel_size_m) {
  constexpr std::int64_t kBias = std::int64_t{1} << 20;
  constexpr std::uint64_t kMask = (std::uint64_t{1} << 21) - 1;
  std::uint64_t key = 0;
  for (int a = 0; a < 3; ++a) {
    const auto i = static_cast<std::int64_t>(std::floor(p[a] / voxel_size_m)) + kBias;
    key = (key << 21) | (static_cast<std::uint64_t>(i) & kMask);
  }
  return key;
}

bool usable(const cv::Vec3f& p) {
  return std::isfinite(p[0]) && std::isfinite(p[1]) && std::isfinite(p[2]) && p[2] > 0.0f;
}

}  // namespace

cv::Mat true_points_at_pixels(const cv::Mat& depth_m, const PinholeIntrinsics& depth_K,
                              const PinholeIntrinsics& model_K, cv::Size model_size) {
  if (depth_m.empty() || depth_m.type() != CV_32FC1) {
    throw std::invalid_argument("true_points_at_pixels: the depth must be CV_32FC1 metres");
  }
  if (!(depth_K.fx > 0 && depth_K.fy > 0 && model_K.fx > 0 && model_K.fy > 0)) {
    throw std::invalid_argument("true_points_at_pixels: intrinsics without a focal length");
  }
  const float nan = std::numeric_limits<float>::quiet_NaN();
  cv::Mat out(model_size, CV_32FC3, cv::Scalar::all(nan));
  for (int v = 0; v < model_size.height; ++v) {
    for (int u = 0; u < model_size.width; ++u) {
      // The pixel's ray (z = 1), then where it meets the depth image.
      const double x = (u - model_K.cx) / model_K.fx, y = (v - model_K.cy) / model_K.fy;
      const long us = std::lround(depth_K.fx * x + depth_K.cx);
      const long vs = std::lround(depth_K.fy * y + depth_K.cy);
      if (us < 0 || vs < 0 || us >= depth_m.cols || vs >= depth_m.rows) continue;
      const float z = depth_m.at<float>(static_cast<int>(vs), static_cast<int>(us));
      if (!(std::isfinite(z) && z > 0.0f)) continue;
      out.at<cv::Vec3f>(v, u) = cv::Vec3f(static_cast<float>(x * z), static_cast<float>(y * z), z);
    }
  }
  return out;
}

FusionBound::FusionBound(double voxel_size_m) : voxel_size_m_(voxel_size_m) {
  if (!(voxel_size_m > 0.0)) throw std::invalid_argument("FusionBound: voxel_size_m must be > 0");
}

void FusionBound::add(const cv::Mat& predicted_C, const cv::Mat& true_C,
                      const Eigen::Isometry3d& T_W_C) {
  if (predicted_C.type() != CV_32FC3 || true_C.type() != CV_32FC3 ||
      predicted_C.size() != true_C.size()) {
    throw std::invalid_argument(
        "FusionBound::add: predicted and true points must be CV_32FC3 "
        "images of one size");
  }
  std::vector<double> ratios;
  for (int v = 0; v < predicted_C.rows; ++v) {
    for (int u = 0; u < predicted_C.cols; ++u) {
      const cv::Vec3f& p = predicted_C.at<cv::Vec3f>(v, u);
      const cv::Vec3f& t = true_C.at<cv::Vec3f>(v, u);
      if (usable(p) && usable(t)) ratios.push_back(static_cast<double>(p[2]) / t[2]);
    }
  }
  if (ratios.empty()) {
    ++frames_;
    return;
  }
  const double ratio = median(ratios);
  depth_ratios_.push_back(ratio);
  for (int v = 0; v < predicted_C.rows; ++v) {
    for (int u = 0; u < predicted_C.cols; ++u) {
      const cv::Vec3f& p = predicted_C.at<cv::Vec3f>(v, u);
      const cv::Vec3f& t = true_C.at<cv::Vec3f>(v, u);
      if (!usable(p) || !usable(t)) continue;
      const Eigen::Vector3d p_C(p[0], p[1], p[2]);
      const Eigen::Vector3d p_W = T_W_C * p_C;
      const Eigen::Vector3d t_W = T_W_C * Eigen::Vector3d(t[0], t[1], t[2]);
      Voxel& vox = voxels_[voxel_key(t_W, voxel_size_m_)];
      vox.sum_predicted += p_W;
      vox.sum_rescaled += T_W_C * (p_C / ratio);
      vox.sum_true += t_W;
      vox.sum_error += (p_W - t_W).norm();
      ++vox.pairs;
      if (vox.last_frame != frames_) {
        vox.last_frame = frames_;
        ++vox.views;
      }
      ++pairs_;
    }
  }
  ++frames_;
}

std::vector<Eigen::Vector3f> FusionBound::averaged_points(bool rescaled) const {
  std::vector<Eigen::Vector3f> out;
  out.reserve(voxels_.size());
  for (const auto& [key, vox] : voxels_) {
    out.push_back(((rescaled ? vox.sum_rescaled : vox.sum_predicted) / vox.pairs).cast<float>());
  }
  return out;
}

FusionBoundSummary FusionBound::summary() const {
  FusionBoundSummary s;
  s.frames = static_cast<std::size_t>(frames_);
  s.pairs = pairs_;
  s.voxels = voxels_.size();
  std::vector<double> single, averaged, rescaled;
  single.reserve(voxels_.size());
  averaged.reserve(voxels_.size());
  rescaled.reserve(voxels_.size());
  double views = 0;
  for (const auto& [key, vox] : voxels_) {
    single.push_back(vox.sum_error / vox.pairs);
    averaged.push_back(((vox.sum_predicted - vox.sum_true) / vox.pairs).norm());
    rescaled.push_back(((vox.sum_rescaled - vox.sum_true) / vox.pairs).norm());
    views += vox.views;
  }
  s.mean_views = voxels_.empty() ? 0.0 : views / static_cast<double>(voxels_.size());
  s.single_view_m = error_statistics(single);
  s.averaged_m = error_statistics(averaged);
  s.averaged_rescaled_m = error_statistics(rescaled);
  s.depth_ratio = depth_ratios_;
  if (!depth_ratios_.empty()) {
    s.depth_ratio_median = median(depth_ratios_);
    std::vector<double> dev;
    for (double r : depth_ratios_) dev.push_back(std::abs(r - s.depth_ratio_median));
    s.depth_ratio_mad = median(dev);
  }
  return s;
}

}  // namespace long3r

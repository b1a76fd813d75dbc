#include "long3r/mapping/surface_map.hpp"

#include <cmath>
#include <stdexcept>
#include <utility>

namespace long3r {

void SurfaceMapConfig::validate(const config::FieldCheck& check) const {
  tsdf.validate(check.nested("tsdf", ""));
  check.require(keep_frames >= 0, "keep_frames", "must be >= 0");
}

SurfaceMap::SurfaceMap(const SurfaceMapConfig& config) : config_(config) {
  config.validate({"surface config", ""});
  if (config_.enabled) volume_ = std::make_unique<TsdfVolume>(config_.tsdf);
}

std::size_t SurfaceMap::integrate(const cv::Mat& points_C, const cv::Mat& rgb, const cv::Mat& conf,
                                  float conf_threshold, const PinholeIntrinsics& K,
                                  const Eigen::Isometry3d& T_W_C) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (!volume_) return 0;
  auto [depth, used] = volume_->depth_of(points_C, conf, conf_threshold);
  const cv::Mat rgb_copy = rgb.clone();
  volume_->integrate_depth(depth, rgb_copy, K, T_W_C);
  ++revision_;
  if (config_.keep_frames > 0) {
    kept_.push_back({std::move(depth), rgb_copy, K, T_W_C});
    while (kept_.size() > static_cast<std::size_t>(config_.keep_frames)) {
      kept_.pop_front();
      ++dropped_;
    }
  } else {
    ++dropped_;
  }
  return used;
}

void SurfaceMap::rescale(double factor) {
  if (!(factor > 0.0 && std::isfinite(factor))) {
    throw std::invalid_argument("SurfaceMap::rescale: factor must be positive and finite");
  }
  std::lock_guard<std::mutex> lock(mutex_);
  if (!volume_ || factor == 1.0) return;
  volume_->clear();
  for (Kept& k : kept_) {
    k.depth.convertTo(k.depth, CV_32FC1, factor);
    k.T_W_C.translation() *= factor;
    volume_->integrate_depth(k.depth, k.rgb, k.K, k.T_W_C);
  }
  ++revision_;
}

void SurfaceMap::clear() {
  std::lock_guard<std::mutex> lock(mutex_);
  if (volume_) volume_->clear();
  kept_.clear();
  dropped_ = 0;
  ++revision_;
}

ColoredPoints SurfaceMap::points() const {
  std::lock_guard<std::mutex> lock(mutex_);
  if (!volume_) return {};
  if (!points_cache_ || points_cache_->first != revision_) {
    points_cache_.emplace(revision_, volume_->extract_points());
  }
  return points_cache_->second;
}

ColoredMesh SurfaceMap::mesh() const {
  std::lock_guard<std::mutex> lock(mutex_);
  if (!volume_) return {};
  if (!mesh_cache_ || mesh_cache_->first != revision_) {
    mesh_cache_.emplace(revision_, volume_->extract_mesh());
  }
  return mesh_cache_->second;
}

std::uint64_t SurfaceMap::revision() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return revision_;
}
std::size_t SurfaceMap::frames_kept() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return kept_.size();
}
std::size_t SurfaceMap::frames_dropped() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return dropped_;
}

}  // namespace long3r

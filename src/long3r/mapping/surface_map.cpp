#include "long3r/mapping/surface_map.hpp"

#include <ATen/ATen.h>

#include "long3r/mapping/state_geometry.hpp"

#include <cmath>
#include <stdexcept>
#include <string>
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

StateDict SurfaceMap::state() const {
  std::lock_guard<std::mutex> lock(mutex_);
  StateDict out;
  put_int(out, "frames", static_cast<int64_t>(kept_.size()));
  put_int(out, "dropped", static_cast<int64_t>(dropped_));
  for (std::size_t i = 0; i < kept_.size(); ++i) {
    const Kept& k = kept_[i];
    const std::string at = std::to_string(i) + ".";
    // Kept frames are continuous (made by depth_of() and clone()).
    out[at + "depth"] =
        at::from_blob(k.depth.data, {k.depth.rows, k.depth.cols}, at::kFloat).clone();
    out[at + "rgb"] = at::from_blob(k.rgb.data, {k.rgb.rows, k.rgb.cols, 3}, at::kByte).clone();
    out[at + "K"] = intrinsics_to_tensor(k.K);
    out[at + "T_W_C"] = pose_to_tensor(k.T_W_C);
  }
  return out;
}

void SurfaceMap::restore(const StateReader& r) {
  if (!config_.enabled) return;
  constexpr int64_t kMaxSide = 1 << 14;
  const int64_t n = r.integer("frames", 0, config_.keep_frames);
  const int64_t dropped = r.integer("dropped", 0, int64_t{1} << 53);
  std::deque<Kept> kept;
  for (int64_t i = 0; i < n; ++i) {
    const std::string at = std::to_string(i) + ".";
    const at::Tensor depth = r.floating(at + "depth", {-1, -1}).to(at::kFloat).contiguous();
    const int64_t h = depth.size(0), w = depth.size(1);
    if (h < 1 || w < 1 || h > kMaxSide || w > kMaxSide) r.fail(at + "depth", "not an image size");
    if (depth.min().item<float>() < 0.0f) r.fail(at + "depth", "holds negative depths");
    const at::Tensor rgb = r.uint8(at + "rgb", {h, w, 3}).contiguous();
    Kept k;
    k.depth = cv::Mat(static_cast<int>(h), static_cast<int>(w), CV_32FC1,
                      const_cast<float*>(depth.data_ptr<float>()))
                  .clone();
    k.rgb = cv::Mat(static_cast<int>(h), static_cast<int>(w), CV_8UC3,
                    const_cast<std::uint8_t*>(rgb.data_ptr<std::uint8_t>()))
                .clone();
    k.K = read_intrinsics(r, at + "K");
    k.T_W_C = read_pose(r, at + "T_W_C");
    kept.push_back(std::move(k));
  }
  // The volume rebuilt apart, so that the running one stays whole until the
  // rebuilt one takes its place.
  auto volume = std::make_unique<TsdfVolume>(config_.tsdf);
  for (const Kept& k : kept) volume->integrate_depth(k.depth, k.rgb, k.K, k.T_W_C);
  std::lock_guard<std::mutex> lock(mutex_);
  volume_ = std::move(volume);
  kept_ = std::move(kept);
  dropped_ = static_cast<std::size_t>(dropped);
  ++revision_;
}

void SurfaceMap::swap(SurfaceMap& other) {
  if (&other == this) return;
  std::scoped_lock lock(mutex_, other.mutex_);
  std::swap(config_, other.config_);
  std::swap(volume_, other.volume_);
  std::swap(kept_, other.kept_);
  std::swap(dropped_, other.dropped_);
  ++revision_;
  ++other.revision_;
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

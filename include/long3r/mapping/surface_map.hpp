// The stream's fused surface: a TsdfVolume (tsdf_volume.hpp) fed with every
// mapped frame, which keeps those frames so that it can be rebuilt, since a
// TSDF cannot be rescaled in place (the metric scale arrives, or is refined).
//
// Frames: W, the stream's world (camera 0); lengths in the stream's scale,
// like the voxel map's. A kept frame is its depth image (z of its points in
// its camera frame C, 0 where left out), colours, intrinsics and T_W_C.
//
// Thread safety: every member function locks an internal mutex, so the ROS
// layer may take points() or mesh() from its timer while frames are fused;
// both are extracted once per revision and cached.
#pragma once

#include <Eigen/Geometry>
#include <opencv2/core.hpp>

#include <cstddef>
#include <cstdint>
#include <deque>
#include <memory>
#include <mutex>
#include <optional>

#include "long3r/config/config_fields.hpp"
#include "long3r/mapping/tsdf_volume.hpp"
#include "long3r/model/loading/state_dict.hpp"

namespace long3r {

struct SurfaceMapConfig {
  static constexpr int kDefaultKeepFrames = 1000;

  bool enabled = false;
  TsdfConfig tsdf;
  // Frames kept for rebuilds, the oldest dropped first (a 224 x 224 frame
  // takes 0.35 MB). A rebuild fuses only the frames still kept.
  int keep_frames = kDefaultKeepFrames;

  // Throws ConfigError naming the field.
  void validate(const config::FieldCheck& check) const;
};

// Flat names surface_<field> (ReconstructionConfig nests it as "surface_").
template <class S, class V>
config::FieldsOf<S, SurfaceMapConfig> visit_fields(S& s, V& v) {
  v("enabled", s.enabled);
  v.nested("tsdf", s.tsdf, "");
  v("keep_frames", s.keep_frames);
}

class SurfaceMap {
 public:
  // Throws ConfigError (config.validate()), std::runtime_error without
  // Open3D when enabled.
  explicit SurfaceMap(const SurfaceMapConfig& config = {});

  // One mapped frame (TsdfVolume::integrate's arguments), kept for rebuilds.
  // Returns the pixels fused. Throws what TsdfVolume::integrate throws;
  // nothing changes then.
  std::size_t integrate(const cv::Mat& points_C, const cv::Mat& rgb, const cv::Mat& conf,
                        float conf_threshold, const PinholeIntrinsics& K,
                        const Eigen::Isometry3d& T_W_C);
  // Every length times `factor` (about W's origin): the volume is rebuilt
  // from the kept frames, their depths and positions scaled. Throws
  // std::invalid_argument unless factor is finite and > 0.
  void rescale(double factor);
  void clear();

  // The surface (coloured points) and its mesh, in W.
  ColoredPoints points() const;
  ColoredMesh mesh() const;
  // Changes whenever the surface does.
  std::uint64_t revision() const;
  std::size_t frames_kept() const;
  std::size_t frames_dropped() const;  // fused, but no longer kept for rebuilds
  const SurfaceMapConfig& config() const { return config_; }

  // The kept frames, for sessions (state_dict.hpp): "frames", "dropped" and
  // per frame i "<i>.depth" [H, W] float32, "<i>.rgb" [H, W, 3] uint8,
  // "<i>.K" and "<i>.T_W_C" (state_geometry.hpp). The volume is not saved:
  // restore() rebuilds it from them, so a restored surface holds the kept
  // frames only (all of them unless more than keep_frames were fused).
  StateDict state() const;
  // Throws StateError naming the part (a frame more than keep_frames counts
  // as damage); nothing changes then. A disabled map takes nothing.
  void restore(const StateReader& state);
  // Exchanges the two maps, volume, frames and config (a restored session's
  // surface takes the running one's place; an ended stream's is kept apart).
  void swap(SurfaceMap& other);

 private:
  struct Kept {
    cv::Mat depth, rgb;
    PinholeIntrinsics K;
    Eigen::Isometry3d T_W_C;
  };
  SurfaceMapConfig config_;
  mutable std::mutex mutex_;
  std::unique_ptr<TsdfVolume> volume_;
  std::deque<Kept> kept_;
  std::size_t dropped_ = 0;
  std::uint64_t revision_ = 0;
  mutable std::optional<std::pair<std::uint64_t, ColoredPoints>> points_cache_;
  mutable std::optional<std::pair<std::uint64_t, ColoredMesh>> mesh_cache_;
};

}  // namespace long3r

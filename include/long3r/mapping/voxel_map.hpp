// The growing coloured map: confident world points fused into a voxel hash.
//
// Frame: every point is in the world frame W (camera 0 of the stream, the
// frame of the model's pointmaps), in pointmap units (metres for a metric
// model).
//
// Voxels are the cubes [i v, (i + 1) v) x [j v, (j + 1) v) x [k v, (k + 1) v)
// for integer (i, j, k) and v = voxel_size_m. A voxel keeps the running mean
// of the positions and colours of every point that fell into it, a hit count
// (points fused) and the index of the last frame that hit it. The map holds
// exactly one point per occupied voxel: that mean, which lies inside its
// voxel (up to float rounding), so no two map points share a voxel.
//
// Cap: after each integrate() the map holds at most max_points voxels.
// Eviction policy: least recently seen first (smallest last-seen frame), ties
// broken by fewest hits, then by voxel index (i, then j, then k), so the
// result is deterministic. Frame indices should not decrease within a stream
// (a voxel's last-seen frame is the maximum it has seen).
//
// Thread safety: every member function locks an internal mutex, so the ROS
// layer may snapshot()/save() from another thread while frames are fused.
#pragma once

#include <Eigen/Core>
#include <opencv2/core/mat.hpp>

#include <array>
#include <cstddef>
#include <cstdint>
#include <map>
#include <mutex>
#include <string>
#include <vector>

#include "long3r/config/config_fields.hpp"
#include "long3r/geometry/cv/point_cloud_io.hpp"
#include "long3r/mapping/voxel_key_index.hpp"
#include "long3r/model/loading/state_dict.hpp"

namespace long3r {

struct VoxelMapConfig {
  double voxel_size_m = 0.02;
  std::size_t max_points = 2000000;  // hard cap on voxels (= points), > 0
  float conf_threshold = 3.0f;       // model confidence (>= 1); pixels below are not fused

  // Throws ConfigError naming the field.
  void validate(const config::FieldCheck& check) const;
};

// conf_threshold comes from ReconstructionConfig::conf_threshold.
template <class S, class V>
config::FieldsOf<S, VoxelMapConfig> visit_fields(S& s, V& v) {
  v("voxel_size_m", s.voxel_size_m);
  v("max_map_points", s.max_points);
}

// Points and colours of the map, index-aligned (RGB), in unspecified order.
using MapSnapshot = ColoredPoints;

// One voxel as the map keeps it.
struct VoxelInfo {
  Eigen::Vector3i index;     // (i, j, k): the voxel is [i v, (i + 1) v) x ...
  Eigen::Vector3f position;  // running mean of its points
  Rgb8 color;                // running mean colour, rounded
  std::uint32_t hits = 0;    // points fused
  std::int64_t last_seen = 0;
};

// One voxel exactly as the map keeps it: sessions save and restore the map
// bit for bit (pipeline/session.hpp).
struct VoxelRecord {
  Eigen::Vector3i index;
  Eigen::Vector3d mean;   // running mean position
  Eigen::Vector3f color;  // running mean colour (RGB), unrounded
  std::uint32_t hits = 0;
  std::int64_t last_seen = 0;
};

struct IntegrationStats {
  std::size_t candidates = 0;  // confident, finite points offered
  std::size_t fused = 0;       // points that went into a voxel
  std::size_t new_voxels = 0;
  std::size_t evicted = 0;       // voxels removed to respect max_points
  std::size_t out_of_range = 0;  // beyond +-2^20 voxels from the origin (skipped)
  std::size_t map_size = 0;      // voxels after this call
};

struct MapSaveOptions {
  bool ascii = false;  // .ply: ascii instead of binary_little_endian; .pcd: DATA ascii
};

class VoxelMap {
 public:
  // Throws std::invalid_argument for voxel_size_m <= 0 (or not finite) or
  // max_points outside [1, 2^31].
  explicit VoxelMap(const VoxelMapConfig& config = {});

  // Fuses the pixels with conf >= conf_threshold and a finite point.
  // pts3d_W: CV_32FC3, conf: CV_32FC1, rgb: CV_8UC3 in RGB order, all [H, W].
  IntegrationStats integrate(const cv::Mat& pts3d_W, const cv::Mat& conf, const cv::Mat& rgb,
                             std::int64_t frame_index);
  // Fuses every finite point (no confidence filter). colors: RGB, same length.
  IntegrationStats integrate(const std::vector<Eigen::Vector3f>& points,
                             const std::vector<Rgb8>& colors, std::int64_t frame_index);

  // Multiplies every position by `factor` (about the origin of W) and bins
  // the voxels again: voxels that land in one new voxel merge (means and
  // colours weighted by hits, hits summed, the latest last-seen frame). For a
  // change of the map's metric scale (metric_scale.hpp); the cap then applies
  // as usual. Throws std::invalid_argument unless factor is finite and > 0.
  void rescale(double factor);

  std::size_t size() const;
  bool empty() const { return size() == 0; }
  void clear();
  // Incremented by every call that changes the map (for "republish if changed").
  std::uint64_t revision() const;

  MapSnapshot snapshot() const;
  std::vector<VoxelInfo> voxels() const;  // unspecified order
  // Every voxel exactly, in storage order (that of snapshot()).
  std::vector<VoxelRecord> records() const;
  // Replaces the map by records() of a map of the same voxel size. Validated
  // first (std::invalid_argument naming the problem: more than max_points,
  // an index out of range or twice, a mean outside its voxel, non-finite
  // values, no hits); the map is unchanged then.
  void restore(const std::vector<VoxelRecord>& records);
  // records() as a state dict (sessions, model/loading/state_dict.hpp): index, mean,
  // color, hits, last_seen per voxel; restore() of one is exact, validated
  // first (StateError naming the entry; the map unchanged then).
  StateDict state() const;
  void restore(const StateReader& state);

  // Writes the map (see save_colored_cloud): format from the extension.
  void save(const std::string& path, const MapSaveOptions& options = {}) const;

  // The voxel index of a point: floor(p / voxel_size_m) per axis. Indices span
  // [-2^20, 2^20) per axis (+-21 km at 2 cm); beyond, std::out_of_range.
  Eigen::Vector3i voxel_index(const Eigen::Vector3f& p) const;
  const VoxelMapConfig& config() const { return config_; }

 private:
  struct Voxel {
    std::uint64_t key;
    double mean[3];
    float color[3];
    std::uint32_t hits;
    std::int64_t last_seen;
  };

  void fuse_locked(const Eigen::Vector3f& p, const std::uint8_t* rgb, std::int64_t frame,
                   IntegrationStats& stats);
  void evict_locked(IntegrationStats& stats);
  void compact_buckets_locked();
  void erase_locked(std::uint64_t key);

  VoxelMapConfig config_;
  mutable std::mutex mutex_;
  // Voxels stored densely (fast snapshots); the hash maps key -> position.
  std::vector<Voxel> voxels_;
  VoxelKeyIndex index_;
  // Voxel keys by last-seen frame, for eviction. Entries go stale when a voxel
  // is seen again or evicted; stale ones are skipped and pruned lazily.
  std::map<std::int64_t, std::vector<std::uint64_t>> buckets_;
  std::size_t bucket_entries_ = 0;
  std::uint64_t revision_ = 0;
};

// Writes a coloured point cloud atomically (see geometry/cv/point_cloud_io.hpp and
// atomic_file.hpp: on any error `path` is untouched, no temporary is left and
// the std::runtime_error says what failed). The extension (case-insensitive)
// selects the format:
//   .ply  binary_little_endian 1.0 (or ascii), "comment long3r map": element
//         vertex with float x, y, z and uchar red, green, blue
//   .pcd  PCD v0.7, FIELDS x y z rgb, TYPE F F F U, rgb = r << 16 | g << 8 | b,
//         DATA binary (or ascii)
// Any other extension throws std::invalid_argument naming it. colors: RGB,
// same length as points (std::invalid_argument otherwise).
void save_colored_cloud(const std::string& path, const std::vector<Eigen::Vector3f>& points,
                        const std::vector<Rgb8>& colors, const MapSaveOptions& options = {});

}  // namespace long3r

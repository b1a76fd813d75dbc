// 3-D occupancy of what the camera has seen, on OctoMap (the OcTree that
// octomap_server keeps): each view's rays from the camera to its points
// update the voxels they cross as misses and the voxels they end in as hits,
// as probabilities in log-odds (clamped, so that a voxel can change its
// mind); a surface seen again where it has gone is cleared. A 2-D grid for
// navigation is projected from it: the columns of a band above the floor.
//
// Frames: the map is kept in the caller's M (the pipeline: the stream's world
// W, camera 0); project() and floor_z() look at it from a z-up frame F (the
// node: its map frame with a robot base) through T_F_M. Lengths in M's units:
// metres once the scale is metric (rescale() follows a change of scale).
// Thread safety: every member function locks an internal mutex, so the ROS
// layer may project the grid while views are inserted.
#pragma once

#include <Eigen/Core>

#include <Eigen/Geometry>
#include <array>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <opencv2/core/mat.hpp>

#include "long3r/config/config_fields.hpp"
#include "long3r/mapping/occupancy_grid.hpp"
#include "long3r/model/loading/state_dict.hpp"

namespace octomap {
class Pointcloud;
}  // namespace octomap

namespace long3r {

struct OccupancyMapConfig {
  // The pipeline keeps one for the mapped views (the node's ~grid needs it;
  // its parameters say when it is off).
  bool enabled = true;
  double resolution_m = 0.05;
  // octomap_server's defaults: a hit's and a miss's probability, and the
  // clamping that keeps every voxel able to change.
  double prob_hit = 0.7;
  double prob_miss = 0.4;
  double clamp_min = 0.12;
  double clamp_max = 0.97;
  // Rays longer than this clear space up to it and mark nothing.
  double max_range_m = 5.0;
  // A view's rays: every pixel_step-th pixel in both directions (the
  // pipeline's views).
  int pixel_step = 4;

  // Throws ConfigError naming the field.
  void validate(const config::FieldCheck& check) const;
};

template <class S, class V>
config::FieldsOf<S, OccupancyMapConfig> visit_fields(S& s, V& v) {
  v("enabled", s.enabled);
  v("resolution_m", s.resolution_m);
  v("prob_hit", s.prob_hit);
  v("prob_miss", s.prob_miss);
  v("clamp_min", s.clamp_min);
  v("clamp_max", s.clamp_max);
  v("max_range_m", s.max_range_m);
  v("pixel_step", s.pixel_step);
}

// The band of the 2-D grid, heights above the floor.
struct GridBand {
  double floor_z_m = 0.0;
  double min_height_m = 0.10;
  double max_height_m = 1.80;
};

// Where the grid's floor is.
enum class GridFloor {
  kFit,   // OccupancyMap::floor_z(), the base's height where none is found
  kBase,  // the robot base's height (base_frame's origin at z = 0 of the map)
};
inline const std::array<std::pair<GridFloor, const char*>, 2>& enum_names(GridFloor) {
  static const std::array<std::pair<GridFloor, const char*>, 2> names{
      {{GridFloor::kFit, "fit"}, {GridFloor::kBase, "base"}}};
  return names;
}

// The node's ~grid: the band above the floor that it shows.
struct GridProjectionConfig {
  double min_height_m = 0.10;
  double max_height_m = 1.80;
  GridFloor floor = GridFloor::kFit;

  // Throws ConfigError naming the field.
  void validate(const config::FieldCheck& check) const;
};

template <class S, class V>
config::FieldsOf<S, GridProjectionConfig> visit_fields(S& s, V& v) {
  v("min_height_m", s.min_height_m);
  v("max_height_m", s.max_height_m);
  v("floor", s.floor);
}

class OccupancyMap {
 public:
  // Throws ConfigError (config.validate()).
  explicit OccupancyMap(const OccupancyMapConfig& config = {});
  ~OccupancyMap();

  // One view: its points and the camera's position, in M. Non-finite points
  // are left out. Returns the points inserted. Throws std::invalid_argument
  // for a non-finite origin.
  std::size_t insert(const std::vector<Eigen::Vector3f>& points_M, const Eigen::Vector3d& origin_M);
  // A pipeline view: its pointmap in M (CV_32FC3, every pixel_step-th pixel
  // with conf >= conf_threshold; conf may be empty) seen from origin_M.
  std::size_t insert(const cv::Mat& points_M, const cv::Mat& conf, float conf_threshold,
                     const Eigen::Vector3d& origin_M);

  // Every length times `factor`, about M's origin: each voxel's log-odds goes
  // to the voxels its scaled cube covers (occupied where any scaled voxel
  // says so), as the voxel map is re-binned. Throws std::invalid_argument
  // unless factor is finite and > 0.
  void rescale(double factor);

  // The grid of the band, seen in F: occupied where a column holds an
  // occupied voxel between floor + min_height and floor + max_height (heights
  // along F's z), free where it holds no such voxel but free ones between
  // the floor and floor + max_height (the rays that end on the floor clear
  // the cells before it, as octomap_server's projection does), unknown
  // elsewhere; cells of config.resolution_m (each voxel in the cell of its
  // centre, so a wall off F's axes is right within a cell), spanning the
  // voxels known. An empty grid (width 0) for an empty map.
  OccupancyGrid project(const GridBand& band,
                        const Eigen::Isometry3d& T_F_M = Eigen::Isometry3d::Identity()) const;
  // The floor's height along F's z: the lowest layer of occupied voxels (in
  // the lowest metre) that holds at least a quarter of the most any layer
  // there holds; nullopt when nothing is occupied.
  std::optional<double> floor_z(
      const Eigen::Isometry3d& T_F_M = Eigen::Isometry3d::Identity()) const;

  // Whether the voxel holding p is occupied (true), free (false) or unknown.
  std::optional<bool> occupied(const Eigen::Vector3d& p_M) const;
  std::size_t voxels() const;  // leaves known (free or occupied)
  // Changes whenever the map does.
  std::uint64_t revision() const;
  void clear();
  const OccupancyMapConfig& config() const { return config_; }

  // A copy of the map, to be kept apart (an ended stream's).
  std::unique_ptr<OccupancyMap> clone() const;
  // Exchanges the two maps, voxels and config (a restored session's map
  // takes the running one's place).
  void swap(OccupancyMap& other);

  // OctoMap's full-probability file (.ot) as bytes, for sessions; read()
  // takes those bytes (of a map of the same resolution). Throws
  // std::runtime_error naming the problem; the map is unchanged then.
  std::string write() const;
  void read(const std::string& bytes);
  // read() of the blob a session keeps under `key` (bytes_tensor(write()));
  // throws StateError naming the key, the map unchanged then.
  void restore(const StateReader& state, const std::string& key);

 private:
  struct Impl;
  // One view's rays (endpoints in M) from origin_M; the one insertion path.
  std::size_t insert_rays(const octomap::Pointcloud& cloud, const Eigen::Vector3d& origin_M);

  OccupancyMapConfig config_;
  mutable std::mutex mutex_;
  std::unique_ptr<Impl> impl_;
  std::uint64_t revision_ = 0;
};

}  // namespace long3r

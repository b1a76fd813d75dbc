// 3-D occupancy of what the camera has seen, on OctoMap (the OcTree that
// octomap_server keeps): each view's rays from the camera to its points
// update the voxels they cross as misses and the voxels they end in as hits,
// as probabilities in log-odds (clamped, so that a voxel can change its
// mind); a surface seen again where it has gone is cleared. A 2-D grid for
// navigation is projected from it: the columns of a band above the floor.
//
// Frame: the caller's F, metric and z up for project() (the node: its map
// frame with a robot base); lengths in metres. Not thread-safe: the caller
// serialises access.
#pragma once

#include <Eigen/Core>

#include <cstddef>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "long3r/config/config_fields.hpp"
#include "long3r/mapping/occupancy_grid.hpp"

namespace long3r {

struct OccupancyMapConfig {
  double resolution_m = 0.05;
  // octomap_server's defaults: a hit's and a miss's probability, and the
  // clamping that keeps every voxel able to change.
  double prob_hit = 0.7;
  double prob_miss = 0.4;
  double clamp_min = 0.12;
  double clamp_max = 0.97;
  // Rays longer than this clear space up to it and mark nothing.
  double max_range_m = 5.0;

  // Throws ConfigError naming the field.
  void validate(const config::FieldCheck& check) const;
};

// The band of the 2-D grid, heights above the floor.
struct GridBand {
  double floor_z_m = 0.0;
  double min_height_m = 0.10;
  double max_height_m = 1.80;
};

class OccupancyMap {
 public:
  // Throws ConfigError (config.validate()).
  explicit OccupancyMap(const OccupancyMapConfig& config = {});
  ~OccupancyMap();
  OccupancyMap(OccupancyMap&&) noexcept;
  OccupancyMap& operator=(OccupancyMap&&) noexcept;

  // One view: its points and the camera's position, in F. Non-finite points
  // are left out. Returns the points inserted. Throws std::invalid_argument
  // for a non-finite origin.
  std::size_t insert(const std::vector<Eigen::Vector3f>& points_F, const Eigen::Vector3d& origin_F);

  // The grid of the band: occupied where a column holds an occupied voxel
  // between floor + min_height and floor + max_height, free where it holds
  // only free ones there, unknown elsewhere; spanning the voxels known.
  // Cells of config.resolution_m. An empty grid (width 0) for an empty map.
  OccupancyGrid project(const GridBand& band) const;
  // The floor's height: of the occupied voxels in the lowest metre of the
  // map, the height that holds the most (the largest level surface there);
  // nullopt when nothing is occupied.
  std::optional<double> floor_z() const;

  // Whether the voxel holding p is occupied (true), free (false) or unknown.
  std::optional<bool> occupied(const Eigen::Vector3d& p_F) const;
  std::size_t voxels() const;  // leaves known (free or occupied)
  void clear();
  const OccupancyMapConfig& config() const { return config_; }

  // OctoMap's full-probability file (.ot) as bytes, for sessions; read()
  // takes those bytes (of a map of the same resolution). Throws
  // std::runtime_error naming the problem; the map is unchanged then.
  std::string write() const;
  void read(const std::string& bytes);

 private:
  struct Impl;
  OccupancyMapConfig config_;
  std::unique_ptr<Impl> impl_;
};

}  // namespace long3r

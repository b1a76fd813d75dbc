// A 2D occupancy grid of a z-up map, for navigation stacks (the node's
// ~grid, nav_msgs/OccupancyGrid's cells and layout).
//
// Frame: the map's, z up, the floor at z = 0 (the node's map frame with a
// robot base). Lengths in metres (the map's units).
//
// Occupied: a cell holding at least min_points map points in the obstacle
// band [min_height_m, max_height_m]. Free: a cell that a ray from a sensor
// position crosses on its way to an observed point (a floor point below the
// band, or an obstacle cell) within max_range_m; the ray stops at the first
// occupied cell it meets, so nothing behind an obstacle is cleared. Points
// above the band (a ceiling) are ignored. Unknown: every other cell.
// Rays are cast per sensor cell over angular sectors of one cell's width at
// max_range_m, each to its farthest observed cell.
#pragma once

#include <Eigen/Core>

#include <cstdint>
#include <vector>

#include "long3r/config/config_fields.hpp"

namespace long3r {

struct OccupancyGridConfig {
  double resolution_m = 0.05;
  double min_height_m = 0.10;  // obstacle band above the floor
  double max_height_m = 1.80;
  double max_range_m = 5.0;  // of the rays from a sensor
  int min_points = 3;        // map points in the band for an occupied cell

  // Throws ConfigError naming the field.
  void validate(const config::FieldCheck& check) const;
};

template <class S, class V>
config::FieldsOf<S, OccupancyGridConfig> visit_fields(S& s, V& v) {
  v("resolution_m", s.resolution_m);
  v("min_height_m", s.min_height_m);
  v("max_height_m", s.max_height_m);
  v("max_range_m", s.max_range_m);
  v("min_points", s.min_points);
}

struct OccupancyGrid {
  static constexpr std::int8_t kUnknown = -1, kFree = 0, kOccupied = 100;
  double resolution_m = 0.0;
  double origin_x_m = 0.0, origin_y_m = 0.0;  // corner of cell (0, 0)
  int width = 0, height = 0;                  // cells along x and y
  std::vector<std::int8_t> cells;             // row-major, row = y index
  std::size_t occupied = 0, free = 0;

  // The cell holding (x, y); kUnknown outside the grid.
  std::int8_t at(double x, double y) const;
};

// The grid of `points` (the map) seen from `sensors` (camera positions, e.g.
// every pose of the path), both in the map frame. It spans the sensors'
// bounding box grown by max_range_m; points beyond are left out. An empty
// grid (width 0) without sensors.
OccupancyGrid build_occupancy_grid(const std::vector<Eigen::Vector3f>& points,
                                   const std::vector<Eigen::Vector3d>& sensors,
                                   const OccupancyGridConfig& config);

}  // namespace long3r

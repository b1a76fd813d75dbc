// A 2-D occupancy grid in nav_msgs/OccupancyGrid's cells and layout (the
// node's ~grid), as OccupancyMap::project() (occupancy_map.hpp) makes it from
// the 3-D occupancy.
//
// Frame: a z-up map frame; lengths in metres.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

namespace long3r {

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

// Grids of one resolution whose origins are multiples of it (as
// OccupancyMap::project() makes them) as one: their union, a cell occupied
// where any says so, else free where any says so. Empty grids are skipped.
// Throws std::invalid_argument for grids of different resolutions.
OccupancyGrid merge_grids(const std::vector<OccupancyGrid>& grids);

// The grid as map_server's files (map_saver's layout, which map_server and
// nav2's map loader read): <stem>.pgm (P5, the top row at the largest y;
// occupied 0, free 254, unknown 205) and <stem>.yaml (image, resolution,
// origin, negate 0, occupied_thresh 0.65, free_thresh 0.196), each written
// atomically. Throws AtomicWriteError naming the file, std::invalid_argument
// for an empty grid.
void save_grid_map(const std::string& stem, const OccupancyGrid& grid);

}  // namespace long3r

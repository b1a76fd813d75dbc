// The grid's cells (occupancy_grid.hpp); OccupancyMap (occupancy_map.hpp)
// makes them.
#include "long3r/mapping/occupancy_grid.hpp"

#include "long3r/io/atomic_file.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <stdexcept>

namespace long3r {

std::int8_t OccupancyGrid::at(double x, double y) const {
  const double fx = std::floor((x - origin_x_m) / resolution_m);
  const double fy = std::floor((y - origin_y_m) / resolution_m);
  if (!(fx >= 0 && fx < width && fy >= 0 && fy < height)) return kUnknown;
  return cells[static_cast<std::size_t>(fy) * width + static_cast<std::size_t>(fx)];
}

OccupancyGrid merge_grids(const std::vector<OccupancyGrid>& grids) {
  OccupancyGrid out;
  double x0 = HUGE_VAL, y0 = HUGE_VAL, x1 = -HUGE_VAL, y1 = -HUGE_VAL;
  for (const OccupancyGrid& g : grids) {
    if (g.width <= 0 || g.height <= 0) continue;
    if (out.resolution_m == 0.0) out.resolution_m = g.resolution_m;
    if (std::abs(g.resolution_m - out.resolution_m) > 1e-12) {
      throw std::invalid_argument("merge_grids: grids of " + std::to_string(out.resolution_m) +
                                  " and " + std::to_string(g.resolution_m) + " m cells");
    }
    x0 = std::min(x0, g.origin_x_m);
    y0 = std::min(y0, g.origin_y_m);
    x1 = std::max(x1, g.origin_x_m + g.width * g.resolution_m);
    y1 = std::max(y1, g.origin_y_m + g.height * g.resolution_m);
  }
  if (out.resolution_m == 0.0) return out;
  const double res = out.resolution_m;
  out.origin_x_m = x0;
  out.origin_y_m = y0;
  out.width = static_cast<int>(std::lround((x1 - x0) / res));
  out.height = static_cast<int>(std::lround((y1 - y0) / res));
  out.cells.assign(static_cast<std::size_t>(out.width) * out.height, OccupancyGrid::kUnknown);
  for (const OccupancyGrid& g : grids) {
    if (g.width <= 0 || g.height <= 0) continue;
    const int dx = static_cast<int>(std::lround((g.origin_x_m - x0) / res));
    const int dy = static_cast<int>(std::lround((g.origin_y_m - y0) / res));
    for (int y = 0; y < g.height; ++y) {
      for (int x = 0; x < g.width; ++x) {
        const std::int8_t c = g.cells[static_cast<std::size_t>(y) * g.width + x];
        std::int8_t& o = out.cells[static_cast<std::size_t>(y + dy) * out.width + (x + dx)];
        if (c == OccupancyGrid::kOccupied) {
          o = c;
        } else if (c == OccupancyGrid::kFree && o == OccupancyGrid::kUnknown) {
          o = c;
        }
      }
    }
  }
  for (std::int8_t c : out.cells) {
    out.occupied += c == OccupancyGrid::kOccupied ? 1 : 0;
    out.free += c == OccupancyGrid::kFree ? 1 : 0;
  }
  return out;
}

void save_grid_map(const std::string& stem, const OccupancyGrid& grid) {
  if (grid.width <= 0 || grid.height <= 0 ||
      grid.cells.size() != static_cast<std::size_t>(grid.width) * grid.height) {
    throw std::invalid_argument("save_grid_map: an empty grid");
  }
  std::string pgm =
      "P5\n" + std::to_string(grid.width) + " " + std::to_string(grid.height) + "\n255\n";
  const std::size_t header = pgm.size();
  pgm.resize(header + grid.cells.size());
  for (int y = 0; y < grid.height; ++y) {
    const std::size_t row = header + static_cast<std::size_t>(grid.height - 1 - y) * grid.width;
    for (int x = 0; x < grid.width; ++x) {
      const std::int8_t c = grid.cells[static_cast<std::size_t>(y) * grid.width + x];
      pgm[row + x] = static_cast<char>(c == OccupancyGrid::kOccupied ? 0
                                       : c == OccupancyGrid::kFree   ? 254
                                                                     : 205);
    }
  }
  char yaml[512];
  std::snprintf(yaml, sizeof yaml,
                "image: %s\nresolution: %.9g\norigin: [%.9g, %.9g, 0.0]\nnegate: 0\n"
                "occupied_thresh: 0.65\nfree_thresh: 0.196\n",
                std::filesystem::path(stem + ".pgm").filename().c_str(), grid.resolution_m,
                grid.origin_x_m, grid.origin_y_m);
  AtomicFile image(stem + ".pgm");
  image.write(pgm);
  image.commit();
  AtomicFile info(stem + ".yaml");
  info.write(yaml);
  info.commit();
}

}  // namespace long3r

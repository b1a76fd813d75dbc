// 2D occupancy grid of a z-up map; see occupancy_grid.hpp.
#include "long3r/mapping/occupancy_grid.hpp"

#include <algorithm>
#include <cmath>
#include <set>
#include <stdexcept>
#include <string>
#include <utility>

namespace long3r {

namespace {

// Beyond this many cells per side the grid is refused (a 5 cm grid of
// 400 m; a map that size wants a coarser resolution).
constexpr int kMaxCellsPerSide = 8192;

}  // namespace

void OccupancyGridConfig::validate(const config::FieldCheck& check) const {
  check.require(resolution_m > 0.0 && std::isfinite(resolution_m), "resolution_m", "must be > 0");
  check.require(std::isfinite(min_height_m), "min_height_m", "must be finite");
  check.require(max_height_m > min_height_m && std::isfinite(max_height_m), "max_height_m",
                "must be finite and above min_height_m");
  check.require(max_range_m >= resolution_m && std::isfinite(max_range_m), "max_range_m",
                "must be finite and at least resolution_m");
  check.require(min_points >= 1, "min_points", "must be >= 1");
}

std::int8_t OccupancyGrid::at(double x, double y) const {
  const double fx = std::floor((x - origin_x_m) / resolution_m);
  const double fy = std::floor((y - origin_y_m) / resolution_m);
  if (!(fx >= 0 && fx < width && fy >= 0 && fy < height)) return kUnknown;
  return cells[static_cast<std::size_t>(fy) * width + static_cast<std::size_t>(fx)];
}

OccupancyGrid build_occupancy_grid(const std::vector<Eigen::Vector3f>& points,
                                   const std::vector<Eigen::Vector3d>& sensors,
                                   const OccupancyGridConfig& config) {
  config.validate({"occupancy grid config", ""});
  OccupancyGrid g;
  g.resolution_m = config.resolution_m;
  if (sensors.empty()) return g;
  const double res = config.resolution_m;
  double lo_x = sensors[0].x(), lo_y = sensors[0].y(), hi_x = lo_x, hi_y = lo_y;
  for (const Eigen::Vector3d& s : sensors) {
    if (!s.allFinite()) continue;
    lo_x = std::min(lo_x, s.x());
    lo_y = std::min(lo_y, s.y());
    hi_x = std::max(hi_x, s.x());
    hi_y = std::max(hi_y, s.y());
  }
  const double pad = config.max_range_m + res;
  g.origin_x_m = std::floor((lo_x - pad) / res) * res;
  g.origin_y_m = std::floor((lo_y - pad) / res) * res;
  const double w = std::ceil((hi_x + pad - g.origin_x_m) / res);
  const double h = std::ceil((hi_y + pad - g.origin_y_m) / res);
  if (!(w <= kMaxCellsPerSide && h <= kMaxCellsPerSide)) {
    throw std::invalid_argument("occupancy grid of " + std::to_string(w) + " x " +
                                std::to_string(h) + " cells: more than " +
                                std::to_string(kMaxCellsPerSide) +
                                " per side; use a coarser resolution");
  }
  g.width = static_cast<int>(w);
  g.height = static_cast<int>(h);
  const std::size_t n = static_cast<std::size_t>(g.width) * g.height;
  g.cells.assign(n, OccupancyGrid::kUnknown);

  auto cell_of = [&](double x, double y, int* cx, int* cy) {
    const double fx = std::floor((x - g.origin_x_m) / res);
    const double fy = std::floor((y - g.origin_y_m) / res);
    if (!(fx >= 0 && fx < g.width && fy >= 0 && fy < g.height)) return false;
    *cx = static_cast<int>(fx);
    *cy = static_cast<int>(fy);
    return true;
  };

  // Obstacle counts and observed cells.
  std::vector<int> band(n, 0);
  std::vector<char> observed(n, 0);
  for (const Eigen::Vector3f& p : points) {
    if (!p.allFinite() || p.z() > config.max_height_m) continue;
    int cx, cy;
    if (!cell_of(p.x(), p.y(), &cx, &cy)) continue;
    const std::size_t i = static_cast<std::size_t>(cy) * g.width + cx;
    observed[i] = 1;
    if (p.z() >= config.min_height_m) ++band[i];
  }
  std::vector<char> occupied(n, 0);
  for (std::size_t i = 0; i < n; ++i) occupied[i] = band[i] >= config.min_points;

  // Rays from each sensor cell, one per angular sector, to the farthest
  // observed cell in it.
  const double range_cells = config.max_range_m / res;
  const int sectors = std::max(8, static_cast<int>(std::ceil(2.0 * M_PI * range_cells)));
  const int reach = static_cast<int>(std::ceil(range_cells));
  std::set<std::pair<int, int>> origins;
  for (const Eigen::Vector3d& s : sensors) {
    int cx, cy;
    if (s.allFinite() && cell_of(s.x(), s.y(), &cx, &cy)) origins.emplace(cx, cy);
  }
  std::vector<char> free(n, 0);
  std::vector<double> farthest(static_cast<std::size_t>(sectors));
  for (const auto& [ox, oy] : origins) {
    std::fill(farthest.begin(), farthest.end(), -1.0);
    const int x0 = std::max(0, ox - reach), x1 = std::min(g.width - 1, ox + reach);
    const int y0 = std::max(0, oy - reach), y1 = std::min(g.height - 1, oy + reach);
    for (int y = y0; y <= y1; ++y) {
      for (int x = x0; x <= x1; ++x) {
        if (!observed[static_cast<std::size_t>(y) * g.width + x]) continue;
        const double dx = x - ox, dy = y - oy, d = std::hypot(dx, dy);
        if (d > range_cells || d == 0.0) continue;
        const int sector = std::min(
            sectors - 1, static_cast<int>((std::atan2(dy, dx) + M_PI) / (2.0 * M_PI) * sectors));
        farthest[static_cast<std::size_t>(sector)] =
            std::max(farthest[static_cast<std::size_t>(sector)], d);
      }
    }
    free[static_cast<std::size_t>(oy) * g.width + ox] = 1;
    for (int k = 0; k < sectors; ++k) {
      const double d = farthest[static_cast<std::size_t>(k)];
      if (d < 0.0) continue;
      const double angle = (k + 0.5) / sectors * 2.0 * M_PI - M_PI;
      const double ux = std::cos(angle), uy = std::sin(angle);
      // Half-cell steps from the origin's centre: every crossed cell is visited.
      for (double t = 0.5; t <= d + 0.5; t += 0.5) {
        const int x = static_cast<int>(std::floor(ox + 0.5 + ux * t));
        const int y = static_cast<int>(std::floor(oy + 0.5 + uy * t));
        if (x < 0 || x >= g.width || y < 0 || y >= g.height) break;
        const std::size_t i = static_cast<std::size_t>(y) * g.width + x;
        if (occupied[i]) break;  // the obstacle hides what lies behind it
        free[i] = 1;
      }
    }
  }
  for (std::size_t i = 0; i < n; ++i) {
    if (occupied[i]) {
      g.cells[i] = OccupancyGrid::kOccupied;
      ++g.occupied;
    } else if (free[i]) {
      g.cells[i] = OccupancyGrid::kFree;
      ++g.free;
    }
  }
  return g;
}

}  // namespace long3r

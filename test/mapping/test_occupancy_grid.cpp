// The occupancy grid (pipeline/occupancy_grid.hpp) of a generated room seen
// from a sensor in it: walls occupied, the floor free as far as the rays
// reach, what an obstacle hides unknown, a ceiling and stray points ignored,
// the layout nav_msgs/OccupancyGrid expects.
#include <gtest/gtest.h>

#include <Eigen/Core>

#include <vector>

#include "long3r/config/config_fields.hpp"
#include "long3r/mapping/occupancy_grid.hpp"

namespace long3r {
namespace {

using G = OccupancyGrid;

// A room with walls 1 m high at x = 0.05, 3.95 and y = 0.05, 2.95 (cell
// centres of the 0.1 m grid below), its floor every 2 cm, a ceiling at 2.5 m
// and a box with sides at x = 2.85, 3.15 and y = 1.35, 1.65.
bool in_box(float x, float y) { return x > 2.8f && x < 3.2f && y > 1.3f && y < 1.7f; }

std::vector<Eigen::Vector3f> room() {
  std::vector<Eigen::Vector3f> p;
  for (float x = 0.06f; x < 3.95f; x += 0.02f) {
    for (float y = 0.06f; y < 2.95f; y += 0.02f) {
      if (!in_box(x, y)) p.emplace_back(x, y, 0.0f);
      p.emplace_back(x, y, 2.5f);  // ceiling: above the band
    }
  }
  for (float z = 0.2f; z < 1.0f; z += 0.1f) {
    for (float t = 0.05f; t <= 3.95f; t += 0.02f) {
      p.emplace_back(t, 0.05f, z);
      p.emplace_back(t, 2.95f, z);
    }
    for (float t = 0.05f; t <= 2.95f; t += 0.02f) {
      p.emplace_back(0.05f, t, z);
      p.emplace_back(3.95f, t, z);
    }
    for (float t = 0.0f; t <= 0.3f; t += 0.02f) {
      p.emplace_back(2.85f + t, 1.35f, z);
      p.emplace_back(2.85f + t, 1.65f, z);
      p.emplace_back(2.85f, 1.35f + t, z);
      p.emplace_back(3.15f, 1.35f + t, z);
    }
  }
  return p;
}

OccupancyGridConfig config() {
  OccupancyGridConfig c;
  c.resolution_m = 0.1;
  c.max_range_m = 6.0;
  return c;
}

TEST(OccupancyGrid, WallsOccupiedFloorFreeShadowAndOutsideUnknown) {
  const G g = build_occupancy_grid(room(), {{1.0, 1.5, 1.2}}, config());
  EXPECT_EQ(g.resolution_m, 0.1);
  EXPECT_EQ(g.cells.size(), static_cast<std::size_t>(g.width) * g.height);
  // The grid spans the sensor +- (range + a cell), on cell boundaries.
  EXPECT_NEAR(g.origin_x_m, -5.1, 1e-9);
  EXPECT_NEAR(g.origin_y_m, -4.6, 1e-9);
  EXPECT_EQ(g.width, 122);
  EXPECT_EQ(g.height, 122);

  for (const double y : {0.5, 1.5, 2.5}) {
    EXPECT_EQ(g.at(0.05, y), G::kOccupied) << y;  // walls
    EXPECT_EQ(g.at(3.95, y), G::kOccupied) << y;
  }
  EXPECT_EQ(g.at(2.0, 2.95), G::kOccupied);
  EXPECT_EQ(g.at(2.85, 1.5), G::kOccupied);  // the box's near side
  // The floor around the sensor and up to the walls.
  for (const auto& [x, y] : {std::pair{1.0, 1.5}, {0.5, 0.5}, {2.5, 2.5}, {3.5, 0.4}, {2.0, 1.0}}) {
    EXPECT_EQ(g.at(x, y), G::kFree) << x << ", " << y;
  }
  EXPECT_EQ(g.at(3.5, 1.5), G::kUnknown);    // behind the box, seen from the sensor
  EXPECT_EQ(g.at(3.0, 1.5), G::kUnknown);    // inside the box: no floor seen, hidden
  EXPECT_EQ(g.at(-1.0, 1.5), G::kUnknown);   // beyond the wall
  EXPECT_EQ(g.at(100.0, 1.5), G::kUnknown);  // outside the grid
  EXPECT_GT(g.occupied, 100u);
  EXPECT_GT(g.free, 900u);

  // A second sensor behind the box sees its shadow.
  const G both = build_occupancy_grid(room(), {{1.0, 1.5, 1.2}, {3.7, 2.5, 1.2}}, config());
  EXPECT_EQ(both.at(3.5, 1.5), G::kFree);
  EXPECT_GT(both.free, g.free);
}

TEST(OccupancyGrid, RangeNoiseAndCeilingAreRespected) {
  OccupancyGridConfig c = config();
  c.max_range_m = 1.0;
  const G near = build_occupancy_grid(room(), {{1.0, 1.5, 1.2}}, c);
  EXPECT_EQ(near.at(1.5, 1.5), G::kFree);
  EXPECT_EQ(near.at(2.5, 1.5), G::kUnknown);  // beyond the rays' range
  EXPECT_EQ(near.at(0.05, 1.5), G::kOccupied);

  // Two stray points in the band over the floor: below min_points (3).
  std::vector<Eigen::Vector3f> p = room();
  p.emplace_back(1.55f, 1.55f, 0.5f);
  p.emplace_back(1.56f, 1.56f, 0.6f);
  EXPECT_EQ(build_occupancy_grid(p, {{1.0, 1.5, 1.2}}, config()).at(1.55, 1.55), G::kFree);
  p.emplace_back(1.57f, 1.57f, 0.7f);  // the third: an obstacle
  EXPECT_EQ(build_occupancy_grid(p, {{1.0, 1.5, 1.2}}, config()).at(1.55, 1.55), G::kOccupied);

  // Raising the band over the walls' tops (1 m): they no longer block.
  c = config();
  c.min_height_m = 1.2;
  const G low = build_occupancy_grid(room(), {{1.0, 1.5, 1.2}}, c);
  EXPECT_EQ(low.occupied, 0u);  // the ceiling is above max_height_m
  EXPECT_EQ(low.at(3.5, 1.5), G::kFree);
}

TEST(OccupancyGrid, NoSensorsNoGridAndBadConfigsAreNamed) {
  const G g = build_occupancy_grid(room(), {}, config());
  EXPECT_EQ(g.width, 0);
  EXPECT_TRUE(g.cells.empty());
  EXPECT_EQ(g.at(1.0, 1.0), G::kUnknown);
  OccupancyGridConfig c = config();
  c.max_height_m = c.min_height_m;
  EXPECT_THROW(build_occupancy_grid(room(), {{1.0, 1.5, 1.2}}, c), ConfigError);
  c = config();
  c.resolution_m = 0.0;
  EXPECT_THROW(c.validate({"grid", ""}), ConfigError);
  c = config();
  c.resolution_m = 0.001;  // 12 km of range at 1 mm
  c.max_range_m = 12000.0;
  EXPECT_THROW(build_occupancy_grid(room(), {{1.0, 1.5, 1.2}}, c), std::invalid_argument);
}

}  // namespace
}  // namespace long3r

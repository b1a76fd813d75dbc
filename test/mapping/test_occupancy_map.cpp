// OccupancyMap on a generated room driven through by a robot: the grid of its
// band is right cell for cell within one cell of the room's walls and
// furniture, the driven path is free, the floor is found; an obstacle that
// moves away is cleared by the views that see through where it was; the map
// round-trips through OctoMap's file exactly.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "long3r/mapping/occupancy_map.hpp"
#include "long3r/synth/cv/sensor_image.hpp"
#include "long3r/synth/render.hpp"
#include "support/cv_test_support.hpp"
#include "support/test_support.hpp"

namespace long3r {
namespace {

using Cell = std::pair<int, int>;

Cell cell_of(const OccupancyGrid& g, double x, double y) {
  return {static_cast<int>(std::floor((x - g.origin_x_m) / g.resolution_m)),
          static_cast<int>(std::floor((y - g.origin_y_m) / g.resolution_m))};
}

bool near(const std::set<Cell>& cells, const Cell& c) {
  for (int dy = -1; dy <= 1; ++dy) {
    for (int dx = -1; dx <= 1; ++dx) {
      if (cells.count({c.first + dx, c.second + dy})) return true;
    }
  }
  return false;
}

// 3 x 2 cells of 0.5 m from (-1, 2): free, occupied, unknown; occupied, free, free.
OccupancyGrid small_grid() {
  OccupancyGrid g;
  g.resolution_m = 0.5;
  g.origin_x_m = -1.0;
  g.origin_y_m = 2.0;
  g.width = 3;
  g.height = 2;
  g.cells = {0, 100, -1, 100, 0, 0};
  return g;
}

// nav_msgs/OccupancyGrid's layout: rows of y, the origin the corner of cell
// (0, 0), unknown outside.
TEST(OccupancyGrid, CellsAreRowsOfY) {
  const OccupancyGrid g = small_grid();
  EXPECT_EQ(g.at(-0.9, 2.1), 0);
  EXPECT_EQ(g.at(-0.4, 2.1), 100);  // x: second column
  EXPECT_EQ(g.at(-0.9, 2.6), 100);  // y: second row
  EXPECT_EQ(g.at(0.4, 2.9), 0);
  EXPECT_EQ(g.at(0.6, 2.1), OccupancyGrid::kUnknown);  // beyond the width
  EXPECT_EQ(g.at(-1.1, 2.1), OccupancyGrid::kUnknown);
  EXPECT_EQ(g.at(-0.9, 3.1), OccupancyGrid::kUnknown);
}

// map_saver's files: the image's top row is the grid's last (largest y),
// occupied black, free white, unknown grey; the YAML places its corner.
TEST(OccupancyGrid, SavesAsMapServerFiles) {
  const OccupancyGrid g = small_grid();
  const std::string stem = test::scratch_dir("occupancy/grid_files") + "/grid";
  save_grid_map(stem, g);
  const std::string pgm = test::read_file(stem + ".pgm");
  const std::string header = "P5\n3 2\n255\n";
  ASSERT_EQ(pgm.size(), header.size() + 6);
  EXPECT_EQ(pgm.substr(0, header.size()), header);
  const std::string pixels = pgm.substr(header.size());
  EXPECT_EQ(pixels, std::string("\x00\xfe\xfe\xfe\x00\xcd", 6));  // row y = 1, then y = 0
  const std::string yaml = test::read_file(stem + ".yaml");
  EXPECT_NE(yaml.find("image: grid.pgm\n"), std::string::npos) << yaml;
  EXPECT_NE(yaml.find("resolution: 0.5\n"), std::string::npos) << yaml;
  EXPECT_NE(yaml.find("origin: [-1, 2, 0.0]\n"), std::string::npos) << yaml;
  EXPECT_NE(yaml.find("occupied_thresh: 0.65\n"), std::string::npos) << yaml;
  test::expect_throw_naming([&] { save_grid_map(stem, OccupancyGrid{}); }, "empty grid");
}

TEST(OccupancyMap, GridOfAGeneratedRoomIsRightWithinOneCell) {
  const synth::SequenceConfig c =
      test::sequence_config(21, synth::TrajectoryType::kRobot, 40, 96, 72);
  const synth::Sequence seq = synth::generate_sequence(c);
  OccupancyMap map;
  const GridBand band;  // 0.10-1.80 m above z = 0, the generated room's floor
  // The room's surfaces well inside the band (a voxel from its edges: what
  // must be occupied), and within a voxel of it (what may be).
  std::vector<Eigen::Vector3f> must, may;
  for (int k = 0; k < c.trajectory.frames; ++k) {
    const synth::RenderedFrame f = synth::render_frame(seq.scene, seq.poses[k], c.intrinsics);
    const cv::Mat depth = synth::depth_image(f);
    const cv::Mat pts = test::pointmap_from_depth(
        c.intrinsics, seq.poses[k], [&](int u, int v) { return depth.at<float>(v, u); });
    std::vector<Eigen::Vector3f> points;
    for (auto it = pts.begin<cv::Vec3f>(); it != pts.end<cv::Vec3f>(); ++it) {
      if (!std::isfinite((*it)[0])) continue;
      points.emplace_back((*it)[0], (*it)[1], (*it)[2]);
      const double h = (*it)[2] - band.floor_z_m;
      if (h > band.min_height_m + 0.05 && h < band.max_height_m - 0.05) {
        must.push_back(points.back());
      }
      if (h > band.min_height_m - 0.05 && h < band.max_height_m + 0.05) {
        may.push_back(points.back());
      }
    }
    EXPECT_EQ(map.insert(points, seq.poses[k].translation()), points.size());
  }
  const OccupancyGrid g = map.project(band);
  ASSERT_GT(g.width, 0);
  std::set<Cell> truth, allowed, occupied;
  for (const Eigen::Vector3f& p : must) truth.insert(cell_of(g, p.x(), p.y()));
  for (const Eigen::Vector3f& p : may) allowed.insert(cell_of(g, p.x(), p.y()));
  for (int y = 0; y < g.height; ++y) {
    for (int x = 0; x < g.width; ++x) {
      if (g.cells[static_cast<std::size_t>(y) * g.width + x] == OccupancyGrid::kOccupied) {
        occupied.insert({x, y});
      }
    }
  }
  ASSERT_FALSE(truth.empty());
  std::size_t wrong = 0, missed = 0;
  for (const Cell& o : occupied) wrong += near(allowed, o) ? 0 : 1;
  for (const Cell& t : truth) missed += near(occupied, t) ? 0 : 1;
  RecordProperty("occupied", static_cast<int>(occupied.size()));
  EXPECT_EQ(wrong, 0u) << "occupied cells not within one cell of the room's surfaces";
  EXPECT_LT(missed, truth.size() / 50) << missed << " of " << truth.size() << " surface cells";
  EXPECT_EQ(g.occupied, occupied.size());
  // The driven path: free.
  for (const Eigen::Isometry3d& T : seq.poses) {
    const Eigen::Vector3d p = T.translation();
    EXPECT_EQ(g.at(p.x(), p.y()), OccupancyGrid::kFree) << p.transpose();
  }
  EXPECT_GT(g.free, occupied.size());
  const std::optional<double> floor = map.floor_z();
  ASSERT_TRUE(floor.has_value());
  EXPECT_NEAR(*floor, 0.0, map.config().resolution_m);
}

// A wall 3 m ahead, and a box in front of it that then goes away: the views
// that see the wall through where the box was clear it.
TEST(OccupancyMap, AnObstacleThatMovesAwayIsCleared) {
  OccupancyMap map;
  const Eigen::Vector3d camera(0.0, 0.0, 0.5);
  auto view = [&](bool box) {
    std::vector<Eigen::Vector3f> points;
    for (int i = -20; i <= 20; ++i) {
      for (int j = -10; j <= 10; ++j) {
        const Eigen::Vector3d dir = Eigen::Vector3d(1.0, 0.02 * i, 0.02 * j).normalized();
        // The box: the face x = 1.5 for |y| < 0.15.
        const double to_box = 1.5 / dir.x();
        const Eigen::Vector3d at_box = camera + to_box * dir;
        const bool hits_box = box && std::abs(at_box.y()) < 0.15;
        const double range = hits_box ? to_box : 3.0 / dir.x();
        points.push_back((camera + range * dir).cast<float>());
      }
    }
    return points;
  };
  const Eigen::Vector3d box_face(1.52, 0.0, 0.5), wall(3.02, 0.0, 0.5);
  for (int k = 0; k < 5; ++k) map.insert(view(true), camera);
  ASSERT_EQ(map.occupied(box_face), std::optional<bool>(true));
  EXPECT_EQ(map.occupied(wall), std::nullopt);  // hidden behind the box
  for (int k = 0; k < 20; ++k) map.insert(view(false), camera);
  EXPECT_EQ(map.occupied(box_face), std::optional<bool>(false));
  EXPECT_EQ(map.occupied(wall), std::optional<bool>(true));
  GridBand band;
  band.floor_z_m = 0.0;
  const OccupancyGrid g = map.project(band);
  EXPECT_EQ(g.at(box_face.x(), box_face.y()), OccupancyGrid::kFree);
  EXPECT_EQ(g.at(wall.x(), wall.y()), OccupancyGrid::kOccupied);
}

// The map kept in another frame M (the pipeline's camera 0: z forward, y
// down) and looked at from a z-up F: the same grid within a cell.
TEST(OccupancyMap, ProjectsFromAnotherFrame) {
  OccupancyMap in_F, in_M;
  // F: x forward, z up; M = F turned so that M's z is F's x, M's y is -F's z.
  Eigen::Isometry3d T_F_M = Eigen::Isometry3d::Identity();
  T_F_M.linear() << 0, 0, 1,  //
      -1, 0, 0,               //
      0, -1, 0;
  T_F_M.translation() = Eigen::Vector3d(0.3, -0.2, 0.5);
  const Eigen::Isometry3d T_M_F = T_F_M.inverse();
  const Eigen::Vector3d camera_F(0.0, 0.0, 0.5);
  std::vector<Eigen::Vector3f> wall_F, wall_M;
  for (int i = -30; i <= 30; ++i) {
    for (int j = 0; j <= 30; ++j) {
      const Eigen::Vector3d p(2.0, 0.03 * i, 0.05 * j);
      wall_F.push_back(p.cast<float>());
      wall_M.push_back((T_M_F * p).cast<float>());
    }
  }
  for (int k = 0; k < 3; ++k) {
    in_F.insert(wall_F, camera_F);
    in_M.insert(wall_M, T_M_F * camera_F);
  }
  GridBand band;
  const OccupancyGrid a = in_F.project(band), b = in_M.project(band, T_F_M);
  ASSERT_GT(a.occupied, 20u);
  std::size_t agree = 0;
  for (int i = -25; i <= 25; ++i) {
    const double y = 0.03 * i;
    // At cell centres (the two grids' cells need not share their edges).
    const double wall_x = 2.025;
    agree += (a.at(wall_x, y) == OccupancyGrid::kOccupied) ==
                     (b.at(wall_x, y) == OccupancyGrid::kOccupied)
                 ? 1
                 : 0;
    // Halfway to the wall the rays span |y| < 0.45.
    if (std::abs(y) < 0.4) {
      EXPECT_EQ(b.at(1.025, y), OccupancyGrid::kFree) << y;
    }
  }
  EXPECT_GE(agree, 45u);
  ASSERT_TRUE(in_M.floor_z(T_F_M).has_value());
}

// A change of scale: every voxel moves with it, obstacles stay whole.
TEST(OccupancyMap, RescaleMovesTheVoxels) {
  OccupancyMap map;
  std::vector<Eigen::Vector3f> wall;
  for (int i = -20; i <= 20; ++i) {
    for (int j = -5; j <= 5; ++j) wall.emplace_back(1.5f, 0.025f * i, 0.025f * j);
  }
  for (int k = 0; k < 3; ++k) map.insert(wall, Eigen::Vector3d::Zero());
  ASSERT_EQ(map.occupied({1.52, 0.0, 0.0}), std::optional<bool>(true));
  const std::uint64_t before = map.revision();
  map.rescale(1.7);
  EXPECT_GT(map.revision(), before);
  EXPECT_EQ(map.occupied({1.52 * 1.7, 0.0, 0.0}), std::optional<bool>(true));
  EXPECT_EQ(map.occupied({0.8 * 1.7, 0.0, 0.0}), std::optional<bool>(false));
  // Along the scaled wall, no gaps.
  for (int i = -15; i <= 15; ++i) {
    EXPECT_EQ(map.occupied({1.52 * 1.7, 0.025 * i * 1.7, 0.0}), std::optional<bool>(true)) << i;
  }
  map.rescale(1.0 / 1.7);
  EXPECT_EQ(map.occupied({1.52, 0.0, 0.0}), std::optional<bool>(true));
  test::expect_throw_naming([&] { map.rescale(0.0); }, "factor");
}

// The pipeline's view: a pointmap, every pixel_step-th pixel, the
// unconfident ones left out.
TEST(OccupancyMap, InsertsAPointmap) {
  OccupancyMap map;  // pixel_step 4
  cv::Mat pts(40, 40, CV_32FC3), conf(40, 40, CV_32FC1, cv::Scalar(5.0f));
  for (int v = 0; v < 40; ++v) {
    for (int u = 0; u < 40; ++u)
      pts.at<cv::Vec3f>(v, u) = cv::Vec3f(0.05f * (u - 20), 0.05f * (v - 20), 2.0f);
  }
  EXPECT_EQ(map.insert(pts, conf, 3.0f, Eigen::Vector3d::Zero()), 100u);
  conf(cv::Rect(0, 0, 40, 20)).setTo(1.0f);
  EXPECT_EQ(map.insert(pts, conf, 3.0f, Eigen::Vector3d::Zero()), 50u);
  EXPECT_EQ(map.insert(pts, cv::Mat(), 0.0f, Eigen::Vector3d::Zero()), 100u);
  test::expect_throw_naming([&] { map.insert(pts, cv::Mat(3, 3, CV_32FC1), 0.0f, {}); },
                            "CV_32FC1");
}

TEST(OccupancyMap, RoundTripsThroughOctoMapsFile) {
  OccupancyMap map;
  std::vector<Eigen::Vector3f> points;
  for (int i = 0; i < 50; ++i) points.emplace_back(2.0f, 0.02f * i - 0.5f, 0.3f);
  map.insert(points, Eigen::Vector3d::Zero());
  const std::string bytes = map.write();
  OccupancyMap copy;
  copy.read(bytes);
  EXPECT_EQ(copy.voxels(), map.voxels());
  EXPECT_EQ(copy.write(), bytes);
  GridBand band;
  band.floor_z_m = 0.0;
  const OccupancyGrid a = map.project(band), b = copy.project(band);
  EXPECT_EQ(a.cells, b.cells);
  // Another resolution, or not an OctoMap file: refused, the map unchanged.
  OccupancyMapConfig coarse;
  coarse.resolution_m = 0.1;
  OccupancyMap other(coarse);
  test::expect_throw_naming([&] { other.read(bytes); }, "resolution");
  test::expect_throw_naming([&] { copy.read("not an octree"); }, "not an OctoMap");
  EXPECT_EQ(copy.voxels(), map.voxels());
  // Bad input.
  const double nan = std::nan("");
  test::expect_throw_naming([&] { map.insert(points, Eigen::Vector3d(nan, 0, 0)); }, "not finite");
  EXPECT_EQ(map.insert({Eigen::Vector3f(nan, 0, 0)}, Eigen::Vector3d::Zero()), 0u);
  OccupancyMapConfig bad;
  bad.prob_hit = 0.4;
  test::expect_throw_naming([&] { OccupancyMap{bad}; }, "prob_hit");
  map.clear();
  EXPECT_EQ(map.voxels(), 0u);
  EXPECT_EQ(map.project(band).width, 0);
  EXPECT_FALSE(map.floor_z().has_value());
}

// OctoMap's own reader trusts its input (children bits past the end of the
// bytes make it recurse and allocate without bound), so crafted files are
// refused before it reads them, each by what is wrong, the map unchanged.
TEST(OccupancyMap, CraftedFilesAreRefusedBeforeOctoMapReadsThem) {
  OccupancyMap map;
  std::vector<Eigen::Vector3f> points;
  for (int i = 0; i < 20; ++i) points.emplace_back(1.0f, 0.05f * i, 0.2f);
  map.insert(points, Eigen::Vector3d::Zero());
  const std::string bytes = map.write();
  const std::size_t data = bytes.find("\ndata\n") + 6;
  ASSERT_NE(data, std::string::npos + 6);
  const std::string header = bytes.substr(0, data), nodes = bytes.substr(data);
  const std::size_t voxels = map.voxels();
  auto node = [](float log_odds, unsigned char children) {
    std::string n(sizeof(float), '\0');
    std::memcpy(n.data(), &log_odds, sizeof(float));
    return n + static_cast<char>(children);
  };
  auto with_size = [&](std::size_t n) {
    const std::size_t at = header.find("size ");
    const std::size_t end = header.find('\n', at);
    return header.substr(0, at) + "size " + std::to_string(n) + header.substr(end);
  };
  auto refused = [&](const std::string& file, const std::string& why) {
    test::expect_throw_naming([&] { map.read(file); }, why);
    EXPECT_EQ(map.voxels(), voxels);
  };
  // A root claiming eight children, and nothing after it.
  refused(with_size(1) + node(0.0f, 0xff), "more nodes than");
  refused(with_size(9) + node(0.0f, 0xff), "cannot hold");
  // A chain of single children deeper than the tree's 16 levels.
  std::string chain;
  for (int d = 0; d <= 17; ++d) chain += node(0.0f, d < 17 ? 1 : 0);
  refused(with_size(18) + chain, "last level");
  // Values that are no log-odds, counts that do not match, bytes left over.
  refused(with_size(1) + node(std::nanf(""), 0), "not finite");
  refused(with_size(2) + node(0.0f, 0) + node(0.0f, 0), "fewer nodes");
  refused(bytes + "x", "after its last node");
  refused(header.substr(0, header.find("id ")) + "id ColorOcTree\n" +
              header.substr(header.find("size ")) + nodes,
          "ColorOcTree");
  refused("# Octomap OcTree file\nid OcTree\nres 0.05\n", "does not end");
  refused("# Octomap OcTree file\nid OcTree\nres 0.05\ndata\n", "lacks");
  // The true file still reads, and an empty map round-trips.
  OccupancyMap copy;
  copy.read(bytes);
  EXPECT_EQ(copy.voxels(), voxels);
  OccupancyMap empty, empty_copy;
  empty_copy.read(empty.write());
  EXPECT_EQ(empty_copy.voxels(), 0u);
}

}  // namespace
}  // namespace long3r

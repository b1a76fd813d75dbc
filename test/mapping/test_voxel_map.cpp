// Voxel map: one point per voxel, running means, the cap and its eviction
// policy, and the atomic .ply / .pcd writers (read back with PCL).
#include <gtest/gtest.h>
#include <pcl/io/pcd_io.h>
#include <pcl/io/ply_io.h>
#include <pcl/point_types.h>
#include <sys/stat.h>
#include <unistd.h>

#include <opencv2/core.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <map>
#include <random>
#include <set>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "long3r/mapping/voxel_map.hpp"
#include "support/test_support.hpp"

namespace long3r {
namespace {

namespace fs = std::filesystem;
using Key = std::array<long, 3>;

Key key_of(const Eigen::Vector3f& p, double voxel) {
  return {static_cast<long>(std::floor(static_cast<double>(p.x()) / voxel)),
          static_cast<long>(std::floor(static_cast<double>(p.y()) / voxel)),
          static_cast<long>(std::floor(static_cast<double>(p.z()) / voxel))};
}
Key key_of(const Eigen::Vector3i& i) { return {i.x(), i.y(), i.z()}; }

std::set<Key> keys_of(const VoxelMap& map) {
  std::set<Key> keys;
  for (const VoxelInfo& v : map.voxels()) keys.insert(key_of(v.index));
  return keys;
}

// A fresh directory per test.
fs::path test_dir() {
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  return test::scratch_dir(std::string("voxel_map/") + info->name());
}

std::vector<std::string> entries(const fs::path& dir) { return test::folder_entries(dir.string()); }

std::string read_all(const fs::path& p) { return test::read_file(p.string()); }

void random_cloud(size_t n, uint64_t seed, std::vector<Eigen::Vector3f>& pts,
                  std::vector<Rgb8>& cols) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<float> pos(-0.5f, 0.5f);
  std::uniform_int_distribution<int> col(0, 255);
  pts.clear();
  cols.clear();
  for (size_t i = 0; i < n; ++i) {
    pts.emplace_back(pos(rng), pos(rng), pos(rng));
    cols.push_back({static_cast<uint8_t>(col(rng)), static_cast<uint8_t>(col(rng)),
                    static_cast<uint8_t>(col(rng))});
  }
}

TEST(VoxelMap, OnePointPerVoxelAtTheMeanOfItsPoints) {
  VoxelMapConfig config;
  config.voxel_size_m = 0.05;
  VoxelMap map(config);
  std::vector<Eigen::Vector3f> pts;
  std::vector<Rgb8> cols;
  random_cloud(30000, 1, pts, cols);
  const IntegrationStats stats = map.integrate(pts, cols, 0);
  EXPECT_EQ(stats.candidates, pts.size());
  EXPECT_EQ(stats.fused, pts.size());
  EXPECT_EQ(stats.evicted, 0u);

  // Expected voxels, computed independently.
  struct Acc {
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    Eigen::Vector3d col = Eigen::Vector3d::Zero();
    uint32_t n = 0;
  };
  std::map<Key, Acc> expected;
  for (size_t i = 0; i < pts.size(); ++i) {
    Acc& a = expected[key_of(pts[i], config.voxel_size_m)];
    a.sum += pts[i].cast<double>();
    a.col += Eigen::Vector3d(cols[i][0], cols[i][1], cols[i][2]);
    ++a.n;
  }
  ASSERT_EQ(map.size(), expected.size());
  EXPECT_EQ(stats.new_voxels, expected.size());

  const std::vector<VoxelInfo> voxels = map.voxels();
  std::set<Key> seen;
  const double v = config.voxel_size_m;
  for (const VoxelInfo& vox : voxels) {
    const Key k = key_of(vox.index);
    EXPECT_TRUE(seen.insert(k).second) << "two points in one voxel";
    ASSERT_TRUE(expected.count(k));
    const Acc& a = expected.at(k);
    EXPECT_EQ(vox.hits, a.n);
    EXPECT_EQ(vox.last_seen, 0);
    // The point lies inside its voxel and is the mean of the voxel's points.
    for (int ax = 0; ax < 3; ++ax) {
      EXPECT_GE(vox.position[ax], k[ax] * v - 1e-6);
      EXPECT_LE(vox.position[ax], (k[ax] + 1) * v + 1e-6);
      EXPECT_NEAR(vox.position[ax], a.sum[ax] / a.n, 1e-6);
      EXPECT_NEAR(vox.color[ax], a.col[ax] / a.n, 0.5 + 1e-3);
    }
  }
  // The snapshot holds the same points.
  const MapSnapshot snap = map.snapshot();
  ASSERT_EQ(snap.points.size(), voxels.size());
  ASSERT_EQ(snap.colors.size(), voxels.size());
  std::set<Key> snap_keys;
  for (const auto& p : snap.points) snap_keys.insert(key_of(p, v));
  EXPECT_EQ(snap_keys.size(), snap.points.size());
}

TEST(VoxelMap, FusesOnlyConfidentFinitePixels) {
  VoxelMapConfig config;
  config.voxel_size_m = 0.1;
  config.conf_threshold = 3.0f;
  VoxelMap map(config);
  cv::Mat pts(10, 10, CV_32FC3), conf(10, 10, CV_32FC1), rgb(10, 10, CV_8UC3);
  for (int v = 0; v < 10; ++v) {
    for (int u = 0; u < 10; ++u) {
      pts.at<cv::Vec3f>(v, u) = cv::Vec3f(0.25f * u, 0.25f * v, 1.0f);  // one voxel each
      conf.at<float>(v, u) = (u + v) % 2 == 0 ? 3.0f : 2.99f;
      rgb.at<cv::Vec3b>(v, u) = cv::Vec3b(u, v, 7);
    }
  }
  pts.at<cv::Vec3f>(0, 0)[0] = std::numeric_limits<float>::quiet_NaN();
  const uint64_t rev0 = map.revision();
  const IntegrationStats s = map.integrate(pts, conf, rgb, 3);
  EXPECT_EQ(s.candidates, 49u);
  EXPECT_EQ(map.size(), 49u);
  EXPECT_GT(map.revision(), rev0);
  for (const VoxelInfo& vox : map.voxels()) {
    const int u = static_cast<int>(std::lround(vox.position.x() / 0.25f));
    const int v = static_cast<int>(std::lround(vox.position.y() / 0.25f));
    EXPECT_EQ((u + v) % 2, 0);
    EXPECT_EQ(vox.color, (Rgb8{static_cast<uint8_t>(u), static_cast<uint8_t>(v), 7}));
    EXPECT_EQ(vox.last_seen, 3);
  }
  EXPECT_THROW(map.integrate(pts, conf, cv::Mat(10, 10, CV_8UC4), 4), std::invalid_argument);
  EXPECT_THROW(VoxelMap(VoxelMapConfig{0.0, 10, 1.0f}), std::invalid_argument);
  EXPECT_THROW(VoxelMap(VoxelMapConfig{0.1, 0, 1.0f}), std::invalid_argument);
  map.clear();
  EXPECT_TRUE(map.empty());
}

// Voxel 1 m: each point below names its voxel directly.
TEST(VoxelMap, EvictsLeastRecentlySeenThenFewestHits) {
  VoxelMapConfig config;
  config.voxel_size_m = 1.0;
  config.max_points = 4;
  VoxelMap map(config);
  auto add = [&](std::vector<Eigen::Vector3f> pts, int64_t frame) {
    return map.integrate(pts, std::vector<Rgb8>(pts.size(), Rgb8{1, 2, 3}), frame);
  };
  const Eigen::Vector3f A(0.5f, 0.5f, 0.5f), B(1.5f, 0.5f, 0.5f), C(2.5f, 0.5f, 0.5f),
      D(3.5f, 0.5f, 0.5f), E(4.5f, 0.5f, 0.5f), F(5.5f, 0.5f, 0.5f), G(6.5f, 0.5f, 0.5f);
  add({A, A, B}, 0);  // A: 2 hits, B: 1 hit, both last seen at 0
  add({C, C, C, D}, 1);
  EXPECT_EQ(map.size(), 4u);
  IntegrationStats s = add({E}, 2);  // over the cap: frame 0 goes first, B (fewer hits)
  EXPECT_EQ(s.evicted, 1u);
  EXPECT_EQ(map.size(), 4u);
  EXPECT_EQ(keys_of(map), (std::set<Key>{{0, 0, 0}, {2, 0, 0}, {3, 0, 0}, {4, 0, 0}}));
  s = add({A, F}, 3);  // A is seen again; frame 1 is now the oldest: D (1 hit) before C
  EXPECT_EQ(s.evicted, 1u);
  EXPECT_EQ(keys_of(map), (std::set<Key>{{0, 0, 0}, {2, 0, 0}, {4, 0, 0}, {5, 0, 0}}));
  s = add({G, G}, 4);  // C (frame 1) goes
  EXPECT_EQ(keys_of(map), (std::set<Key>{{0, 0, 0}, {4, 0, 0}, {5, 0, 0}, {6, 0, 0}}));
  // E (frame 2) goes, then F (frame 3, 1 hit) before A (frame 3, 3 hits).
  const Eigen::Vector3f P(-0.5f, 0.5f, 0.5f), Q(-1.5f, 0.5f, 0.5f), R(7.5f, 0.5f, 0.5f),
      S(8.5f, 0.5f, 0.5f), T(9.5f, 0.5f, 0.5f), X(10.5f, 0.5f, 0.5f);
  s = add({P, Q}, 5);
  EXPECT_EQ(s.evicted, 2u);
  EXPECT_EQ(keys_of(map), (std::set<Key>{{0, 0, 0}, {6, 0, 0}, {-1, 0, 0}, {-2, 0, 0}}));
  add({R}, 6);  // A (frame 3)
  EXPECT_EQ(keys_of(map), (std::set<Key>{{6, 0, 0}, {-1, 0, 0}, {-2, 0, 0}, {7, 0, 0}}));
  add({S}, 7);  // G (frame 4)
  EXPECT_EQ(keys_of(map), (std::set<Key>{{-1, 0, 0}, {-2, 0, 0}, {7, 0, 0}, {8, 0, 0}}));
  add({T}, 8);  // P and Q: same frame, same hits: the lower index, Q, goes
  EXPECT_EQ(keys_of(map), (std::set<Key>{{-1, 0, 0}, {7, 0, 0}, {8, 0, 0}, {9, 0, 0}}));
  // One frame alone over the cap: all older voxels go, then that frame's
  // fewest-hit ones (G and X tie at 1 hit: G has the lower index).
  s = add({D, D, D, E, E, F, F, F, F, G, X}, 9);
  EXPECT_EQ(s.evicted, 5u);
  EXPECT_EQ(map.size(), 4u);
  EXPECT_EQ(keys_of(map), (std::set<Key>{{3, 0, 0}, {4, 0, 0}, {5, 0, 0}, {10, 0, 0}}));
}

// Against a brute-force model of the policy over many frames.
TEST(VoxelMap, EvictionMatchesTheReferencePolicy) {
  VoxelMapConfig config;
  config.voxel_size_m = 0.1;
  config.max_points = 500;
  VoxelMap map(config);
  struct Ref {
    uint32_t hits;
    int64_t last;
  };
  std::map<Key, Ref> ref;
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<float> jitter(0.01f, 0.09f);
  std::vector<Eigen::Vector3f> history;
  size_t total_evicted = 0;
  for (int64_t frame = 0; frame < 40; ++frame) {
    std::vector<Eigen::Vector3f> pts;
    std::uniform_int_distribution<int> cell(0, 14);
    for (int i = 0; i < 120; ++i) {  // new area of the scene
      pts.emplace_back(0.1f * (cell(rng) + 15 * frame) + jitter(rng),
                       0.1f * cell(rng) + jitter(rng), jitter(rng));
    }
    for (int i = 0; i < 80 && !history.empty(); ++i) {  // revisits
      pts.push_back(history[std::uniform_int_distribution<size_t>(0, history.size() - 1)(rng)]);
    }
    history.insert(history.end(), pts.begin(), pts.begin() + 120);

    const IntegrationStats s = map.integrate(pts, std::vector<Rgb8>(pts.size()), frame);
    for (const auto& p : pts) {
      auto [it, inserted] = ref.try_emplace(key_of(p, config.voxel_size_m), Ref{0, frame});
      ++it->second.hits;
      it->second.last = std::max(it->second.last, frame);
    }
    size_t evicted = 0;
    if (ref.size() > config.max_points) {
      std::vector<std::pair<std::tuple<int64_t, uint32_t, Key>, Key>> order;
      for (const auto& [k, r] : ref) order.push_back({{r.last, r.hits, k}, k});
      std::sort(order.begin(), order.end());
      evicted = ref.size() - config.max_points;
      for (size_t i = 0; i < evicted; ++i) ref.erase(order[i].second);
    }
    total_evicted += evicted;
    ASSERT_EQ(s.evicted, evicted) << "frame " << frame;
    ASSERT_LE(map.size(), config.max_points);
    std::set<Key> ref_keys;
    for (const auto& [k, r] : ref) ref_keys.insert(k);
    ASSERT_EQ(keys_of(map), ref_keys) << "frame " << frame;
    for (const VoxelInfo& v : map.voxels()) {
      const Ref& r = ref.at(key_of(v.index));
      ASSERT_EQ(v.hits, r.hits);
      ASSERT_EQ(v.last_seen, r.last);
    }
  }
  EXPECT_GT(total_evicted, 2000u);
}

MapSnapshot small_cloud() {
  MapSnapshot s;
  std::vector<Eigen::Vector3f> pts;
  std::vector<Rgb8> cols;
  random_cloud(1234, 9, pts, cols);
  pts[0] = Eigen::Vector3f(1e-7f, -123456.789f, 3.0f);  // values that must survive exactly
  s.points = pts;
  s.colors = cols;
  return s;
}

template <typename Cloud>
void expect_cloud_equals(const Cloud& cloud, const MapSnapshot& s) {
  ASSERT_EQ(cloud.size(), s.points.size());
  for (size_t i = 0; i < s.points.size(); ++i) {
    ASSERT_EQ(cloud[i].x, s.points[i].x()) << i;
    ASSERT_EQ(cloud[i].y, s.points[i].y()) << i;
    ASSERT_EQ(cloud[i].z, s.points[i].z()) << i;
    ASSERT_EQ(cloud[i].r, s.colors[i][0]) << i;
    ASSERT_EQ(cloud[i].g, s.colors[i][1]) << i;
    ASSERT_EQ(cloud[i].b, s.colors[i][2]) << i;
  }
}

TEST(MapFile, PlyAndPcdAreReadableByPcl) {
  const fs::path dir = test_dir();
  const MapSnapshot s = small_cloud();
  for (bool ascii : {false, true}) {
    const std::string tag = ascii ? "ascii" : "binary";
    MapSaveOptions options;
    options.ascii = ascii;
    const fs::path ply = dir / ("map_" + tag + ".ply");
    const fs::path pcd = dir / ("map_" + tag + ".PCD");  // extension case does not matter
    save_colored_cloud(ply.string(), s.points, s.colors, options);
    save_colored_cloud(pcd.string(), s.points, s.colors, options);

    const std::string head = read_all(ply).substr(0, 64);
    EXPECT_NE(head.find(ascii ? "format ascii 1.0" : "format binary_little_endian 1.0"),
              std::string::npos);
    pcl::PointCloud<pcl::PointXYZRGB> from_ply, from_pcd;
    ASSERT_EQ(pcl::io::loadPLYFile(ply.string(), from_ply), 0) << tag;
    expect_cloud_equals(from_ply, s);
    ASSERT_EQ(pcl::io::loadPCDFile(pcd.string(), from_pcd), 0) << tag;
    expect_cloud_equals(from_pcd, s);
  }
  EXPECT_EQ(entries(dir).size(), 4u);  // no temporaries left
  EXPECT_EQ(fs::status(dir / "map_binary.ply").permissions() & fs::perms::others_read,
            fs::perms::others_read);
  fs::remove_all(dir);
}

TEST(MapFile, VoxelMapSaveWritesItsSnapshot) {
  const fs::path dir = test_dir();
  VoxelMapConfig config;
  config.voxel_size_m = 0.05;
  VoxelMap map(config);
  std::vector<Eigen::Vector3f> pts;
  std::vector<Rgb8> cols;
  random_cloud(5000, 3, pts, cols);
  map.integrate(pts, cols, 0);
  map.save((dir / "map.ply").string());
  pcl::PointCloud<pcl::PointXYZRGB> cloud;
  ASSERT_EQ(pcl::io::loadPLYFile((dir / "map.ply").string(), cloud), 0);
  expect_cloud_equals(cloud, map.snapshot());
  fs::remove_all(dir);
}

TEST(MapFile, UnknownExtensionIsRejected) {
  const fs::path dir = test_dir();
  const MapSnapshot s = small_cloud();
  for (const char* name : {"map.xyz", "map", "map.ply.bak"}) {
    try {
      save_colored_cloud((dir / name).string(), s.points, s.colors);
      FAIL() << name;
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find("extension"), std::string::npos) << e.what();
    }
  }
  EXPECT_TRUE(entries(dir).empty());
  EXPECT_THROW(save_colored_cloud((dir / "a.ply").string(), s.points, {}), std::invalid_argument);
  fs::remove_all(dir);
}

TEST(MapFile, OverwriteReplacesTheFileAtomically) {
  const fs::path dir = test_dir();
  const fs::path target = dir / "map.ply";
  const MapSnapshot s = small_cloud();
  { std::ofstream(target) << "old"; }
  save_colored_cloud(target.string(), s.points, s.colors);
  pcl::PointCloud<pcl::PointXYZRGB> cloud;
  ASSERT_EQ(pcl::io::loadPLYFile(target.string(), cloud), 0);
  expect_cloud_equals(cloud, s);
  EXPECT_EQ(entries(dir), std::vector<std::string>{"map.ply"});
  fs::remove_all(dir);
}

// A directory where no file can be created: the call throws and leaves the
// old file as it was. (root ignores permission bits, so as root the
// directory is one in /proc, where nobody can create files.)
TEST(MapFile, UnwritableDirectoryFailsCleanly) {
  const MapSnapshot s = small_cloud();
  if (::geteuid() != 0) {
    const fs::path dir = test_dir();
    const fs::path target = dir / "map.pcd";
    { std::ofstream(target) << "old map"; }
    fs::permissions(dir, fs::perms::owner_read | fs::perms::owner_exec);
    EXPECT_THROW(save_colored_cloud(target.string(), s.points, s.colors), std::runtime_error);
    fs::permissions(dir, fs::perms::owner_all);
    EXPECT_EQ(read_all(target), "old map");
    EXPECT_EQ(entries(dir), std::vector<std::string>{"map.pcd"});
    fs::remove_all(dir);
  } else {
    try {
      save_colored_cloud("/proc/self/long3r_map.ply", s.points, s.colors);
      FAIL() << "no exception";
    } catch (const std::runtime_error& e) {
      EXPECT_NE(std::string(e.what()).find("/proc/self/long3r_map.ply"), std::string::npos);
    }
  }
  const fs::path missing = fs::temp_directory_path() / "long3r_no_such_dir" / "x" / "map.ply";
  EXPECT_THROW(save_colored_cloud(missing.string(), s.points, s.colors), std::runtime_error);
}

// The disk fills up in the middle of the write (RLIMIT_FSIZE makes write()
// fail with EFBIG): the target keeps its old content and the partial
// temporary is removed.
TEST(MapFile, FailedWriteLeavesTheOldFileAndNoTemporary) {
  const fs::path dir = test_dir();
  const fs::path target = dir / "map.ply";
  const MapSnapshot s = small_cloud();  // ~18 kB as binary PLY
  { std::ofstream(target) << "old map"; }

  bool threw = false;
  std::string what;
  {
    const test::FileSizeLimit limit(4096);
    try {
      save_colored_cloud(target.string(), s.points, s.colors);
    } catch (const std::runtime_error& e) {
      threw = true;
      what = e.what();
    }
  }

  EXPECT_TRUE(threw);
  EXPECT_NE(what.find("write failed"), std::string::npos) << what;
  EXPECT_EQ(read_all(target), "old map");
  EXPECT_EQ(entries(dir), std::vector<std::string>{"map.ply"});
  fs::remove_all(dir);
}

// rename() over a directory fails after the data was written: the
// temporary is removed and the directory is untouched.
TEST(MapFile, FailedRenameRemovesTheTemporary) {
  const fs::path dir = test_dir();
  fs::create_directory(dir / "map.ply");
  { std::ofstream(dir / "map.ply" / "keep") << "x"; }
  const MapSnapshot s = small_cloud();
  EXPECT_THROW(save_colored_cloud((dir / "map.ply").string(), s.points, s.colors),
               std::runtime_error);
  EXPECT_EQ(entries(dir), std::vector<std::string>{"map.ply"});
  EXPECT_TRUE(fs::is_directory(dir / "map.ply"));
  EXPECT_EQ(entries(dir / "map.ply"), std::vector<std::string>{"keep"});
  fs::remove_all(dir);
}

}  // namespace
}  // namespace long3r

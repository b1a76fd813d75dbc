// SurfaceMap: off, it holds nothing; on, a rescale rebuilds the volume from
// the kept frames as if they had come in at the new scale; the frames kept
// are capped; sessions keep the frames and rebuild from them; the surface
// and the mesh are read while frames are fused.
#include <gtest/gtest.h>

#include <ATen/ATen.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <string>
#include <thread>
#include <vector>

#include "long3r/mapping/surface_map.hpp"
#include "support/cv_test_support.hpp"
#include "support/test_support.hpp"

namespace long3r {
namespace {

// A box-shaped room's far wall and floor seen from cameras stepping along x:
// camera-frame points of a slanted plane (depth 2 m at the top row, 3 m at
// the bottom), grey.
struct Scene {
  PinholeIntrinsics K = PinholeIntrinsics::from_hfov(48, 36, 70.0);
  cv::Mat points_C, rgb{36, 48, CV_8UC3, cv::Scalar(120, 130, 140)};
  Scene() {
    points_C = test::pointmap_from_depth(K, Eigen::Isometry3d::Identity(),
                                         [](int, int v) { return 2.0 + v / 35.0; });
  }
  static Eigen::Isometry3d pose(int k, double scale = 1.0) {
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.translation().x() = 0.02 * k * scale;
    return T;
  }
};

SurfaceMapConfig enabled_config() {
  SurfaceMapConfig c;
  c.enabled = true;
  c.tsdf.voxel_size_m = 0.05;
  c.tsdf.truncation_m = 0.2;
  c.tsdf.min_weight = 1.0f;
  return c;
}

std::vector<Eigen::Vector3f> sorted(std::vector<Eigen::Vector3f> p) {
  std::sort(p.begin(), p.end(), [](const Eigen::Vector3f& a, const Eigen::Vector3f& b) {
    return std::lexicographical_compare(a.data(), a.data() + 3, b.data(), b.data() + 3);
  });
  return p;
}

class SurfaceMapTest : public ::testing::Test {
 protected:
  void SetUp() override {
    if (!TsdfVolume::available()) GTEST_SKIP() << "built without Open3D";
  }
};

TEST(SurfaceMapOff, HoldsNothing) {
  SurfaceMap off;  // the default config: off
  const Scene s;
  EXPECT_EQ(off.integrate(s.points_C, s.rgb, cv::Mat(), 0.0f, s.K, Scene::pose(0)), 0u);
  EXPECT_TRUE(off.points().points.empty());
  EXPECT_TRUE(off.mesh().triangles.empty());
  EXPECT_EQ(off.frames_kept(), 0u);
  off.rescale(2.0);
  off.clear();
}

TEST_F(SurfaceMapTest, RescaleRebuildsAsIfTheFramesCameAtTheNewScale) {
  const Scene s;
  SurfaceMap rescaled(enabled_config()), direct(enabled_config());
  for (int k = 0; k < 6; ++k) {
    rescaled.integrate(s.points_C, s.rgb, cv::Mat(), 0.0f, s.K, Scene::pose(k));
    direct.integrate(s.points_C * 1.5, s.rgb, cv::Mat(), 0.0f, s.K, Scene::pose(k, 1.5));
  }
  const std::uint64_t before = rescaled.revision();
  const std::size_t points_before = rescaled.points().points.size();
  rescaled.rescale(1.5);
  EXPECT_GT(rescaled.revision(), before);
  const auto a = sorted(rescaled.points().points), b = sorted(direct.points().points);
  ASSERT_EQ(a.size(), b.size());
  EXPECT_NE(a.size(), points_before);  // a larger surface in voxels of the same size
  for (std::size_t i = 0; i < a.size(); ++i) ASSERT_LT((a[i] - b[i]).norm(), 1e-4f) << i;
  EXPECT_EQ(rescaled.mesh().triangles.size(), direct.mesh().triangles.size());
  test::expect_throw_naming([&] { rescaled.rescale(0.0); }, "factor");
  test::expect_throw_naming([&] { rescaled.rescale(NAN); }, "factor");
}

TEST_F(SurfaceMapTest, KeepsAtMostKeepFramesForRebuilds) {
  const Scene s;
  SurfaceMapConfig c = enabled_config();
  c.keep_frames = 3;
  SurfaceMap map(c);
  for (int k = 0; k < 5; ++k) {
    EXPECT_GT(map.integrate(s.points_C, s.rgb, cv::Mat(), 0.0f, s.K, Scene::pose(k)), 0u);
  }
  EXPECT_EQ(map.frames_kept(), 3u);
  EXPECT_EQ(map.frames_dropped(), 2u);
  EXPECT_FALSE(map.points().points.empty());
  map.clear();
  EXPECT_EQ(map.frames_kept(), 0u);
  EXPECT_EQ(map.frames_dropped(), 0u);
  EXPECT_TRUE(map.points().points.empty());
  c.keep_frames = -1;
  test::expect_throw_naming([&] { SurfaceMap{c}; }, "keep_frames");
}

TEST_F(SurfaceMapTest, BadFrameChangesNothing) {
  const Scene s;
  SurfaceMap map(enabled_config());
  map.integrate(s.points_C, s.rgb, cv::Mat(), 0.0f, s.K, Scene::pose(0));
  const std::uint64_t revision = map.revision();
  EXPECT_THROW(
      map.integrate(s.points_C, cv::Mat(3, 3, CV_8UC3), cv::Mat(), 0.0f, s.K, Scene::pose(1)),
      std::invalid_argument);
  EXPECT_EQ(map.revision(), revision);
  EXPECT_EQ(map.frames_kept(), 1u);
}

// Sessions keep the frames and rebuild the volume from them: the restored
// surface is the saved one, point for point. Damaged parts are refused by
// name and change nothing.
TEST_F(SurfaceMapTest, SavesItsFramesAndRebuildsFromThem) {
  const Scene s;
  SurfaceMap map(enabled_config());
  for (int k = 0; k < 4; ++k)
    map.integrate(s.points_C, s.rgb, cv::Mat(), 0.0f, s.K, Scene::pose(k));
  const StateDict saved = map.state();
  SurfaceMap copy(enabled_config());
  copy.restore(StateReader(saved, "surface"));
  EXPECT_EQ(copy.frames_kept(), 4u);
  ASSERT_FALSE(map.points().points.empty());
  EXPECT_EQ(sorted(copy.points().points), sorted(map.points().points));
  EXPECT_EQ(copy.mesh().triangles.size(), map.mesh().triangles.size());

  const std::vector<Eigen::Vector3f> before = sorted(copy.points().points);
  auto refused = [&](StateDict damaged, const std::string& why) {
    test::expect_throw_naming([&] { copy.restore(StateReader(damaged, "surface")); }, why);
    EXPECT_EQ(copy.frames_kept(), 4u);
    EXPECT_EQ(sorted(copy.points().points), before);
  };
  StateDict d = saved;
  d["2.depth"] = saved.at("2.depth").clone().fill_(-1.0f);
  refused(d, "negative");
  d = saved;
  d["1.depth"] = saved.at("1.depth").clone().fill_(NAN);
  refused(d, "non-finite");
  d = saved;
  d["0.rgb"] = saved.at("0.rgb").narrow(0, 0, 5).clone();
  refused(d, "0.rgb");
  d = saved;
  d["3.T_W_C"] = saved.at("3.T_W_C").clone().mul_(2.0);
  refused(d, "3.T_W_C");
  d = saved;
  d["3.K"] = saved.at("3.K").clone().fill_(0.0);
  refused(d, "3.K");
  d = saved;
  d.erase("3.depth");
  refused(d, "3.depth");
  SurfaceMapConfig few = enabled_config();
  few.keep_frames = 2;
  SurfaceMap small(few);
  test::expect_throw_naming([&] { small.restore(StateReader(saved, "surface")); }, "frames");
  EXPECT_EQ(small.frames_kept(), 0u);
  // Off, it takes nothing.
  SurfaceMap off;
  off.restore(StateReader(saved, "surface"));
  EXPECT_EQ(off.frames_kept(), 0u);
}

TEST_F(SurfaceMapTest, ReadWhileFramesAreFused) {
  const Scene s;
  SurfaceMap map(enabled_config());
  std::atomic<bool> done{false};
  std::size_t reads = 0;
  std::thread reader([&] {
    while (!done) {
      const ColoredPoints p = map.points();
      EXPECT_EQ(p.points.size(), p.colors.size());
      map.mesh();
      ++reads;
    }
  });
  for (int k = 0; k < 20; ++k) {
    map.integrate(s.points_C, s.rgb, cv::Mat(), 0.0f, s.K, Scene::pose(k));
    if (k == 10) map.rescale(1.2);
  }
  done = true;
  reader.join();
  EXPECT_GT(reads, 0u);
  EXPECT_EQ(map.frames_kept(), 20u);
}

}  // namespace
}  // namespace long3r

#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>

#include "long3r/dataset/tum_dataset.hpp"
#include "long3r/synth/cv/sensor_image.hpp"
#include "long3r/synth/cv/tum_writer.hpp"
#include "long3r/synth/generate.hpp"
#include "long3r/synth/geometry.hpp"
#include "long3r/synth/render.hpp"
#include "support/cv_test_support.hpp"
#include "support/test_support.hpp"

using namespace long3r;
using namespace long3r::synth;

namespace {

using test::read_file;
using test::scratch_dir;

bool is_planar(const Scene& scene, int surface_id) {
  if (surface_id < 0) return false;
  if (surface_id < 16) return true;  // room walls, floor, ceiling
  return scene.shapes[surface_id / 16 - 1].type == ShapeType::kBox;
}

// Checks that depth, poses and intrinsics agree: pixels of view a on planar
// surfaces are back-projected to the world, projected into view b, and
// compared with b's depth there (inverse depth interpolates exactly along a
// plane). Returns the number of pixels checked; fills the worst 3D error.
int cross_view_check(const Scene& scene, const PinholeIntrinsics& k, const Eigen::Isometry3d& Ta,
                     const RenderedFrame& a, const Eigen::Isometry3d& Tb, const RenderedFrame& b,
                     double* worst) {
  const cv::Mat depth_a = depth_image(a), id_a = surface_id_image(a);
  const cv::Mat depth_b = depth_image(b), id_b = surface_id_image(b);
  int checked = 0;
  *worst = 0.0;
  const Eigen::Isometry3d Tb_inv = Tb.inverse();
  for (int v = 0; v < k.height; ++v) {
    for (int u = 0; u < k.width; ++u) {
      const int id = id_a.at<int32_t>(v, u);
      const double za = depth_a.at<float>(v, u);
      if (!is_planar(scene, id) || !(za > 0)) continue;
      const Eigen::Vector3d X = Ta * k.backproject(u, v, za);
      const Eigen::Vector3d pb = Tb_inv * X;
      if (pb.z() <= 0.05) continue;
      const Eigen::Vector2d px = k.project(pb);
      const int u0 = static_cast<int>(std::floor(px.x())),
                v0 = static_cast<int>(std::floor(px.y()));
      if (u0 < 0 || v0 < 0 || u0 + 1 >= k.width || v0 + 1 >= k.height) continue;
      bool same = true;
      double inv = 0.0;
      const double fu = px.x() - u0, fv = px.y() - v0;
      for (int dy = 0; dy < 2; ++dy) {
        for (int dx = 0; dx < 2; ++dx) {
          if (id_b.at<int32_t>(v0 + dy, u0 + dx) != id) same = false;
          const double w = (dx ? fu : 1 - fu) * (dy ? fv : 1 - fv);
          inv += w / depth_b.at<float>(v0 + dy, u0 + dx);
        }
      }
      if (!same) continue;  // occluded or at a surface boundary in view b
      const Eigen::Vector3d Xb = Tb * k.backproject(px.x(), px.y(), 1.0 / inv);
      *worst = std::max(*worst, (Xb - X).norm());
      ++checked;
    }
  }
  return checked;
}

}  // namespace

TEST(SynthGenerator, RngIsPortableAndSeeded) {
  // mt19937_64's 10000th output is fixed by the C++ standard.
  Rng r(5489u);
  for (int i = 0; i < 9999; ++i) r.next_u64();
  EXPECT_EQ(r.next_u64(), 9981545732273789042ull);
  Rng a(1), b(1), c(2);
  for (int i = 0; i < 100; ++i) {
    const double x = a.uniform(-1.0, 2.0);
    EXPECT_EQ(x, b.uniform(-1.0, 2.0));
    EXPECT_GE(x, -1.0);
    EXPECT_LT(x, 2.0);
    const int k = a.uniform_int(3, 5);
    EXPECT_EQ(k, b.uniform_int(3, 5));
    EXPECT_TRUE(k >= 3 && k <= 5);
  }
  EXPECT_NE(Rng(1).next_u64(), c.next_u64());
}

TEST(SynthGenerator, DepthPosesAndIntrinsicsAgreeAcrossViews) {
  SequenceConfig cfg = test::sequence_config(21, TrajectoryType::kWalk, 12, 128, 96);
  cfg.intrinsics.cx = 60.3;  // off-centre principal point and non-square pixels
  cfg.intrinsics.fy = cfg.intrinsics.fx * 1.1;
  const Sequence seq = generate_sequence(cfg);
  const auto& k = cfg.intrinsics;
  const RenderedFrame a = render_frame(seq.scene, seq.poses[0], k);
  for (int j : {4, 11}) {
    const RenderedFrame b = render_frame(seq.scene, seq.poses[j], k);
    double worst = 0.0;
    const int n = cross_view_check(seq.scene, k, seq.poses[0], a, seq.poses[j], b, &worst);
    EXPECT_GT(n, k.width * k.height / 5) << "too few co-visible pixels with frame " << j;
    EXPECT_LT(worst, 1e-4) << "frame " << j;
  }
}

TEST(SynthGenerator, WrongIntrinsicsBreakTheCrossViewCheck) {
  // The check above must be able to fail: a 2% focal error is detected.
  const SequenceConfig cfg = test::sequence_config(21, TrajectoryType::kWalk, 12, 128, 96);
  const Sequence seq = generate_sequence(cfg);
  const RenderedFrame a = render_frame(seq.scene, seq.poses[0], cfg.intrinsics);
  const RenderedFrame b = render_frame(seq.scene, seq.poses[11], cfg.intrinsics);
  PinholeIntrinsics wrong = cfg.intrinsics;
  wrong.fx *= 1.02;
  double worst = 0.0;
  cross_view_check(seq.scene, wrong, seq.poses[0], a, seq.poses[11], b, &worst);
  EXPECT_GT(worst, 1e-3);
}

TEST(SynthGenerator, SameSeedSameBytesAnyThreadCount) {
  const SequenceConfig cfg = test::sequence_config(5, TrajectoryType::kOrbit, 4, 64, 48);
  const std::string d1 = scratch_dir("synth_det_1"), d2 = scratch_dir("synth_det_2");
  RenderOptions one, three;
  one.threads = 1;
  three.threads = 3;
  write_tum_sequence(generate_sequence(cfg), d1, one);
  write_tum_sequence(generate_sequence(cfg), d2, three);
  int files = 0;
  for (const auto& e : std::filesystem::recursive_directory_iterator(d1)) {
    if (!e.is_regular_file()) continue;
    const auto rel = std::filesystem::relative(e.path(), d1);
    EXPECT_EQ(read_file(e.path().string()), read_file((std::filesystem::path(d2) / rel).string()))
        << rel;
    ++files;
  }
  EXPECT_EQ(files, 4 * 2 + 5);  // images + rgb/depth lists, gt, calibration, scene.json

  // A different seed gives a different scene.
  SequenceConfig other = cfg;
  other.seed = 6;
  const Sequence s1 = generate_sequence(cfg), s2 = generate_sequence(other);
  const cv::Mat i1 = bgr_image(render_frame(s1.scene, s1.poses[0], cfg.intrinsics));
  const cv::Mat i2 = bgr_image(render_frame(s2.scene, s2.poses[0], cfg.intrinsics));
  EXPECT_GT(cv::norm(i1, i2, cv::NORM_L1), 0.0);
}

TEST(SynthGenerator, CameraStaysClearOfEverySurface) {
  for (TrajectoryType type : {TrajectoryType::kWalk, TrajectoryType::kOrbit,
                              TrajectoryType::kPanReturn, TrajectoryType::kRobot}) {
    for (uint64_t seed : {1u, 2u, 3u}) {
      SequenceConfig cfg = test::sequence_config(seed, type, 2000);
      const Sequence seq = generate_sequence(cfg);
      ASSERT_EQ(seq.poses.size(), 2000u);
      const double c = cfg.trajectory.clearance;
      const Eigen::Vector3d room = seq.scene.room_size;
      double worst_step = 0.0, worst_turn = 0.0;
      for (size_t i = 0; i < seq.poses.size(); ++i) {
        const Eigen::Vector3d p = seq.poses[i].translation();
        for (int a = 0; a < 3; ++a) {
          ASSERT_GE(p(a), c) << to_string(type) << " seed " << seed << " frame " << i;
          ASSERT_LE(p(a), room(a) - c) << to_string(type) << " seed " << seed << " frame " << i;
        }
        for (const Shape& s : seq.scene.shapes) {
          ASSERT_GE(s.distance(p), c) << to_string(type) << " " << s.label << " frame " << i;
        }
        EXPECT_NEAR(seq.poses[i].linear().determinant(), 1.0, 1e-9);
        if (i > 0) {
          worst_step = std::max(worst_step, (p - seq.poses[i - 1].translation()).norm());
          const Eigen::AngleAxisd d(seq.poses[i - 1].linear().transpose() * seq.poses[i].linear());
          worst_turn = std::max(worst_turn, std::abs(d.angle()) * 180.0 / M_PI);
        }
      }
      // Smooth motion: about `speed` per frame, a few degrees at most.
      EXPECT_LE(worst_step, 1.25 * cfg.trajectory.speed) << to_string(type);
      EXPECT_LE(worst_turn, 3.0) << to_string(type);
      EXPECT_GE(seq.scene.shapes.size(), 5u) << to_string(type) << " seed " << seed;
      // Nothing is rendered closer than the clearance allows (z >= distance * cos(corner angle)).
      const cv::Mat depth = depth_image(render_frame(seq.scene, seq.poses[777], cfg.intrinsics));
      double min_depth = 1e9;
      for (int v = 0; v < depth.rows; ++v) {
        for (int u = 0; u < depth.cols; ++u)
          min_depth = std::min<double>(min_depth, depth.at<float>(v, u));
      }
      EXPECT_GT(min_depth, 0.6 * c) << to_string(type);
    }
  }
}

TEST(SynthGenerator, RevisitingTrajectoriesReturn) {
  // Pan-and-return comes back to where it started; an orbit closes its circle.
  const Sequence pan =
      generate_sequence(test::sequence_config(4, TrajectoryType::kPanReturn, 2000));
  double closest = 1e9;
  for (size_t i = 300; i < pan.poses.size(); ++i) {
    closest = std::min(closest, (pan.poses[i].translation() - pan.poses[0].translation()).norm());
  }
  EXPECT_LT(closest, 0.05);
  const Sequence walk = generate_sequence(test::sequence_config(4, TrajectoryType::kWalk, 2000));
  closest = 1e9;
  for (size_t i = 600; i < walk.poses.size(); ++i) {
    closest = std::min(closest, (walk.poses[i].translation() - walk.poses[0].translation()).norm());
  }
  EXPECT_LT(closest, 0.2);  // the loop is walked more than once in 40 m
}

TEST(SynthGenerator, ImagesCarryMatchableTexture) {
  const SequenceConfig cfg = test::sequence_config(8, TrajectoryType::kWalk, 10, 224, 224);
  const Sequence seq = generate_sequence(cfg);
  for (int i : {0, 9}) {
    const RenderedFrame f = render_frame(seq.scene, seq.poses[i], cfg.intrinsics);
    cv::Mat grey;
    cv::cvtColor(bgr_image(f), grey, cv::COLOR_BGR2GRAY);
    std::vector<cv::Point2f> corners;
    cv::goodFeaturesToTrack(grey, corners, 500, 0.01, 5.0);
    EXPECT_GT(corners.size(), 100u) << "frame " << i;
    cv::Mat lap;
    cv::Laplacian(grey, lap, CV_64F);
    cv::Scalar mean, stddev;
    cv::meanStdDev(lap, mean, stddev);
    EXPECT_GT(stddev[0], 5.0) << "frame " << i;
  }
}

TEST(SynthGenerator, RejectsBadConfigs) {
  SequenceConfig c = test::sequence_config(1, TrajectoryType::kWalk, 0);
  EXPECT_THROW(generate_sequence(c), std::invalid_argument);
  c.trajectory.frames = 10;
  c.trajectory.clearance = 3.0;  // no room left for the camera
  EXPECT_THROW(generate_sequence(c), std::invalid_argument);
  EXPECT_THROW(trajectory_type_from_string("spiral"), std::invalid_argument);
  EXPECT_EQ(trajectory_type_from_string("pan"), TrajectoryType::kPanReturn);
  EXPECT_EQ(trajectory_type_from_string("robot"), TrajectoryType::kRobot);
  c = test::sequence_config(1, TrajectoryType::kRobot, 10);
  c.trajectory.max_yaw_rate_deg = 0.2;  // a turning circle wider than any room
  EXPECT_THROW(generate_sequence(c), std::invalid_argument);
}

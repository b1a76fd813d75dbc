// FusionBound: errors that differ from view to view average away, a scale
// every view shares stays (and is named by the depth ratio), a shape error
// every view shares stays even with the scale divided out; the true points
// of a model's pixels follow each pixel's ray into a depth image of another
// resolution.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>
#include <vector>

#include "long3r/eval/fusion_bound.hpp"
#include "support/cv_test_support.hpp"
#include "support/test_support.hpp"

namespace long3r {
namespace {

// A wall at z = 2 m seen head-on from cameras stepping sideways along x.
struct Wall {
  PinholeIntrinsics K = PinholeIntrinsics::from_hfov(40, 30, 60.0);
  cv::Mat truth_C;
  Wall() {
    truth_C =
        test::pointmap_from_depth(K, Eigen::Isometry3d::Identity(), [](int, int) { return 2.0; });
  }
  static Eigen::Isometry3d pose(int k) {
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.translation().x() = 0.01 * k;
    return T;
  }
};

TEST(FusionBound, ErrorsThatDifferFromViewToViewAverageAway) {
  const Wall wall;
  FusionBound bound(0.02);
  std::mt19937 rng(1);
  std::normal_distribution<float> noise(0.0f, 0.05f);
  for (int k = 0; k < 40; ++k) {
    cv::Mat pred = wall.truth_C.clone();
    for (auto it = pred.begin<cv::Vec3f>(); it != pred.end<cv::Vec3f>(); ++it) {
      (*it)[2] += noise(rng);
    }
    bound.add(pred, wall.truth_C, Wall::pose(k));
  }
  const FusionBoundSummary s = bound.summary();
  EXPECT_EQ(s.frames, 40u);
  EXPECT_EQ(s.pairs, 40u * 40u * 30u);
  EXPECT_GT(s.mean_views, 5.0);
  EXPECT_NEAR(s.single_view_m.mean, 0.05 * std::sqrt(2.0 / M_PI), 0.004);
  EXPECT_LT(s.averaged_m.mean, 0.35 * s.single_view_m.mean);
  EXPECT_NEAR(s.depth_ratio_median, 1.0, 0.005);
  EXPECT_EQ(bound.averaged_points().size(), s.voxels);
}

TEST(FusionBound, ErrorsEveryViewSharesStay) {
  const Wall wall;
  FusionBound scaled(0.02), tilted(0.02);
  for (int k = 0; k < 20; ++k) {
    // 10 % too deep: the scale every view shares.
    scaled.add(wall.truth_C * 1.1, wall.truth_C, Wall::pose(k));
    // The wall tilted by its column (depth 2 +- 0.2 m), then scaled back so
    // that its median depth is right: shape, not scale.
    cv::Mat tilt = wall.truth_C.clone();
    for (int v = 0; v < tilt.rows; ++v) {
      for (int u = 0; u < tilt.cols; ++u) {
        tilt.at<cv::Vec3f>(v, u) *= 1.0f + 0.1f * (2.0f * u / (tilt.cols - 1) - 1.0f);
      }
    }
    tilted.add(tilt, wall.truth_C, Wall::pose(k));
  }
  const FusionBoundSummary s = scaled.summary();
  EXPECT_NEAR(s.depth_ratio_median, 1.1, 1e-5);
  EXPECT_NEAR(s.depth_ratio_mad, 0.0, 1e-6);
  EXPECT_NEAR(s.averaged_m.mean, s.single_view_m.mean, 1e-3);
  EXPECT_GT(s.averaged_m.mean, 0.19);
  EXPECT_LT(s.averaged_rescaled_m.mean, 1e-4);  // the scale was all of it

  const FusionBoundSummary t = tilted.summary();
  EXPECT_NEAR(t.depth_ratio_median, 1.0, 0.01);
  EXPECT_GT(t.averaged_rescaled_m.mean, 0.5 * t.single_view_m.mean);
}

TEST(FusionBound, SkipsPixelsWithoutAPointOrATruth) {
  const Wall wall;
  FusionBound bound(0.05);
  cv::Mat pred = wall.truth_C.clone(), truth = wall.truth_C.clone();
  const float nan = std::numeric_limits<float>::quiet_NaN();
  pred.at<cv::Vec3f>(0, 0) = cv::Vec3f(nan, 0, 1);
  pred.at<cv::Vec3f>(0, 1) = cv::Vec3f(0, 0, -1);
  truth.at<cv::Vec3f>(0, 2) = cv::Vec3f(nan, nan, nan);
  bound.add(pred, truth, Eigen::Isometry3d::Identity());
  EXPECT_EQ(bound.summary().pairs, 40u * 30u - 3u);
  // A frame with no pair at all counts as seen, with no depth ratio.
  bound.add(cv::Mat(30, 40, CV_32FC3, cv::Scalar::all(nan)), truth, Eigen::Isometry3d::Identity());
  EXPECT_EQ(bound.summary().frames, 2u);
  EXPECT_EQ(bound.summary().depth_ratio.size(), 1u);
  test::expect_throw_naming([&] { bound.add(pred, truth(cv::Rect(0, 0, 10, 10)), {}); },
                            "of one size");
  test::expect_throw_naming([] { FusionBound{0.0}; }, "voxel_size_m");
}

TEST(FusionBound, TruePointsFollowEachPixelsRayIntoTheDepthImage) {
  // Depth at 80 x 60 of a scene whose depth grows with the column; the
  // model's pixels at 40 x 30 (half the resolution, the same field of view).
  const PinholeIntrinsics depth_K = PinholeIntrinsics::from_hfov(80, 60, 60.0);
  PinholeIntrinsics model_K = PinholeIntrinsics::from_hfov(40, 30, 60.0);
  cv::Mat depth(60, 80, CV_32FC1);
  for (int v = 0; v < 60; ++v) {
    for (int u = 0; u < 80; ++u) depth.at<float>(v, u) = 1.0f + 0.01f * u;
  }
  depth.at<float>(29, 40) = 0.0f;  // no depth there
  const cv::Mat pts = true_points_at_pixels(depth, depth_K, model_K, {40, 30});
  ASSERT_EQ(pts.type(), CV_32FC3);
  ASSERT_EQ(pts.size(), cv::Size(40, 30));
  for (int v = 0; v < 30; ++v) {
    for (int u = 0; u < 40; ++u) {
      const cv::Vec3f p = pts.at<cv::Vec3f>(v, u);
      const double x = (u - model_K.cx) / model_K.fx, y = (v - model_K.cy) / model_K.fy;
      const long us = std::lround(depth_K.fx * x + depth_K.cx);
      const long vs = std::lround(depth_K.fy * y + depth_K.cy);
      const float z = depth.at<float>(static_cast<int>(vs), static_cast<int>(us));
      if (z == 0.0f) {
        EXPECT_TRUE(std::isnan(p[2])) << u << "," << v;
        continue;
      }
      EXPECT_FLOAT_EQ(p[2], z);
      EXPECT_NEAR(p[0], x * z, 1e-5);
      EXPECT_NEAR(p[1], y * z, 1e-5);
    }
  }
  test::expect_throw_naming(
      [&] {
        true_points_at_pixels(cv::Mat(60, 80, CV_16UC1), depth_K, model_K, {40, 30});
      },
      "CV_32FC1");
  test::expect_throw_naming(
      [&] {
        true_points_at_pixels(depth, PinholeIntrinsics{}, model_K, {40, 30});
      },
      "focal length");
}

}  // namespace
}  // namespace long3r

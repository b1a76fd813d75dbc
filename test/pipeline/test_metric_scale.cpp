// Metric scale: the robust estimate, the odometry and depth samplers, the
// policy of when a scale is applied, and the pipeline's rescaling (map,
// trajectory) and pose covariance.
#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <cmath>
#include <random>

#include "long3r/mapping/voxel_map.hpp"
#include "long3r/pipeline/metric_scale.hpp"
#include "long3r/pipeline/pose.hpp"

namespace long3r {
namespace {

MetricScaleConfig estimating(ScaleSource source = ScaleSource::kOdometry) {
  MetricScaleConfig c;
  c.source = source;
  c.min_samples = 5;
  c.max_rel_stddev = 0.03;
  return c;
}

TEST(MetricScale, RobustEstimateRejectsOutliers) {
  std::mt19937 rng(3);
  std::normal_distribution<double> noise(0.0, 0.02);
  std::vector<double> samples;
  for (int i = 0; i < 40; ++i) samples.push_back(2.5 * (1.0 + noise(rng)));
  samples.push_back(40.0);  // a stalled segment: the model hardly moved
  samples.push_back(0.01);
  samples.push_back(std::nan(""));
  const ScaleEstimate e = robust_scale(samples, estimating());
  EXPECT_NEAR(e.scale, 2.5, 0.02);
  EXPECT_EQ(e.rejected, 3);
  EXPECT_EQ(e.samples, 40);
  // The median's standard error for 2 % noise over 40 samples: ~0.5 %.
  EXPECT_NEAR(e.stddev / e.scale, 1.2533 * 0.02 / std::sqrt(40.0), 0.003);
  EXPECT_TRUE(e.converged);
  EXPECT_FALSE(robust_scale({2.5, 2.6}, estimating()).converged);          // too few
  EXPECT_FALSE(robust_scale({1, 2, 3, 4, 5, 6}, estimating()).converged);  // too spread
}

TEST(MetricScale, OdometrySamplerTakesSegmentsOfEnoughBaseline) {
  MetricScaleConfig c = estimating();
  c.min_baseline_m = 0.1;
  OdometryScaleSampler s(c);
  // The model reconstructs at a third of metric size.
  std::vector<double> got;
  for (int k = 0; k <= 20; ++k) {
    const Eigen::Vector3d odom(0.03 * k, 0.0, 0.01 * k);
    if (auto r = s.add(odom, odom / 3.0)) got.push_back(*r);
  }
  ASSERT_EQ(got.size(), 5u);  // 0.0316 m per frame: a sample every 4 frames
  for (double r : got) EXPECT_NEAR(r, 3.0, 1e-9);
  s.reset();
  EXPECT_FALSE(s.add(Eigen::Vector3d(5, 5, 5), Eigen::Vector3d::Zero()).has_value());
  // A model that did not move gives no sample (not an infinite ratio).
  EXPECT_FALSE(s.add(Eigen::Vector3d(6, 5, 5), Eigen::Vector3d::Zero()).has_value());
}

TEST(MetricScale, DepthSampleIsTheMedianRatioOverValidPixels) {
  cv::Mat pred(10, 20, CV_32FC1, cv::Scalar(0.5f)), meas(10, 20, CV_32FC1, cv::Scalar(1.5f));
  cv::Mat conf(10, 20, CV_32FC1, cv::Scalar(2.0f));
  meas(cv::Rect(0, 0, 20, 2)).setTo(0.0f);   // no depth
  meas(cv::Rect(0, 2, 5, 1)).setTo(100.0f);  // a few wrong readings
  pred(cv::Rect(0, 3, 20, 1)).setTo(std::nanf(""));
  conf(cv::Rect(0, 9, 20, 1)).setTo(1.0f);  // not confident
  const auto r = depth_scale_sample(pred, meas, conf, 1.5f);
  ASSERT_TRUE(r.has_value());
  EXPECT_DOUBLE_EQ(*r, 3.0);
  EXPECT_FALSE(depth_scale_sample(pred, meas, conf, 1.5f, 1000).has_value());
  EXPECT_THROW(depth_scale_sample(pred, meas(cv::Rect(0, 0, 10, 10)), conf, 1.0f),
               std::invalid_argument);
}

TEST(MetricScale, PolicyAppliesOnConvergenceThenFreezes) {
  ScalePolicy p(estimating());
  EXPECT_FALSE(p.metric());
  EXPECT_DOUBLE_EQ(p.applied(), 1.0);
  for (int i = 0; i < 4; ++i) {
    p.add_sample(2.0 + 0.001 * i);
    EXPECT_FALSE(p.scale_to_apply().has_value());
  }
  p.add_sample(2.0);
  const auto s = p.scale_to_apply();
  ASSERT_TRUE(s.has_value());
  EXPECT_NEAR(*s, 2.0, 0.002);
  EXPECT_TRUE(p.metric());
  for (int i = 0; i < 50; ++i) p.add_sample(2.5);
  EXPECT_FALSE(p.scale_to_apply().has_value());  // frozen
  p.reset();
  EXPECT_FALSE(p.metric());
}

TEST(MetricScale, PolicyUpdatesOnlyOnASignificantChangeWithoutFreeze) {
  MetricScaleConfig c = estimating();
  c.freeze = false;
  c.update_rel_change = 0.02;
  ScalePolicy p(c);
  for (int i = 0; i < 10; ++i) p.add_sample(2.0);
  ASSERT_TRUE(p.scale_to_apply().has_value());
  p.add_sample(2.01);
  EXPECT_FALSE(p.scale_to_apply().has_value());  // 0.5 %: below the change threshold
  for (int i = 0; i < 30; ++i) p.add_sample(2.2);
  const auto s = p.scale_to_apply();
  ASSERT_TRUE(s.has_value());
  EXPECT_NEAR(*s, 2.2, 1e-9);
}

TEST(MetricScale, FixedAndNoneNeverChange) {
  MetricScaleConfig c = estimating(ScaleSource::kFixed);
  c.fixed_scale = 0.7;
  ScalePolicy fixed(c);
  EXPECT_TRUE(fixed.metric());
  EXPECT_DOUBLE_EQ(fixed.applied(), 0.7);
  for (int i = 0; i < 10; ++i) fixed.add_sample(2.0);
  EXPECT_FALSE(fixed.scale_to_apply().has_value());
  ScalePolicy none(estimating(ScaleSource::kNone));
  EXPECT_FALSE(none.metric());
}

TEST(MetricScale, ConfigIsValidated) {
  MetricScaleConfig c;
  c.validate({"scale", ""});
  c.fixed_scale = 0.0;
  EXPECT_THROW(c.validate({"scale", ""}), ConfigError);
  c = MetricScaleConfig();
  c.min_baseline_m = -1;
  EXPECT_THROW(c.validate({"scale", ""}), ConfigError);
}

TEST(VoxelMap, RescaleMovesAndMergesVoxels) {
  VoxelMapConfig config;
  config.voxel_size_m = 0.1;
  config.conf_threshold = 1.0f;
  VoxelMap map(config);
  map.integrate({{0.01f, 0.01f, 0.01f}, {0.06f, 0.01f, 0.01f}, {1.01f, 1.01f, 1.01f}},
                {Rgb8{10, 10, 10}, Rgb8{30, 30, 30}, Rgb8{2, 2, 2}}, 0);
  map.integrate({{0.06f, 0.02f, 0.01f}}, {Rgb8{30, 30, 30}}, 1);
  ASSERT_EQ(map.size(), 2u);  // [0, 0.1)^3 holds three points, [1, 1.1)^3 one
  const std::uint64_t revision = map.revision();
  map.rescale(10.0);
  EXPECT_GT(map.revision(), revision);
  std::vector<VoxelInfo> v = map.voxels();
  ASSERT_EQ(v.size(), 2u);
  for (const VoxelInfo& i : v) {
    EXPECT_EQ(i.index, map.voxel_index(i.position));
    if (i.hits == 1) {
      EXPECT_NEAR(i.position.x(), 10.1, 1e-5);
    }
  }
  map.rescale(0.005);  // both now fall into [0, 0.1)^3 and merge, weighted by hits
  v = map.voxels();
  ASSERT_EQ(v.size(), 1u);
  EXPECT_EQ(v[0].index, Eigen::Vector3i(0, 0, 0));
  EXPECT_EQ(v[0].hits, 4u);
  EXPECT_NEAR(v[0].position.x(), (0.01 + 0.06 + 0.06 + 1.01) * 0.05 / 4, 1e-6);
  EXPECT_EQ(v[0].color[0], 18);  // (10 + 30 + 30 + 2) / 4
  EXPECT_EQ(v[0].last_seen, 1);
  EXPECT_THROW(map.rescale(0.0), std::invalid_argument);
}

// The covariance of an exact pose from many points: small, symmetric,
// positive definite, and larger when the points are noisier or fewer tokens
// hold them.
TEST(PoseCovariance, ReflectsTheEvidence) {
  PinholeIntrinsics k = PinholeIntrinsics::from_hfov(224, 224, 70.0);
  Eigen::Isometry3d T_W_C = Eigen::Isometry3d::Identity();
  T_W_C.translation() = Eigen::Vector3d(0.2, -0.1, 0.3);
  T_W_C.linear() = Eigen::AngleAxisd(0.2, Eigen::Vector3d(0.3, 1.0, 0.1).normalized()).matrix();
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> depth(1.0, 4.0);
  std::normal_distribution<double> px(0.0, 0.5);
  std::vector<Eigen::Vector3d> pts;
  std::vector<Eigen::Vector2d> pix, pix_noisy;
  for (int v = 0; v < 224; v += 4) {
    for (int u = 0; u < 224; u += 4) {
      const double z = depth(rng);
      const Eigen::Vector3d X_C((u - k.cx) / k.fx * z, (v - k.cy) / k.fy * z, z);
      pts.push_back(T_W_C * X_C);
      pix.emplace_back(u, v);
      pix_noisy.emplace_back(u + px(rng), v + px(rng));
    }
  }
  const auto exact = pose_covariance(pts, pix, k, T_W_C, 2.0);
  const auto noisy = pose_covariance(pts, pix_noisy, k, T_W_C, 2.0);
  ASSERT_TRUE(exact && noisy);
  using Matrix6d = Eigen::Matrix<double, 6, 6>;
  for (const Matrix6d* c : {&*exact, &*noisy}) {
    EXPECT_TRUE(c->isApprox(c->transpose()));
    const Eigen::SelfAdjointEigenSolver<Matrix6d> eig(*c);
    EXPECT_GT(eig.eigenvalues().minCoeff(), 0.0);
  }
  // min_sigma_px (0.5) floors a perfect fit; the noisy one has ~0.7 px RMSE.
  EXPECT_GT(noisy->trace(), exact->trace());
  // The same evidence from one 16x16 token only: far less information.
  std::vector<Eigen::Vector3d> few_pts(pts.begin(), pts.begin() + 4);
  std::vector<Eigen::Vector2d> few_pix(pix.begin(), pix.begin() + 4);
  EXPECT_FALSE(pose_covariance(few_pts, few_pix, k, T_W_C, 2.0).has_value());  // < 6 points
  // Positions beyond the threshold are not evidence.
  std::vector<Eigen::Vector2d> far = pix;
  for (auto& p : far) p.x() += 5.0;
  EXPECT_FALSE(pose_covariance(pts, far, k, T_W_C, 2.0).has_value());
}

}  // namespace
}  // namespace long3r

#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "long3r/eval/eval.hpp"
#include "support/test_support.hpp"

using namespace long3r;

namespace {

// Grid on the plane z = 0, spacing `step`, n x n points.
std::vector<Eigen::Vector3f> plane_grid(int n, float step) {
  std::vector<Eigen::Vector3f> p;
  for (int i = 0; i < n; ++i) {
    for (int j = 0; j < n; ++j) p.emplace_back(i * step, j * step, 0.0f);
  }
  return p;
}

// Points sampled on the surface of an axis-aligned box (5 faces, open top),
// a shape with a well-defined Sim(3).
std::vector<Eigen::Vector3f> box_surface(int per_face, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  const Eigen::Vector3f size(2.0f, 1.5f, 1.0f);
  std::vector<Eigen::Vector3f> p;
  for (int f = 0; f < 5; ++f) {
    for (int i = 0; i < per_face; ++i) {
      const float a = u(rng), b = u(rng);
      Eigen::Vector3f q;
      switch (f) {
        case 0:
          q = {a * size.x(), b * size.y(), 0.0f};
          break;
        case 1:
          q = {0.0f, a * size.y(), b * size.z()};
          break;
        case 2:
          q = {size.x(), a * size.y(), b * size.z()};
          break;
        case 3:
          q = {a * size.x(), 0.0f, b * size.z()};
          break;
        default:
          q = {a * size.x(), size.y(), b * size.z()};
          break;
      }
      p.push_back(q);
    }
  }
  return p;
}

std::vector<Eigen::Vector3f> transform_points(const Sim3& s,
                                              const std::vector<Eigen::Vector3f>& p) {
  std::vector<Eigen::Vector3f> out;
  for (const auto& x : p) out.push_back((s * x.cast<double>()).cast<float>());
  return out;
}

}  // namespace

TEST(EvalReconstruction, IdenticalCloudsAreZeroAndFullyConsistent) {
  const auto gt = box_surface(800, 1);
  const auto m = reconstruction_metrics(gt, gt);
  EXPECT_EQ(m.accuracy_mean, 0.0);
  EXPECT_EQ(m.accuracy_median, 0.0);
  EXPECT_EQ(m.completion_mean, 0.0);
  EXPECT_EQ(m.completion_median, 0.0);
  EXPECT_NEAR(m.nc_mean, 1.0, 1e-6);
  EXPECT_NEAR(m.nc_accuracy_median, 1.0, 1e-6);
  EXPECT_EQ(m.completion_ratio, 1.0);
  EXPECT_EQ(m.num_pred, gt.size());
  EXPECT_EQ(m.accuracy_errors.size(), gt.size());
}

TEST(EvalReconstruction, KnownOffsetGivesThatDistance) {
  const auto gt = plane_grid(60, 0.01f);
  for (float d : {0.03f, 0.07f}) {
    std::vector<Eigen::Vector3f> pred = gt;
    for (auto& p : pred) p.z() += d;
    const auto m = reconstruction_metrics(pred, gt);
    EXPECT_NEAR(m.accuracy_mean, d, 1e-6);
    EXPECT_NEAR(m.accuracy_median, d, 1e-6);
    EXPECT_NEAR(m.completion_mean, d, 1e-6);
    EXPECT_NEAR(m.completion_median, d, 1e-6);
    EXPECT_NEAR(m.nc_mean, 1.0, 1e-5);
    EXPECT_EQ(m.completion_ratio, d < 0.05f ? 1.0 : 0.0);
  }
}

TEST(EvalReconstruction, PartialPredictionLowersCompletionOnly) {
  // Prediction = left half of the GT grid: accuracy 0, completion = mean
  // distance of the right half to the cut line.
  const int n = 40;
  const float step = 0.01f;
  const auto gt = plane_grid(n, step);
  std::vector<Eigen::Vector3f> pred;
  for (const auto& p : gt) {
    if (p.x() < 19.5f * step) pred.push_back(p);
  }
  ReconstructionMetricsOptions o;
  o.normals = false;
  const auto m = reconstruction_metrics(pred, gt, o);
  EXPECT_EQ(m.accuracy_mean, 0.0);
  // Columns 20..39 are 1..20 steps from column 19; columns 0..19 are 0.
  double expected = 0.0;
  for (int c = 20; c < n; ++c) expected += (c - 19) * step;
  expected /= n;
  EXPECT_NEAR(m.completion_mean, expected, 1e-6);
  EXPECT_NEAR(m.completion_median, 0.5 * (0.0 + 1 * step), 1e-6);  // numpy median of an even count
}

TEST(EvalReconstruction, NormalConsistencyOfTiltedPlaneIsCosine) {
  const auto gt = plane_grid(50, 0.02f);
  const double theta = 20.0 * M_PI / 180.0;
  Sim3 tilt;
  tilt.rotation = Eigen::AngleAxisd(theta, Eigen::Vector3d::UnitX()).toRotationMatrix();
  const auto pred = transform_points(tilt, gt);
  const auto m = reconstruction_metrics(pred, gt);
  EXPECT_NEAR(m.nc_accuracy_mean, std::cos(theta), 1e-5);
  EXPECT_NEAR(m.nc_completion_mean, std::cos(theta), 1e-5);
  EXPECT_NEAR(m.nc_median, std::cos(theta), 1e-5);
}

TEST(EvalReconstruction, NormalsOfPlaneAreItsNormal) {
  const auto pts = plane_grid(20, 0.05f);
  const auto n = estimate_normals(pts, 30);
  for (const auto& v : n) EXPECT_NEAR(std::abs(v.z()), 1.0f, 1e-5f);
}

TEST(EvalReconstruction, KnownSim3RecoveredFromCorrespondences) {
  const auto gt = box_surface(500, 2);
  Sim3 truth;
  truth.scale = 0.37;
  truth.rotation =
      Eigen::AngleAxisd(1.1, Eigen::Vector3d(0.2, -1.0, 0.4).normalized()).toRotationMatrix();
  truth.translation = Eigen::Vector3d(-0.8, 2.0, 0.3);
  const auto pred = transform_points(truth.inverse(), gt);  // prediction in another frame and scale
  ReconstructionEvalOptions o;
  o.initial = align_correspondences(pred, gt, true);
  o.icp = false;
  const auto r = evaluate_reconstruction(pred, gt, o);
  // Float points: the recovered transform is exact to float precision.
  EXPECT_NEAR(r.alignment.scale, truth.scale, 1e-6);
  EXPECT_LT((r.alignment.rotation - truth.rotation).norm(), 1e-5);
  EXPECT_LT((r.alignment.translation - truth.translation).norm(), 1e-5);
  EXPECT_LT(r.metrics.accuracy_mean, 1e-5);
  EXPECT_LT(r.metrics.completion_mean, 1e-5);
}

TEST(EvalReconstruction, IcpRefinesSmallRigidMisalignment) {
  const auto gt = box_surface(1500, 3);
  Sim3 offset;
  offset.rotation =
      Eigen::AngleAxisd(2.0 * M_PI / 180.0, Eigen::Vector3d(0.3, 0.5, 1.0).normalized())
          .toRotationMatrix();
  offset.translation = Eigen::Vector3d(0.02, -0.015, 0.01);
  const auto pred = transform_points(offset, gt);
  ReconstructionEvalOptions with_icp;
  const auto r = evaluate_reconstruction(pred, gt, with_icp);
  ASSERT_TRUE(r.icp.has_value());
  EXPECT_EQ(r.alignment.scale, 1.0);  // rigid by default
  EXPECT_LT(r.metrics.accuracy_mean, 1e-4);
  const Sim3 back = r.alignment * offset;  // should be the identity
  EXPECT_LT((back.rotation - Eigen::Matrix3d::Identity()).norm(), 1e-4);
  EXPECT_LT(back.translation.norm(), 1e-4);

  ReconstructionEvalOptions no_icp;
  no_icp.icp = false;
  EXPECT_GT(evaluate_reconstruction(pred, gt, no_icp).metrics.accuracy_mean, 5e-3);
}

TEST(EvalReconstruction, RejectsEmptyClouds) {
  const std::vector<Eigen::Vector3f> empty, one = {Eigen::Vector3f::Zero()};
  EXPECT_THROW(reconstruction_metrics(empty, one), std::invalid_argument);
  EXPECT_THROW(reconstruction_metrics(one, empty), std::invalid_argument);
}

TEST(EvalReconstruction, VoxelDownsampleAveragesPerVoxel) {
  const std::vector<Eigen::Vector3f> pts = {
      {0.01f, 0.01f, 0.01f}, {0.03f, 0.05f, 0.07f}, {1.01f, 0.0f, 0.0f}, {-0.02f, 0.0f, 0.0f}};
  const auto v = voxel_downsample(pts, 0.1);
  ASSERT_EQ(v.size(), 3u);
  EXPECT_TRUE(v[0].isApprox(Eigen::Vector3f(0.02f, 0.03f, 0.04f)));
  EXPECT_TRUE(v[1].isApprox(Eigen::Vector3f(1.01f, 0.0f, 0.0f)));
  EXPECT_TRUE(v[2].isApprox(Eigen::Vector3f(-0.02f, 0.0f, 0.0f)));
}

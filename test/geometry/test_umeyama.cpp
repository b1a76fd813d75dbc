#include <gtest/gtest.h>

#include <random>

#include "long3r/geometry/umeyama.hpp"

using long3r::Sim3;
using long3r::umeyama_alignment;

namespace {

Eigen::Matrix3d random_rotation(std::mt19937_64& rng) {
  std::normal_distribution<double> n(0.0, 1.0);
  Eigen::Quaterniond q(n(rng), n(rng), n(rng), n(rng));
  return q.normalized().toRotationMatrix();
}

Eigen::Matrix3Xd random_points(std::mt19937_64& rng, int n) {
  std::uniform_real_distribution<double> u(-3.0, 3.0);
  Eigen::Matrix3Xd p(3, n);
  for (int i = 0; i < n; ++i) p.col(i) = Eigen::Vector3d(u(rng), u(rng), u(rng));
  return p;
}

Eigen::Matrix3Xd apply(const Sim3& s, const Eigen::Matrix3Xd& p) {
  Eigen::Matrix3Xd out(3, p.cols());
  for (int i = 0; i < p.cols(); ++i) out.col(i) = s * Eigen::Vector3d(p.col(i));
  return out;
}

}  // namespace

TEST(EvalUmeyama, RecoversKnownSim3) {
  std::mt19937_64 rng(42);
  for (int trial = 0; trial < 5; ++trial) {
    Sim3 truth;
    truth.rotation = random_rotation(rng);
    truth.scale = 0.3 + 0.5 * trial;
    truth.translation = Eigen::Vector3d(1.0 * trial, -2.0, 0.5);
    const Eigen::Matrix3Xd src = random_points(rng, 50);
    const Sim3 est = umeyama_alignment(src, apply(truth, src), true);
    EXPECT_NEAR(est.scale, truth.scale, 1e-6);
    EXPECT_LT((est.rotation - truth.rotation).norm(), 1e-6);
    EXPECT_LT((est.translation - truth.translation).norm(), 1e-6);
    EXPECT_NEAR(est.rotation.determinant(), 1.0, 1e-9);
  }
}

TEST(EvalUmeyama, RigidModeKeepsUnitScale) {
  std::mt19937_64 rng(7);
  Sim3 truth;
  truth.rotation = random_rotation(rng);
  truth.translation = Eigen::Vector3d(0.1, 0.2, 0.3);
  const Eigen::Matrix3Xd src = random_points(rng, 20);
  const Sim3 est = umeyama_alignment(src, apply(truth, src), false);
  EXPECT_EQ(est.scale, 1.0);
  EXPECT_LT((est.rotation - truth.rotation).norm(), 1e-9);
  EXPECT_LT((est.translation - truth.translation).norm(), 1e-9);
}

TEST(EvalUmeyama, PlanarPointsNeedNoReflection) {
  // Coplanar points: the SVD alone could return a reflection; det(R) must be +1.
  Eigen::Matrix3Xd src(3, 4);
  src << 0, 1, 1, 0, 0, 0, 1, 1, 0, 0, 0, 0;
  Sim3 truth;
  truth.rotation = Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  truth.scale = 2.0;
  const Sim3 est = umeyama_alignment(src, apply(truth, src), true);
  EXPECT_NEAR(est.rotation.determinant(), 1.0, 1e-12);
  EXPECT_LT((est.rotation - truth.rotation).norm(), 1e-9);
  EXPECT_NEAR(est.scale, 2.0, 1e-9);
}

TEST(EvalUmeyama, LeastSquaresWithNoise) {
  // With zero-mean noise the fit stays close and beats the truth's residual.
  std::mt19937_64 rng(3);
  Sim3 truth;
  truth.rotation = random_rotation(rng);
  truth.scale = 1.7;
  const Eigen::Matrix3Xd src = random_points(rng, 400);
  Eigen::Matrix3Xd dst = apply(truth, src);
  std::normal_distribution<double> n(0.0, 0.01);
  for (int i = 0; i < dst.cols(); ++i) dst.col(i) += Eigen::Vector3d(n(rng), n(rng), n(rng));
  const Sim3 est = umeyama_alignment(src, dst, true);
  EXPECT_NEAR(est.scale, 1.7, 5e-3);
  EXPECT_LE((apply(est, src) - dst).squaredNorm(), (apply(truth, src) - dst).squaredNorm());
}

TEST(EvalUmeyama, RejectsBadInput) {
  Eigen::Matrix3Xd a(3, 2), b(3, 3);
  a.setRandom();
  b.setRandom();
  EXPECT_THROW(umeyama_alignment(a, a), std::invalid_argument);  // too few
  EXPECT_THROW(umeyama_alignment(b, a), std::invalid_argument);  // size mismatch
  Eigen::Matrix3Xd line(3, 5);
  for (int i = 0; i < 5; ++i) line.col(i) = Eigen::Vector3d(i, 2.0 * i, 0.0);
  EXPECT_THROW(umeyama_alignment(line, line), std::invalid_argument);  // collinear
}

TEST(EvalUmeyama, Sim3AlgebraIsConsistent) {
  std::mt19937_64 rng(9);
  Sim3 a, b;
  a.rotation = random_rotation(rng);
  a.scale = 2.0;
  a.translation = Eigen::Vector3d(1, 2, 3);
  b.rotation = random_rotation(rng);
  b.scale = 0.5;
  b.translation = Eigen::Vector3d(-1, 0, 4);
  const Eigen::Vector3d p(0.3, -0.2, 0.9);
  EXPECT_LT(((a * b) * p - a * (b * p)).norm(), 1e-12);
  EXPECT_LT((a.inverse() * (a * p) - p).norm(), 1e-12);
  EXPECT_LT(((a.matrix() * p.homogeneous()).head<3>() - a * p).norm(), 1e-12);
  // apply_to_pose moves the camera centre like a point and keeps a rotation.
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  pose.linear() = random_rotation(rng);
  pose.translation() = Eigen::Vector3d(0.5, 0.6, 0.7);
  const Eigen::Isometry3d moved = a.apply_to_pose(pose);
  EXPECT_LT((moved.translation() - a * pose.translation()).norm(), 1e-12);
  EXPECT_LT((moved.linear() - a.rotation * pose.linear()).norm(), 1e-12);
}

#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "long3r/eval/eval.hpp"

using namespace long3r;

namespace {

Eigen::Isometry3d pose(const Eigen::Vector3d& t,
                       const Eigen::Matrix3d& r = Eigen::Matrix3d::Identity()) {
  Eigen::Isometry3d p = Eigen::Isometry3d::Identity();
  p.linear() = r;
  p.translation() = t;
  return p;
}

PoseTrajectory make(const std::vector<double>& stamps,
                    const std::vector<Eigen::Isometry3d>& poses) {
  PoseTrajectory t;
  t.stamps = stamps;
  t.poses = poses;
  return t;
}

// A curvy 3D trajectory with rotations.
PoseTrajectory wiggly(int n) {
  PoseTrajectory t;
  for (int i = 0; i < n; ++i) {
    const double a = 0.1 * i;
    t.stamps.push_back(i / 30.0);
    t.poses.push_back(
        pose(Eigen::Vector3d(std::cos(a), std::sin(1.3 * a), 0.2 * a),
             Eigen::AngleAxisd(a, Eigen::Vector3d(0.1, 0.2, 1.0).normalized()).toRotationMatrix()));
  }
  return t;
}

}  // namespace

TEST(EvalTrajectory, StatisticsFollowNumpy) {
  const auto s = error_statistics({4.0, 1.0, 3.0, 2.0});
  EXPECT_DOUBLE_EQ(s.mean, 2.5);
  EXPECT_DOUBLE_EQ(s.median, 2.5);
  EXPECT_DOUBLE_EQ(s.rmse, std::sqrt(30.0 / 4.0));
  EXPECT_DOUBLE_EQ(s.sse, 30.0);
  EXPECT_DOUBLE_EQ(s.std, std::sqrt(1.25));
  EXPECT_DOUBLE_EQ(s.min, 1.0);
  EXPECT_DOUBLE_EQ(s.max, 4.0);
  EXPECT_DOUBLE_EQ(error_statistics({5.0, 1.0, 3.0}).median, 3.0);
}

TEST(EvalTrajectory, IdenticalTrajectoriesHaveZeroError) {
  const auto t = wiggly(50);
  const auto m = evaluate_trajectory(t, t);
  EXPECT_EQ(m.matched, 50u);
  EXPECT_LT(m.ate.rmse, 1e-9);
  EXPECT_LT(m.rpe_translation.max, 1e-9);
  EXPECT_LT(m.rpe_rotation_deg.max, 1e-6);
  EXPECT_NEAR(m.alignment.scale, 1.0, 1e-9);
}

TEST(EvalTrajectory, Sim3DistortedEstimateAlignsExactly) {
  const auto ref = wiggly(60);
  Sim3 s;
  s.scale = 0.25;
  s.rotation = Eigen::AngleAxisd(2.0, Eigen::Vector3d(1, -1, 0.5).normalized()).toRotationMatrix();
  s.translation = Eigen::Vector3d(3, -4, 5);
  PoseTrajectory est = ref;
  for (auto& p : est.poses) p = s.apply_to_pose(p);
  const auto m = evaluate_trajectory(ref, est);
  EXPECT_NEAR(m.alignment.scale, 4.0, 1e-9);
  EXPECT_LT(m.ate.rmse, 1e-9);
  EXPECT_LT(m.rpe_translation.max, 1e-9);
  EXPECT_LT(m.rpe_rotation_deg.max, 1e-6);
  // Without scale correction the error cannot vanish.
  TrajectoryEvalOptions se3;
  se3.correct_scale = false;
  EXPECT_GT(evaluate_trajectory(ref, est, se3).ate.rmse, 0.1);
}

TEST(EvalTrajectory, ConstantOffsetWithoutAlignment) {
  const auto ref = wiggly(20);
  PoseTrajectory est = ref;
  const Eigen::Vector3d c(0.03, -0.04, 0.0);  // |c| = 0.05
  for (auto& p : est.poses) p.translation() += c;
  TrajectoryEvalOptions o;
  o.align = false;
  const auto m = evaluate_trajectory(ref, est, o);
  EXPECT_NEAR(m.ate.rmse, 0.05, 1e-12);
  EXPECT_NEAR(m.ate.min, 0.05, 1e-12);
  EXPECT_LT(m.rpe_translation.max, 1e-12);  // a world shift leaves relative motion unchanged
}

TEST(EvalTrajectory, HandComputedAteAndRpe) {
  // Square of side 2 in z = 0; the estimate moves each corner by +-e along z
  // in a pattern that is uncorrelated with x and y, so Umeyama keeps R = I,
  // t = 0 and (with scale) s = 2 / (2 + e^2).
  const double e = 0.1;
  const std::vector<Eigen::Vector3d> corners = {{1, 1, 0}, {1, -1, 0}, {-1, -1, 0}, {-1, 1, 0}};
  const double dz[4] = {e, -e, e, -e};
  std::vector<Eigen::Isometry3d> ref, est;
  for (int i = 0; i < 4; ++i) {
    ref.push_back(pose(corners[i]));
    est.push_back(pose(corners[i] + Eigen::Vector3d(0, 0, dz[i])));
  }
  const std::vector<double> stamps = {0.0, 0.1, 0.2, 0.3};
  TrajectoryEvalOptions se3;
  se3.correct_scale = false;
  const auto a = evaluate_trajectory(make(stamps, ref), make(stamps, est), se3);
  EXPECT_NEAR(a.ate.rmse, e, 1e-12);
  EXPECT_LT((a.alignment.rotation - Eigen::Matrix3d::Identity()).norm(), 1e-12);
  // RPE: consecutive corners differ by 2e in z, rotations equal.
  for (double v : a.rpe.translation) EXPECT_NEAR(v, 2 * e, 1e-12);
  EXPECT_EQ(a.rpe.translation.size(), 3u);

  const auto b = evaluate_trajectory(make(stamps, ref), make(stamps, est));  // Sim(3)
  const double c = 2.0 / (2.0 + e * e);
  EXPECT_NEAR(b.alignment.scale, c, 1e-12);
  EXPECT_NEAR(b.ate.rmse, std::sqrt(2 * (c - 1) * (c - 1) + c * c * e * e), 1e-12);
  // Aligned estimate = c * est: E_t = (c - 1) * d_ref + (0, 0, +-2ce), |d_ref| = 2.
  for (double v : b.rpe.translation) {
    EXPECT_NEAR(v, 2.0 * std::sqrt((c - 1) * (c - 1) + c * c * e * e), 1e-12);
  }
}

TEST(EvalTrajectory, RpeRotationStepAndItsTranslationEffect) {
  // Straight line along x with unit steps; the estimate turns by alpha about z
  // between frames k and k+1 and keeps the reference positions.
  const int n = 8, k = 3;
  const double alpha = 10.0 * M_PI / 180.0;
  std::vector<Eigen::Isometry3d> ref, est;
  for (int i = 0; i < n; ++i) {
    ref.push_back(pose(Eigen::Vector3d(i, 0, 0)));
    const Eigen::Matrix3d r =
        i > k ? Eigen::AngleAxisd(alpha, Eigen::Vector3d::UnitZ()).toRotationMatrix()
              : Eigen::Matrix3d::Identity();
    est.push_back(pose(Eigen::Vector3d(i, 0, 0), r));
  }
  const auto r = rpe_errors(ref, est, 1, false);
  ASSERT_EQ(r.pairs.size(), static_cast<size_t>(n - 1));
  for (size_t p = 0; p < r.pairs.size(); ++p) {
    const int i = r.pairs[p].first;
    EXPECT_NEAR(r.rotation_deg[p], i == k ? 10.0 : 0.0, 1e-9) << "pair " << i;
    // After the turn the estimate's body-frame step is rotated: |R^T d - d| = 2 sin(alpha/2).
    EXPECT_NEAR(r.translation[p], i > k ? 2.0 * std::sin(alpha / 2) : 0.0, 1e-12) << "pair " << i;
  }
  // Pair selection as evo: consecutive (0,2),(2,4),(4,6) vs all (i, i+2).
  EXPECT_EQ(rpe_errors(ref, est, 2, false).pairs.size(), 3u);
  EXPECT_EQ(rpe_errors(ref, est, 2, true).pairs.size(), static_cast<size_t>(n - 2));
  EXPECT_THROW(rpe_errors(ref, est, 0, false), std::invalid_argument);
  EXPECT_THROW(rpe_errors(ref, est, n, false), std::invalid_argument);
}

TEST(EvalTrajectory, AssociationMatchesEvo) {
  // Reference at 100 Hz, estimate at ~30 Hz with jitter: each estimate stamp
  // takes the closest reference stamp within max_diff.
  PoseTrajectory ref, est;
  for (int i = 0; i < 100; ++i) {
    ref.stamps.push_back(i * 0.01);
    ref.poses.push_back(pose(Eigen::Vector3d(i, 0, 0)));
  }
  for (double t : {0.0004, 0.0333, 0.0671, 0.5, 2.0}) {
    est.stamps.push_back(t);
    est.poses.push_back(pose(Eigen::Vector3d::Zero()));
  }
  const auto m = associate_trajectories(ref, est, 0.01);
  ASSERT_EQ(m.size(), 4u);  // 2.0 is beyond the reference
  EXPECT_EQ(m[0], std::make_pair(0, 0));
  EXPECT_EQ(m[1], std::make_pair(3, 1));
  EXPECT_EQ(m[2], std::make_pair(7, 2));
  EXPECT_EQ(m[3], std::make_pair(50, 3));
  // Offset shifts the estimate's stamps.
  const auto shifted = associate_trajectories(ref, est, 0.001, 0.1);
  ASSERT_GE(shifted.size(), 2u);
  EXPECT_EQ(shifted[0], std::make_pair(10, 0));
  // Estimate longer than the reference: the reference drives.
  const auto swapped = associate_trajectories(est, ref, 0.01);
  ASSERT_EQ(swapped.size(), 4u);
  EXPECT_EQ(swapped[1], std::make_pair(1, 3));
  // Too few matches.
  PoseTrajectory far = est;
  for (double& t : far.stamps) t += 100.0;
  EXPECT_THROW(evaluate_trajectory(ref, far), std::invalid_argument);
}

TEST(EvalTrajectory, UpAxisFromCameraPoses) {
  // Cameras looking horizontally in a z-up world: image down is -z.
  std::vector<Eigen::Isometry3d> poses;
  for (int i = 0; i < 8; ++i) {
    const double yaw = 0.7 * i;
    Eigen::Matrix3d r;
    const Eigen::Vector3d f(std::cos(yaw), std::sin(yaw), 0.0), down(0, 0, -1);
    r.col(0) = down.cross(f);
    r.col(1) = down;
    r.col(2) = f;
    poses.push_back(pose(Eigen::Vector3d::Zero(), r));
  }
  EXPECT_LT((estimate_up_axis(poses) - Eigen::Vector3d::UnitZ()).norm(), 1e-12);
}

// Camera pose by PnP-RANSAC from synthetic pointmaps with a known pose.
#include <gtest/gtest.h>

#include <opencv2/core.hpp>

#include <cmath>
#include <fstream>
#include <limits>
#include <stdexcept>
#include <string>
#include <vector>

#include "long3r/pipeline/pose.hpp"
#include "support/cv_test_support.hpp"

namespace long3r {
namespace {

// A camera at model resolution (224 x 224).
PinholeIntrinsics model_camera() { return {200.0, 201.0, 111.5, 112.0, 224, 224}; }

Eigen::Isometry3d known_pose() {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = Eigen::AngleAxisd(0.35, Eigen::Vector3d(0.2, 1.0, -0.3).normalized()).matrix();
  T.translation() = Eigen::Vector3d(0.3, -0.2, 0.5);
  return T;
}

// World pointmap seen by camera T_W_C: a smooth bumpy surface 1.5-4 m away,
// so each pixel's world point projects exactly onto that pixel's centre.
void make_scene(const PinholeIntrinsics& k, const Eigen::Isometry3d& T_W_C, cv::Mat& pts_W,
                cv::Mat& conf) {
  pts_W = test::pointmap_from_depth(k, T_W_C, [](int u, int v) {
    return 2.5 + 0.8 * std::sin(0.05 * u) * std::cos(0.07 * v) + 0.004 * u;
  });
  conf = cv::Mat(k.height, k.width, CV_32FC1, cv::Scalar(5.0f));
}

// A gross outlier that the confidence does not flag: the point moved up to
// 1 m along each axis.
cv::Vec3f gross_offset(cv::RNG& rng) {
  return cv::Vec3f(rng.uniform(-1.f, 1.f), rng.uniform(-1.f, 1.f), rng.uniform(-1.f, 1.f));
}

double rotation_error(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b) {
  return Eigen::AngleAxisd(a.linear().transpose() * b.linear()).angle();
}

void expect_pose_near(const Eigen::Isometry3d& est, const Eigen::Isometry3d& truth, double tol) {
  EXPECT_LT(rotation_error(est, truth), tol);
  EXPECT_LT((est.translation() - truth.translation()).norm(), tol);
  EXPECT_LT((est.matrix() - truth.matrix()).cwiseAbs().maxCoeff(), tol);
}

TEST(Pose, PnpRecoversAKnownPose) {
  const PinholeIntrinsics k = model_camera();
  const Eigen::Isometry3d T = known_pose();
  cv::Mat pts, conf;
  make_scene(k, T, pts, conf);
  const PoseResult r = estimate_pose_pnp(pts, conf, k);
  ASSERT_TRUE(r.ok()) << r.message;
  EXPECT_EQ(r.status, PnpStatus::kOk);
  EXPECT_TRUE(r.message.empty());
  expect_pose_near(r.T_W_C, T, 1e-4);
  EXPECT_EQ(r.correspondences, 4000);  // default max_correspondences
  EXPECT_EQ(r.inliers, 4000);
  EXPECT_LT(r.inlier_rmse_px, 1e-3);
}

TEST(Pose, FrameZeroIsTheIdentity) {
  const PinholeIntrinsics k = model_camera();
  cv::Mat pts, conf;
  make_scene(k, Eigen::Isometry3d::Identity(), pts, conf);
  const PoseResult r = estimate_pose_pnp(pts, conf, k);
  ASSERT_TRUE(r.ok()) << r.message;
  expect_pose_near(r.T_W_C, Eigen::Isometry3d::Identity(), 1e-4);
}

TEST(Pose, OutliersAndLowConfidenceAreRejected) {
  const PinholeIntrinsics k = model_camera();
  const Eigen::Isometry3d T = known_pose();
  cv::Mat pts, conf;
  make_scene(k, T, pts, conf);
  cv::RNG rng(21);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (int v = 0; v < pts.rows; ++v) {
    for (int u = 0; u < pts.cols; ++u) {
      const double x = rng.uniform(0.0, 1.0);
      cv::Vec3f& p = pts.at<cv::Vec3f>(v, u);
      if (x < 0.3) {
        p += gross_offset(rng);
      } else if (x < 0.5) {  // outliers with low confidence
        p += cv::Vec3f(5.f, 5.f, 5.f);
        conf.at<float>(v, u) = 1.2f;
      } else if (x < 0.55) {
        p[1] = nan;
      }
    }
  }
  PnpConfig config;
  config.iterations = 500;
  const PoseResult r = estimate_pose_pnp(pts, conf, k, config);
  ASSERT_TRUE(r.ok()) << r.message;
  expect_pose_near(r.T_W_C, T, 1e-4);
  // 0.75 of the pixels are usable (confident and finite); 0.3 / 0.75 of those are outliers.
  EXPECT_GT(r.inliers, 0.5 * r.correspondences);
  EXPECT_LT(r.inliers, 0.7 * r.correspondences);
}

// Both RANSACs find the pose among gross outliers and agree on the inliers.
TEST(Pose, UsacAndClassicRansacAgree) {
  const PinholeIntrinsics k = model_camera();
  const Eigen::Isometry3d T = known_pose();
  cv::Mat pts, conf;
  make_scene(k, T, pts, conf);
  cv::RNG rng(5);
  for (int v = 0; v < pts.rows; ++v) {
    for (int u = 0; u < pts.cols; ++u) {
      if (rng.uniform(0.0, 1.0) < 0.6) pts.at<cv::Vec3f>(v, u) += gross_offset(rng);
    }
  }
  PnpConfig config;
  config.iterations = 1000;
  config.ransac = PnpRansac::kUsac;
  const PoseResult usac = estimate_pose_pnp(pts, conf, k, config);
  config.ransac = PnpRansac::kClassic;
  const PoseResult classic = estimate_pose_pnp(pts, conf, k, config);
  ASSERT_TRUE(usac.ok()) << usac.message;
  ASSERT_TRUE(classic.ok()) << classic.message;
  expect_pose_near(usac.T_W_C, T, 1e-4);
  expect_pose_near(classic.T_W_C, T, 1e-4);
  EXPECT_NEAR(usac.inliers, classic.inliers, 2);  // counted under each refined pose
  EXPECT_GT(usac.inliers, 0.35 * usac.correspondences);
  EXPECT_LT(usac.inliers, 0.45 * usac.correspondences);
  // Deterministic.
  config.ransac = PnpRansac::kUsac;
  const PoseResult again = estimate_pose_pnp(pts, conf, k, config);
  EXPECT_TRUE(again.T_W_C.matrix() == usac.T_W_C.matrix());
}

// A pointmap from a trained 64 x 64 model (test/data/pnp/README.md) on
// which OpenCV 4.6's classic solvePnPRansac, asked for SOLVEPNP_ITERATIVE,
// finds a consensus of about 1600 points and then returns the pose of its
// final solve on that set from scratch, which diverged (13 inliers, the
// camera 10^8 m away). The pose must keep its consensus.
TEST(Pose, ClassicRansacKeepsItsConsensusOnAModelPointmap) {
  std::ifstream in(std::string(LONG3R_SOURCE_DIR) + "/test/data/pnp/consensus_set_diverges.f32",
                   std::ios::binary);
  ASSERT_TRUE(in) << "test/data/pnp/consensus_set_diverges.f32 is missing";
  std::vector<float> rows(4000 * 5);
  in.read(reinterpret_cast<char*>(rows.data()), static_cast<std::streamsize>(rows.size() * 4));
  ASSERT_EQ(in.gcount(), static_cast<std::streamsize>(rows.size() * 4));
  const PinholeIntrinsics k{45.7, 45.7, 31.5, 31.5, 64, 64};
  cv::Mat pts(64, 64, CV_32FC3, cv::Scalar::all(0.0f));
  cv::Mat conf(64, 64, CV_32FC1, cv::Scalar(0.0f));  // the pixels left out of the file
  for (std::size_t i = 0; i < 4000; ++i) {
    const float* row = &rows[5 * i];
    const int u = static_cast<int>(row[3]), v = static_cast<int>(row[4]);
    pts.at<cv::Vec3f>(v, u) = cv::Vec3f(row[0], row[1], row[2]);
    conf.at<float>(v, u) = 5.0f;
  }
  PnpConfig config;
  ASSERT_EQ(config.ransac, PnpRansac::kClassic);
  const PoseResult classic = estimate_pose_pnp(pts, conf, k, config);
  ASSERT_EQ(classic.correspondences, 4000);
  ASSERT_TRUE(classic.ok()) << classic.message;
  EXPECT_GT(classic.inliers, 1500);
  config.ransac = PnpRansac::kUsac;
  const PoseResult usac = estimate_pose_pnp(pts, conf, k, config);
  ASSERT_TRUE(usac.ok()) << usac.message;
  // USAC's consensus is as large (1712 against 1694 under each refined pose),
  // and the two cameras lie 13 cm apart, 1.4 m from the world origin: a
  // 64 x 64 pointmap at 2 px does not pin the pose down further.
  EXPECT_GT(classic.inliers, 0.9 * usac.inliers);
  EXPECT_LT((classic.T_W_C.translation() - usac.T_W_C.translation()).norm(), 0.2);
}

TEST(Pose, SubsamplingRespectsTheCap) {
  const PinholeIntrinsics k = model_camera();
  cv::Mat pts, conf;
  make_scene(k, known_pose(), pts, conf);
  PnpConfig config;
  config.max_correspondences = 300;
  const PoseResult r = estimate_pose_pnp(pts, conf, k, config);
  ASSERT_TRUE(r.ok()) << r.message;
  EXPECT_EQ(r.correspondences, 300);
  expect_pose_near(r.T_W_C, known_pose(), 1e-4);
}

TEST(Pose, TrackerKeepsTheLastGoodPoseOnFailure) {
  const PinholeIntrinsics k = model_camera();
  const Eigen::Isometry3d T = known_pose();
  cv::Mat pts, conf;
  make_scene(k, T, pts, conf);
  PoseTracker tracker;
  EXPECT_FALSE(tracker.has_good_pose());
  ASSERT_TRUE(tracker.track(pts, conf, k).ok());
  EXPECT_TRUE(tracker.has_good_pose());

  // Nothing confident: too few points.
  const cv::Mat low(conf.size(), CV_32FC1, cv::Scalar(1.0f));
  PoseResult r = tracker.track(pts, low, k);
  EXPECT_EQ(r.status, PnpStatus::kTooFewPoints);
  EXPECT_STREQ(to_string(r.status), "too_few_points");
  EXPECT_FALSE(r.message.empty());
  expect_pose_near(r.T_W_C, T, 1e-4);
  EXPECT_EQ(tracker.consecutive_failures(), 1);

  // Points that fit no camera: no pose with enough inliers.
  cv::Mat noise(pts.size(), CV_32FC3);
  cv::RNG(22).fill(noise, cv::RNG::UNIFORM, -3.0, 3.0);
  r = tracker.track(noise, conf, k);
  EXPECT_FALSE(r.ok());
  EXPECT_TRUE(r.status == PnpStatus::kTooFewInliers || r.status == PnpStatus::kSolverFailed)
      << to_string(r.status) << ": " << r.message;
  expect_pose_near(r.T_W_C, T, 1e-4);
  EXPECT_EQ(tracker.consecutive_failures(), 2);

  // All non-finite.
  const cv::Mat nan_pts(pts.size(), CV_32FC3,
                        cv::Scalar::all(std::numeric_limits<float>::quiet_NaN()));
  EXPECT_EQ(tracker.track(nan_pts, conf, k).status, PnpStatus::kTooFewPoints);

  // A good frame again resets the failure count.
  ASSERT_TRUE(tracker.track(pts, conf, k).ok());
  EXPECT_EQ(tracker.consecutive_failures(), 0);
  tracker.reset();
  EXPECT_FALSE(tracker.has_good_pose());
  expect_pose_near(tracker.last_good_pose(), Eigen::Isometry3d::Identity(), 0.0 + 1e-15);
}

TEST(Pose, BadInputsThrow) {
  const PinholeIntrinsics k = model_camera();
  cv::Mat pts, conf;
  make_scene(k, known_pose(), pts, conf);
  PinholeIntrinsics other = k;
  other.width = 320;
  EXPECT_THROW(estimate_pose_pnp(pts, conf, other), std::invalid_argument);
  EXPECT_THROW(estimate_pose_pnp(pts, cv::Mat(), k), std::invalid_argument);
  EXPECT_THROW(estimate_pose_pnp(pts, conf, PinholeIntrinsics{}), std::invalid_argument);
}

TEST(Pose, PointsInCameraFrame) {
  const PinholeIntrinsics k = model_camera();
  const Eigen::Isometry3d T = known_pose();
  cv::Mat pts, conf;
  make_scene(k, T, pts, conf);
  pts.at<cv::Vec3f>(3, 4)[2] = std::numeric_limits<float>::infinity();
  const cv::Mat pc = points_in_camera(pts, T);
  ASSERT_EQ(pc.type(), CV_32FC3);
  for (int v = 0; v < k.height; v += 13) {
    for (int u = 0; u < k.width; u += 11) {
      if (v == 3 && u == 4) continue;
      const cv::Vec3f p = pc.at<cv::Vec3f>(v, u);
      const Eigen::Vector2d px = k.project(Eigen::Vector3d(p[0], p[1], p[2]));
      EXPECT_NEAR(px.x(), u, 1e-4);
      EXPECT_NEAR(px.y(), v, 1e-4);
      const double d = 2.5 + 0.8 * std::sin(0.05 * u) * std::cos(0.07 * v) + 0.004 * u;
      EXPECT_NEAR(p[2], d, 1e-5);
    }
  }
  EXPECT_TRUE(std::isnan(pc.at<cv::Vec3f>(3, 4)[0]));
}

// A body turning at a constant rate while it drives forward: the finite
// difference gives its velocities in its own frame; the covariance is the
// two poses' summed, rotated into the body, over dt^2.
TEST(Pose, FiniteDifferenceTwist) {
  Eigen::Isometry3d a = Eigen::Isometry3d::Identity();
  a.linear() = Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  a.translation() = Eigen::Vector3d(1.0, 2.0, 0.5);
  Eigen::Isometry3d step = Eigen::Isometry3d::Identity();
  step.linear() = Eigen::AngleAxisd(0.05, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  step.translation() = Eigen::Vector3d(0.2, 0.0, 0.0);
  const Eigen::Isometry3d b = a * step;
  Eigen::Matrix<double, 6, 6> cov = Eigen::Matrix<double, 6, 6>::Zero();
  cov.diagonal() << 1e-4, 4e-4, 9e-4, 1e-6, 1e-6, 1e-6;
  const auto t = finite_difference_twist(a, cov, 10.0, b, cov, 10.5);
  ASSERT_TRUE(t.has_value());
  // 0.2 m along a's x over 0.5 s, seen from b (turned 0.05 rad further).
  EXPECT_TRUE(
      t->linear.isApprox(Eigen::Vector3d(0.4 * std::cos(0.05), -0.4 * std::sin(0.05), 0.0), 1e-12));
  EXPECT_TRUE(t->angular.isApprox(Eigen::Vector3d(0.0, 0.0, 0.1), 1e-12));
  // x and y of the position variance swap roles under the body's yaw.
  const Eigen::Matrix3d Rb = b.linear();
  const Eigen::Matrix3d expected =
      Rb.transpose() * (2.0 * cov.topLeftCorner<3, 3>()) * Rb / (0.5 * 0.5);
  const Eigen::Matrix3d position_cov = t->covariance.topLeftCorner(3, 3);
  EXPECT_TRUE(position_cov.isApprox(expected, 1e-12));
  EXPECT_TRUE(t->covariance.isApprox(t->covariance.transpose()));
  EXPECT_FALSE(finite_difference_twist(a, cov, 10.0, b, cov, 10.0).has_value());
  EXPECT_FALSE(finite_difference_twist(a, cov, 10.0, b, cov, 9.0).has_value());
}

}  // namespace
}  // namespace long3r

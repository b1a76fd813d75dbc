// Camera pose per frame from the model's pointmap by PnP-RANSAC.
//
// Frames: the model's pointmaps are in the frame of camera 0 of the stream,
// which is the world frame W here. Each pixel (u, v) whose confidence passes
// the threshold gives a 2D-3D correspondence (pixel centre (u, v), world
// point); RANSAC finds the inliers (the classic cv::solvePnPRansac by
// default: EPnP samples scored through cv::projectPoints, and EPnP again on
// the consensus set; or OpenCV's USAC: P3P samples, MSAC scoring, inner local
// optimisation, about 4x faster at the same iteration count, see
// docs/performance.md for what it changes), then Levenberg-Marquardt on the
// inliers refines the pose.
// The result is T_W_C, camera optical frame (x right, y down, z forward) to
// world.
#pragma once

#include <ATen/core/Tensor.h>
#include <Eigen/Geometry>
#include <opencv2/core/mat.hpp>

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "long3r/config/config_fields.hpp"
#include "long3r/mapping/state_geometry.hpp"  // pose_to_tensor, for sessions
#include "long3r/pipeline/intrinsics.hpp"

namespace long3r {

// The RANSAC that finds the inliers (see the top of this file).
enum class PnpRansac { kUsac, kClassic };
inline const std::array<std::pair<PnpRansac, const char*>, 2>& enum_names(PnpRansac) {
  static const std::array<std::pair<PnpRansac, const char*>, 2> names{
      {{PnpRansac::kUsac, "usac"}, {PnpRansac::kClassic, "classic"}}};
  return names;
}

struct PnpConfig {
  PnpRansac ransac = PnpRansac::kClassic;
  float conf_threshold = 3.0f;         // model confidence (>= 1); pixels below are ignored
  double reprojection_error_px = 2.0;  // RANSAC inlier threshold, model pixels
  int iterations = 100;                // RANSAC iterations
  double ransac_confidence = 0.999;
  int min_inliers = 50;            // fewer -> kTooFewInliers
  int max_correspondences = 4000;  // evenly spaced subsample of the confident pixels
  bool refine = true;              // LM refinement on the inliers

  // Throws ConfigError naming the field.
  void validate(const config::FieldCheck& check) const;
};

// conf_threshold comes from ReconstructionConfig::conf_threshold.
template <class S, class V>
config::FieldsOf<S, PnpConfig> visit_fields(S& s, V& v) {
  v("ransac", s.ransac);
  v("reprojection_error_px", s.reprojection_error_px);
  v("min_inliers", s.min_inliers);
  v("iterations", s.iterations);
  v("ransac_confidence", s.ransac_confidence);
  v("max_correspondences", s.max_correspondences);
  v("refine", s.refine);
}

enum class PnpStatus {
  kOk,
  kTooFewPoints,   // fewer usable correspondences than max(min_inliers, 6)
  kSolverFailed,   // solvePnPRansac found no pose (or threw)
  kTooFewInliers,  // a pose, but fewer than min_inliers inliers
  kNonFinite,      // the solver returned NaN/inf
  // Relocalising (pose_method keyframes): PnP posed the pointmap, but no
  // kept keyframe's image correspondences confirm where (KeyframeTracker);
  // also the frame that lost tracking, after which relocalising starts.
  kNotRelocalised,
};
const char* to_string(PnpStatus status);

struct PoseResult {
  PnpStatus status = PnpStatus::kSolverFailed;
  std::string message;  // empty when ok; otherwise why, with the numbers
  bool ok() const { return status == PnpStatus::kOk; }
  // The new pose when ok(); otherwise the last good pose (PoseTracker) or the
  // identity (estimate_pose_pnp).
  Eigen::Isometry3d T_W_C = Eigen::Isometry3d::Identity();
  int correspondences = 0;  // used (after filtering and subsampling)
  int inliers = 0;
  double inlier_rmse_px = 0.0;  // reprojection RMSE over the inliers after refinement
  // Covariance of T_W_C from the inliers (pose_covariance), when ok():
  // (camera position x, y, z in W; rotation about W's x, y, z axes).
  std::optional<Eigen::Matrix<double, 6, 6>> covariance;
};

// Covariance of a camera pose from the 2D-3D correspondences it explains,
// the Gauss-Newton estimate sigma^2 (J^T J)^-1 inflated for correlated errors:
//   J      the 2x6 Jacobian of each inlier's reprojection (pixel) with respect
//          to the pose, perturbed as c' = c + dp (position in W) and
//          R'_WC = Exp(dth) R_WC (rotation about W's axes), the order and axes
//          of a ROS pose covariance;
//   sigma  the inliers' reprojection RMSE, at least min_sigma_px (a perfect
//          fit is not a certain pose);
//   n / n_eff  the inliers' errors are not independent: the model predicts a
//          pointmap per 16x16-pixel token (patch_px), and the errors of one
//          token move together, so the information of n inliers is that of
//          the n_eff tokens they cover.
// Inliers: the correspondences whose reprojection error under T_W_C is within
// threshold_px. nullopt with fewer than 6 or a singular J^T J.
std::optional<Eigen::Matrix<double, 6, 6>> pose_covariance(
    const std::vector<Eigen::Vector3d>& points_W, const std::vector<Eigen::Vector2d>& pixels,
    const PinholeIntrinsics& intrinsics, const Eigen::Isometry3d& T_W_C, double threshold_px,
    double min_sigma_px = 0.5, int patch_px = 16);

// pose_covariance() over the confident, finite pixels of a pointmap (as PnP
// selects them), e.g. for frame 0, whose pose is the identity by definition.
std::optional<Eigen::Matrix<double, 6, 6>> pose_covariance(const cv::Mat& pts3d_W,
                                                           const cv::Mat& conf,
                                                           const PinholeIntrinsics& intrinsics,
                                                           const Eigen::Isometry3d& T_W_C,
                                                           const PnpConfig& config);

// One PnP solve. pts3d_W: CV_32FC3 [H, W] world points (camera-0 frame);
// conf: CV_32FC1 [H, W]; intrinsics at the same resolution (width/height, if
// set, must match: std::invalid_argument otherwise, as for wrong types).
// Pixels with non-finite points are skipped. Deterministic (fixed RNG seed).
PoseResult estimate_pose_pnp(const cv::Mat& pts3d_W, const cv::Mat& conf,
                             const PinholeIntrinsics& intrinsics, const PnpConfig& config = {});

// Keeps the last good pose across a stream: a failed frame reports the
// failure and returns the previous good T_W_C (the caller should not add such
// a frame to the map).
class PoseTracker {
 public:
  explicit PoseTracker(const PnpConfig& config = {}) : config_(config) {}

  PoseResult track(const cv::Mat& pts3d_W, const cv::Mat& conf,
                   const PinholeIntrinsics& intrinsics);

  // Identity until the first success.
  const Eigen::Isometry3d& last_good_pose() const { return last_good_; }
  // The world's scale changed by `factor` (Reconstruction::set_scale).
  void rescale(double factor) { last_good_.translation() *= factor; }
  bool has_good_pose() const { return has_good_; }
  int64_t consecutive_failures() const { return consecutive_failures_; }
  void reset();  // new stream
  const PnpConfig& config() const { return config_; }

  // What the tracker carries from frame to frame (sessions).
  struct State {
    Eigen::Isometry3d last_good = Eigen::Isometry3d::Identity();
    bool has_good = false;
    int64_t consecutive_failures = 0;
  };
  State state() const { return {last_good_, has_good_, consecutive_failures_}; }
  void restore(const State& s) {
    last_good_ = s.last_good;
    has_good_ = s.has_good;
    consecutive_failures_ = s.consecutive_failures;
  }

 private:
  PnpConfig config_;
  Eigen::Isometry3d last_good_ = Eigen::Isometry3d::Identity();
  bool has_good_ = false;
  int64_t consecutive_failures_ = 0;
};

// points (CV_32FC3) mapped through T: p' = T p, e.g. the world pointmap into
// the camera frame with T = T_W_C.inverse(). Non-finite points stay NaN.
cv::Mat transform_points(const cv::Mat& points, const Eigen::Isometry3d& T);

// The pointmap in the camera frame: T_C_W = T_W_C^-1 applied to pts3d_W.
inline cv::Mat points_in_camera(const cv::Mat& pts3d_W, const Eigen::Isometry3d& T_W_C) {
  return transform_points(pts3d_W, T_W_C.inverse());
}

// A body's velocity between two of its poses T_map_body (a, then b) by
// finite difference, in the body frame at b (REP-105: nav_msgs/Odometry's
// twist is in its child frame): linear = its displacement over dt, angular =
// the rotation vector of T_a^-1 T_b over dt (the same in both frames), with the
// covariance ([linear, angular]) from the two pose covariances ([t, r] in
// map, taken as independent) rotated into the body frame at b and divided by
// dt^2. nullopt unless t_b > t_a.
struct Twist {
  Eigen::Vector3d linear = Eigen::Vector3d::Zero();
  Eigen::Vector3d angular = Eigen::Vector3d::Zero();
  Eigen::Matrix<double, 6, 6> covariance = Eigen::Matrix<double, 6, 6>::Zero();
};
std::optional<Twist> finite_difference_twist(const Eigen::Isometry3d& T_map_a,
                                             const Eigen::Matrix<double, 6, 6>& cov_a, double t_a,
                                             const Eigen::Isometry3d& T_map_b,
                                             const Eigen::Matrix<double, 6, 6>& cov_b, double t_b);

}  // namespace long3r

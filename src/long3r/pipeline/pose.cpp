#include "long3r/pipeline/pose.hpp"

#include <ATen/ATen.h>

#include <opencv2/calib3d.hpp>
#include <opencv2/core/eigen.hpp>

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <unordered_set>
#include <vector>

namespace long3r {

void PnpConfig::validate(const config::FieldCheck& check) const {
  check.require(conf_threshold >= 0.0f && std::isfinite(conf_threshold), "conf_threshold",
                "must be >= 0");
  check.require(reprojection_error_px > 0.0 && std::isfinite(reprojection_error_px),
                "reprojection_error_px", "must be > 0");
  check.require(min_inliers >= 4, "min_inliers", "must be >= 4");
  check.require(iterations >= 1, "iterations", "must be >= 1");
  check.require(ransac_confidence > 0.0 && ransac_confidence < 1.0, "ransac_confidence",
                "must be in (0, 1)");
  check.require(max_correspondences >= min_inliers, "max_correspondences",
                "must be >= min_inliers");
}

namespace {

bool finite3(const cv::Vec3f& p) {
  return std::isfinite(p[0]) && std::isfinite(p[1]) && std::isfinite(p[2]);
}

PoseResult failure(PnpStatus status, std::string message, int correspondences, int inliers) {
  PoseResult r;
  r.status = status;
  r.message = std::move(message);
  r.correspondences = correspondences;
  r.inliers = inliers;
  return r;
}

}  // namespace

const char* to_string(PnpStatus status) {
  switch (status) {
    case PnpStatus::kOk:
      return "ok";
    case PnpStatus::kTooFewPoints:
      return "too_few_points";
    case PnpStatus::kSolverFailed:
      return "solver_failed";
    case PnpStatus::kTooFewInliers:
      return "too_few_inliers";
    case PnpStatus::kNonFinite:
      return "non_finite";
    case PnpStatus::kNotRelocalised:
      return "not_relocalised";
  }
  return "unknown";
}

PoseResult estimate_pose_pnp(const cv::Mat& pts3d_W, const cv::Mat& conf,
                             const PinholeIntrinsics& intrinsics, const PnpConfig& config) {
  if (pts3d_W.type() != CV_32FC3 || conf.type() != CV_32FC1 || conf.size() != pts3d_W.size()) {
    throw std::invalid_argument(
        "estimate_pose_pnp: expected CV_32FC3 points and CV_32FC1 conf of the same size");
  }
  if (!intrinsics.valid()) throw std::invalid_argument("estimate_pose_pnp: invalid intrinsics");
  if ((intrinsics.width != 0 || intrinsics.height != 0) &&
      (intrinsics.width != pts3d_W.cols || intrinsics.height != pts3d_W.rows)) {
    throw std::invalid_argument("estimate_pose_pnp: intrinsics are for " +
                                std::to_string(intrinsics.width) + "x" +
                                std::to_string(intrinsics.height) + ", the pointmap is " +
                                std::to_string(pts3d_W.cols) + "x" + std::to_string(pts3d_W.rows));
  }

  // Confident, finite pixels, in row-major order.
  std::vector<cv::Point3f> all_obj;
  std::vector<cv::Point2f> all_img;
  for (int v = 0; v < pts3d_W.rows; ++v) {
    const auto* p = pts3d_W.ptr<cv::Vec3f>(v);
    const float* c = conf.ptr<float>(v);
    for (int u = 0; u < pts3d_W.cols; ++u) {
      if (!(c[u] >= config.conf_threshold) || !finite3(p[u])) continue;
      all_obj.emplace_back(p[u][0], p[u][1], p[u][2]);
      all_img.emplace_back(static_cast<float>(u), static_cast<float>(v));
    }
  }
  // Evenly spaced subsample keeps the spatial spread and is deterministic.
  std::vector<cv::Point3f> obj;
  std::vector<cv::Point2f> img;
  const size_t max_n = static_cast<size_t>(std::max(config.max_correspondences, 0));
  if (max_n > 0 && all_obj.size() > max_n) {
    obj.reserve(max_n);
    img.reserve(max_n);
    for (size_t i = 0; i < max_n; ++i) {
      const size_t j = i * all_obj.size() / max_n;
      obj.push_back(all_obj[j]);
      img.push_back(all_img[j]);
    }
  } else {
    obj = std::move(all_obj);
    img = std::move(all_img);
  }
  const int n = static_cast<int>(obj.size());
  const int needed = std::max(config.min_inliers, 6);
  if (n < needed) {
    return failure(PnpStatus::kTooFewPoints,
                   std::to_string(n) + " confident correspondences (conf >= " +
                       std::to_string(config.conf_threshold) + "), need " + std::to_string(needed),
                   n, 0);
  }

  cv::Mat K;
  cv::eigen2cv(intrinsics.matrix(), K);
  const cv::Mat no_distortion;
  cv::Mat rvec, tvec;
  std::vector<int> ransac_inliers;
  bool found = false;
  try {
    if (config.ransac == PnpRansac::kUsac) {
      cv::UsacParams usac;
      usac.confidence = config.ransac_confidence;
      usac.maxIterations = config.iterations;
      usac.threshold = config.reprojection_error_px;
      usac.sampler = cv::SAMPLING_UNIFORM;
      usac.score = cv::SCORE_METHOD_MSAC;
      usac.loMethod = cv::LOCAL_OPTIM_INNER_LO;
      usac.loIterations = 10;
      usac.loSampleSize = 14;
      usac.randomGeneratorState = 0;  // deterministic
      // Serial: its parallel mode is not deterministic, and the model's
      // threads want the cores back right after.
      usac.isParallel = false;
      cv::Mat K_usac = K.clone();  // an in-out argument there
      found = cv::solvePnPRansac(obj, img, K_usac, no_distortion, rvec, tvec, ransac_inliers, usac);
    } else {
      // Its samples are EPnP whatever the flag; the flag picks the final solve
      // on the consensus set. SOLVEPNP_ITERATIVE starts that one from scratch
      // in OpenCV 4.6 (DLT or a homography, not the best sample's pose) and on
      // model pointmaps diverged on about a fifth of the frames of a long
      // stream, leaving a pose with few or none of its inliers; EPnP is closed-form,
      // and the refinement below follows either way.
      found = cv::solvePnPRansac(obj, img, K, no_distortion, rvec, tvec, false, config.iterations,
                                 static_cast<float>(config.reprojection_error_px),
                                 config.ransac_confidence, ransac_inliers, cv::SOLVEPNP_EPNP);
    }
  } catch (const cv::Exception& e) {
    return failure(PnpStatus::kSolverFailed, std::string("solvePnPRansac threw: ") + e.what(), n,
                   0);
  }
  if (!found || rvec.empty() || tvec.empty()) {
    return failure(PnpStatus::kSolverFailed,
                   "solvePnPRansac found no pose from " + std::to_string(n) + " correspondences", n,
                   0);
  }
  if (static_cast<int>(ransac_inliers.size()) < config.min_inliers) {
    return failure(PnpStatus::kTooFewInliers,
                   std::to_string(ransac_inliers.size()) + " RANSAC inliers of " +
                       std::to_string(n) + ", need " + std::to_string(config.min_inliers),
                   n, static_cast<int>(ransac_inliers.size()));
  }
  rvec.convertTo(rvec, CV_64F);
  tvec.convertTo(tvec, CV_64F);
  if (config.refine) {
    std::vector<cv::Point3f> obj_in;
    std::vector<cv::Point2f> img_in;
    obj_in.reserve(ransac_inliers.size());
    img_in.reserve(ransac_inliers.size());
    for (int i : ransac_inliers) {
      obj_in.push_back(obj[i]);
      img_in.push_back(img[i]);
    }
    try {
      cv::solvePnPRefineLM(
          obj_in, img_in, K, no_distortion, rvec, tvec,
          cv::TermCriteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 50, 1e-12));
    } catch (const cv::Exception& e) {
      return failure(PnpStatus::kSolverFailed, std::string("solvePnPRefineLM threw: ") + e.what(),
                     n, static_cast<int>(ransac_inliers.size()));
    }
  }
  const cv::Vec3d r(rvec), t(tvec);
  if (!std::isfinite(r[0]) || !std::isfinite(r[1]) || !std::isfinite(r[2]) ||
      !std::isfinite(t[0]) || !std::isfinite(t[1]) || !std::isfinite(t[2])) {
    return failure(PnpStatus::kNonFinite, "PnP returned a non-finite pose", n,
                   static_cast<int>(ransac_inliers.size()));
  }

  // Final inliers and their RMSE under the refined pose.
  std::vector<cv::Point2f> projected;
  cv::projectPoints(obj, rvec, tvec, K, no_distortion, projected);
  const double thr2 = config.reprojection_error_px * config.reprojection_error_px;
  int inliers = 0;
  double sse = 0.0;
  for (int i = 0; i < n; ++i) {
    const double dx = projected[i].x - img[i].x, dy = projected[i].y - img[i].y;
    const double e2 = dx * dx + dy * dy;
    if (e2 <= thr2) {
      ++inliers;
      sse += e2;
    }
  }
  if (inliers < config.min_inliers) {
    return failure(PnpStatus::kTooFewInliers,
                   std::to_string(inliers) + " inliers of " + std::to_string(n) +
                       " after refinement, need " + std::to_string(config.min_inliers),
                   n, inliers);
  }

  cv::Mat R_cv;
  cv::Rodrigues(rvec, R_cv);
  Eigen::Matrix3d R;
  cv::cv2eigen(R_cv, R);
  Eigen::Isometry3d T_C_W = Eigen::Isometry3d::Identity();
  T_C_W.linear() = R;
  T_C_W.translation() = Eigen::Vector3d(t[0], t[1], t[2]);

  PoseResult result;
  result.status = PnpStatus::kOk;
  result.T_W_C = T_C_W.inverse();
  result.correspondences = n;
  result.inliers = inliers;
  result.inlier_rmse_px = std::sqrt(sse / inliers);
  if (!result.T_W_C.matrix().allFinite()) {
    return failure(PnpStatus::kNonFinite, "PnP pose inverse is not finite", n, inliers);
  }
  std::vector<Eigen::Vector3d> points(obj.size());
  std::vector<Eigen::Vector2d> pixels(img.size());
  for (int i = 0; i < n; ++i) {
    points[i] = Eigen::Vector3d(obj[i].x, obj[i].y, obj[i].z);
    pixels[i] = Eigen::Vector2d(img[i].x, img[i].y);
  }
  result.covariance =
      pose_covariance(points, pixels, intrinsics, result.T_W_C, config.reprojection_error_px);
  return result;
}

std::optional<Eigen::Matrix<double, 6, 6>> pose_covariance(
    const std::vector<Eigen::Vector3d>& points_W, const std::vector<Eigen::Vector2d>& pixels,
    const PinholeIntrinsics& k, const Eigen::Isometry3d& T_W_C, double threshold_px,
    double min_sigma_px, int patch_px) {
  if (points_W.size() != pixels.size()) {
    throw std::invalid_argument("pose_covariance: points and pixels differ in number");
  }
  const Eigen::Matrix3d R_CW = T_W_C.linear().transpose();
  const Eigen::Vector3d c = T_W_C.translation();
  Eigen::Matrix<double, 6, 6> H = Eigen::Matrix<double, 6, 6>::Zero();
  double sse = 0.0;
  int n = 0;
  std::unordered_set<std::int64_t> tokens;
  const double thr2 = threshold_px * threshold_px;
  for (std::size_t i = 0; i < points_W.size(); ++i) {
    const Eigen::Vector3d d = points_W[i] - c;
    const Eigen::Vector3d X = R_CW * d;
    if (!(X.z() > 0.0)) continue;
    const double iz = 1.0 / X.z();
    const Eigen::Vector2d e(k.fx * X.x() * iz + k.cx - pixels[i].x(),
                            k.fy * X.y() * iz + k.cy - pixels[i].y());
    if (!(e.squaredNorm() <= thr2)) continue;
    Eigen::Matrix<double, 2, 3> A;
    A << k.fx * iz, 0.0, -k.fx * X.x() * iz * iz, 0.0, k.fy * iz, -k.fy * X.y() * iz * iz;
    // dX/dp = -R_CW; dX/dth = R_CW [d]x (see the header).
    Eigen::Matrix3d d_cross;
    d_cross << 0.0, -d.z(), d.y(), d.z(), 0.0, -d.x(), -d.y(), d.x(), 0.0;
    Eigen::Matrix<double, 2, 6> J;
    J.leftCols<3>() = -A * R_CW;
    J.rightCols<3>() = A * R_CW * d_cross;
    H += J.transpose() * J;
    sse += e.squaredNorm();
    ++n;
    tokens.insert(static_cast<std::int64_t>(std::floor(pixels[i].y() / patch_px)) * (1 << 20) +
                  static_cast<std::int64_t>(std::floor(pixels[i].x() / patch_px)));
  }
  if (n < 6) return std::nullopt;
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 6, 6>> eig(H);
  const Eigen::Matrix<double, 6, 1> lambda = eig.eigenvalues();
  if (!(lambda.minCoeff() > 1e-12 * lambda.maxCoeff())) return std::nullopt;
  const double sigma2 = std::max(sse / n, min_sigma_px * min_sigma_px);
  const double correlation = static_cast<double>(n) / static_cast<double>(tokens.size());
  const Eigen::Matrix<double, 6, 6> cov = sigma2 * correlation * eig.eigenvectors() *
                                          lambda.cwiseInverse().asDiagonal() *
                                          eig.eigenvectors().transpose();
  if (!cov.allFinite()) return std::nullopt;
  return 0.5 * (cov + cov.transpose());
}

std::optional<Eigen::Matrix<double, 6, 6>> pose_covariance(const cv::Mat& pts3d_W,
                                                           const cv::Mat& conf,
                                                           const PinholeIntrinsics& intrinsics,
                                                           const Eigen::Isometry3d& T_W_C,
                                                           const PnpConfig& config) {
  std::vector<Eigen::Vector3d> points;
  std::vector<Eigen::Vector2d> pixels;
  for (int v = 0; v < pts3d_W.rows; ++v) {
    const auto* p = pts3d_W.ptr<cv::Vec3f>(v);
    const float* c = conf.ptr<float>(v);
    for (int u = 0; u < pts3d_W.cols; ++u) {
      if (!(c[u] >= config.conf_threshold) || !finite3(p[u])) continue;
      points.emplace_back(p[u][0], p[u][1], p[u][2]);
      pixels.emplace_back(u, v);
    }
  }
  return pose_covariance(points, pixels, intrinsics, T_W_C, config.reprojection_error_px);
}

PoseResult PoseTracker::track(const cv::Mat& pts3d_W, const cv::Mat& conf,
                              const PinholeIntrinsics& intrinsics) {
  PoseResult r = estimate_pose_pnp(pts3d_W, conf, intrinsics, config_);
  if (r.ok()) {
    last_good_ = r.T_W_C;
    has_good_ = true;
    consecutive_failures_ = 0;
  } else {
    r.T_W_C = last_good_;
    ++consecutive_failures_;
  }
  return r;
}

void PoseTracker::reset() {
  last_good_ = Eigen::Isometry3d::Identity();
  has_good_ = false;
  consecutive_failures_ = 0;
}

cv::Mat transform_points(const cv::Mat& points, const Eigen::Isometry3d& T) {
  if (points.type() != CV_32FC3) throw std::invalid_argument("transform_points: expected CV_32FC3");
  cv::Mat out(points.size(), CV_32FC3);
  const Eigen::Matrix3d R = T.linear();
  const Eigen::Vector3d t = T.translation();
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (int v = 0; v < points.rows; ++v) {
    const auto* in = points.ptr<cv::Vec3f>(v);
    auto* o = out.ptr<cv::Vec3f>(v);
    for (int u = 0; u < points.cols; ++u) {
      if (!finite3(in[u])) {
        o[u] = cv::Vec3f(nan, nan, nan);
        continue;
      }
      const Eigen::Vector3d q = R * Eigen::Vector3d(in[u][0], in[u][1], in[u][2]) + t;
      o[u] = cv::Vec3f(static_cast<float>(q.x()), static_cast<float>(q.y()),
                       static_cast<float>(q.z()));
    }
  }
  return out;
}

std::optional<Twist> finite_difference_twist(const Eigen::Isometry3d& T_map_a,
                                             const Eigen::Matrix<double, 6, 6>& cov_a, double t_a,
                                             const Eigen::Isometry3d& T_map_b,
                                             const Eigen::Matrix<double, 6, 6>& cov_b, double t_b) {
  if (!(t_b > t_a)) return std::nullopt;
  const double dt = t_b - t_a;
  const Eigen::Isometry3d delta = T_map_a.inverse() * T_map_b;
  const Eigen::AngleAxisd aa(delta.rotation());
  Twist twist;
  twist.linear = delta.rotation().transpose() * delta.translation() / dt;  // in b
  twist.angular = aa.angle() * aa.axis() / dt;
  Eigen::Matrix<double, 6, 6> R = Eigen::Matrix<double, 6, 6>::Zero();
  R.topLeftCorner<3, 3>() = T_map_b.linear().transpose();
  R.bottomRightCorner<3, 3>() = T_map_b.linear().transpose();
  const Eigen::Matrix<double, 6, 6> c = R * (cov_a + cov_b) * R.transpose() / (dt * dt);
  twist.covariance = 0.5 * (c + c.transpose());
  return twist;
}

}  // namespace long3r

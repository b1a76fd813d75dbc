#include "long3r/tracking/baseline_scale.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

#include "long3r/geometry/angles.hpp"
#include "long3r/geometry/statistics.hpp"
#include "long3r/tracking/feature_matching.hpp"

namespace long3r {

BaselineScale::BaselineScale(const KeyframeTrackerConfig& features)
    : features_(features),
      orb_(make_orb(features.max_features, features.fast_threshold, features.pyramid_levels)) {}

BaselineScale::Reference BaselineScale::make_reference(const TrackerFrame& frame,
                                                       const std::vector<cv::KeyPoint>& keypoints,
                                                       const cv::Mat& descriptors,
                                                       const Eigen::Isometry3d& T_W_C) const {
  Reference r;
  r.T_W_R = T_W_C;
  r.descriptors = descriptors.clone();
  const Eigen::Matrix3d K_inv = frame.K.inverse();
  const Eigen::Matrix3d image_to_model = frame.model_to_image.inverse();
  for (const cv::KeyPoint& kp : keypoints) {
    r.pixels.push_back(kp.pt);
    r.bearings.push_back((K_inv * Eigen::Vector3d(kp.pt.x, kp.pt.y, 1.0)).normalized());
    // The model's depth under the feature.
    const std::optional<Eigen::Vector3d> p = point_at(frame, image_to_model, kp.pt);
    std::optional<double> z;
    if (p && p->z() > 0.0) z = p->z();
    r.depths.push_back(z);
  }
  return r;
}

BaselineScaleResult BaselineScale::add(const TrackerFrame& frame, const Eigen::Isometry3d& T_W_C) {
  if (frame.gray.empty() || frame.gray.type() != CV_8UC1) {
    throw std::invalid_argument("BaselineScale::add: the image must be CV_8UC1");
  }
  if (frame.points_C.empty() || frame.points_C.type() != CV_32FC3) {
    throw std::invalid_argument("BaselineScale::add: the pointmap must be CV_32FC3");
  }
  BaselineScaleResult out;
  std::vector<cv::KeyPoint> keypoints;
  cv::Mat descriptors;
  orb_->detectAndCompute(frame.gray, cv::noArray(), keypoints, descriptors);
  std::ostringstream why;
  while (!references_.empty()) {
    out = measure(references_.front(), frame, keypoints, descriptors, T_W_C);
    if (out.sample) {
      references_.pop_front();  // used up: the next sample pairs other frames
      break;
    }
    if (out.matches >= features_.min_matches) {
      why << out.triangulated << " of " << out.matches << " matches triangulated (at least "
          << kMinTriangulated << ", median parallax " << out.parallax_deg << " deg, at least "
          << kMinParallaxDeg << "): waiting for more baseline";
      break;
    }
    references_.pop_front();  // out of sight: try the next one
  }
  if (!out.sample && why.str().empty()) why << "no reference frame in sight: this frame is one now";
  out.message = why.str();
  references_.push_back(make_reference(frame, keypoints, descriptors, T_W_C));
  while (references_.size() > kMaxReferences) references_.pop_front();
  return out;
}

BaselineScaleResult BaselineScale::measure(const Reference& ref, const TrackerFrame& frame,
                                           const std::vector<cv::KeyPoint>& keypoints,
                                           const cv::Mat& descriptors,
                                           const Eigen::Isometry3d& T_W_C) const {
  BaselineScaleResult out;
  const std::vector<cv::DMatch> matches =
      ratio_matches(descriptors, ref.descriptors, features_.ratio_test);
  out.matches = static_cast<int>(matches.size());
  const Eigen::Matrix3d K_inv = frame.K.inverse();
  const double max_gap_rad = kMaxRayGapPx / frame.K(0, 0);
  const Eigen::Vector3d o_r = ref.T_W_R.translation(), o_c = T_W_C.translation();
  std::vector<double> parallax(matches.size());
  std::vector<Eigen::Vector3d> d_c(matches.size());
  for (std::size_t j = 0; j < matches.size(); ++j) {
    const cv::Point2f& px = keypoints[static_cast<std::size_t>(matches[j].queryIdx)].pt;
    d_c[j] = T_W_C.linear() * (K_inv * Eigen::Vector3d(px.x, px.y, 1.0)).normalized();
    const Eigen::Vector3d d_r =
        ref.T_W_R.linear() * ref.bearings[static_cast<std::size_t>(matches[j].trainIdx)];
    parallax[j] = std::acos(std::clamp(d_r.dot(d_c[j]), -1.0, 1.0)) * kRadToDeg;
  }
  out.parallax_deg = median(parallax);
  std::vector<double> ratios;
  for (std::size_t j = 0; j < matches.size() && out.parallax_deg >= kMinParallaxDeg; ++j) {
    const auto i = static_cast<std::size_t>(matches[j].trainIdx);
    if (parallax[j] < 0.25 * kMinParallaxDeg || !ref.depths[i]) continue;
    // Closest points o_r + s d_r and o_c + t d_c of the two rays.
    const Eigen::Vector3d d_r = ref.T_W_R.linear() * ref.bearings[i];
    const Eigen::Vector3d w = o_r - o_c;
    const double b = d_r.dot(d_c[j]), d = d_r.dot(w), e = d_c[j].dot(w);
    const double denom = 1.0 - b * b;
    if (denom < 1e-12) continue;
    const double s = (b * e - d) / denom, t = (e - b * d) / denom;
    if (s <= 0.0 || t <= 0.0) continue;  // behind a camera
    const double gap = ((o_r + s * d_r) - (o_c + t * d_c[j])).norm();
    if (gap > max_gap_rad * std::min(s, t)) continue;  // the rays miss each other
    const double z_r = s * ref.bearings[i].z();        // depth in R, metres
    ratios.push_back(z_r / *ref.depths[i]);
  }
  out.triangulated = static_cast<int>(ratios.size());
  if (out.triangulated >= kMinTriangulated) out.sample = median(ratios);
  return out;
}

}  // namespace long3r

#include "long3r/tracking/keyframe_tracker.hpp"

#include "long3r/geometry/angles.hpp"
#include "long3r/geometry/statistics.hpp"
#include "long3r/tracking/feature_matching.hpp"

#include <opencv2/calib3d.hpp>
#include <opencv2/core/eigen.hpp>
#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/video/tracking.hpp>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <iterator>
#include <limits>
#include <numeric>
#include <sstream>
#include <stdexcept>

namespace long3r {

namespace {

// Fewer lifted inliers than this: the length (or PnP) is not trusted.
constexpr int kMinLiftedInliers = 12;
// A keyframe's pointmap must lie in front of its camera: this share of its
// finite points at least.
constexpr double kMinShareInFront = 0.9;
constexpr int kRansacSeed = 7;
// A pose from which the inliers are seen more than this far (median) from
// where the keyframe saw them is not taken: ORB matches no view turned that
// far about the points, so such a pose is one the matches happen to fit
// (on a generated robot path PnP took one 156 degrees and 3 m off, its 46
// inliers seen 142 degrees apart).
constexpr double kMaxParallaxDeg = 60.0;
// Untracked frames in a row after which the last becomes the keyframe.
constexpr int kKeyframeAfterLostFrames = 2;
// Guided matching (KeyframeTrackerConfig::guided_matching): ORB-SLAM's
// bounds for matches by projection (a Hamming distance of at most 64 of 256
// bits, the best below 0.9 of the second best within the radius), and a
// prior's radius this many times the radius about a pose the matches found.
constexpr int kGuidedMaxDistance = 64;
constexpr double kGuidedRatio = 0.9;
constexpr double kPriorRadiusFactor = 3.0;
// The optical-flow bridge (KeyframeTrackerConfig::flow_bridge): Shi-Tomasi
// corners at least this share of the strongest one's response (so a dim or
// low-contrast wall still gives some) and this far apart, tracked by
// pyramidal Lucas-Kanade with this window and pyramid (levels above the
// image: about 170 px of motion), and kept where the flow back lands within
// this distance of where the corner was.
constexpr int kFlowCorners = 500;
constexpr double kFlowQuality = 0.001;
constexpr double kFlowMinDistancePx = 8.0;
constexpr int kFlowWindowPx = 21;
constexpr int kFlowLevels = 3;
constexpr double kFlowBackPx = 1.0;

// The value at half the total weight.
double weighted_median(std::vector<std::pair<double, double>> value_weight) {
  std::sort(value_weight.begin(), value_weight.end());
  double total = 0.0;
  for (const auto& [v, w] : value_weight) total += w;
  double acc = 0.0;
  for (const auto& [v, w] : value_weight) {
    acc += w;
    if (acc >= 0.5 * total) return v;
  }
  return value_weight.empty() ? 0.0 : value_weight.back().first;
}

// Share of the pointmap's finite points in front of the camera (z > 0).
double share_in_front(const cv::Mat& points_C) {
  std::size_t finite = 0, front = 0;
  for (int v = 0; v < points_C.rows; ++v) {
    const auto* row = points_C.ptr<cv::Vec3f>(v);
    for (int u = 0; u < points_C.cols; ++u) {
      if (!std::isfinite(row[u][2])) continue;
      ++finite;
      front += row[u][2] > 0.0f ? 1 : 0;
    }
  }
  return finite == 0 ? 0.0 : static_cast<double>(front) / static_cast<double>(finite);
}

Eigen::Isometry3d isometry(const cv::Mat& R, const cv::Mat& t) {
  Eigen::Matrix3d r;
  Eigen::Vector3d v;
  cv::cv2eigen(R, r);
  cv::cv2eigen(t, v);
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = r;
  T.translation() = v;
  return T;
}

}  // namespace

void KeyframeTrackerConfig::validate(const config::FieldCheck& check) const {
  check.require(max_features >= 50 && max_features <= 100000, "max_features",
                "must be in [50, 100000]");
  check.require(fast_threshold >= 1 && fast_threshold <= 255, "fast_threshold",
                "must be in [1, 255]");
  check.require(pyramid_levels >= 1 && pyramid_levels <= 16, "pyramid_levels",
                "must be in [1, 16]");
  check.require(ratio_test > 0.0 && ratio_test <= 1.0, "ratio_test", "must be in (0, 1]");
  check.require(min_matches >= 8, "min_matches",
                "must be >= 8 (the essential matrix needs 5, PnP 6)");
  check.require(guided_radius_px >= 1.0 && guided_radius_px <= 1000.0, "guided_radius_px",
                "must be in [1, 1000]");
  check.require(ransac_threshold_px > 0.0 && std::isfinite(ransac_threshold_px),
                "ransac_threshold_px", "must be > 0");
  check.require(pnp_reprojection_error_px > 0.0 && std::isfinite(pnp_reprojection_error_px),
                "pnp_reprojection_error_px", "must be > 0");
  check.require(min_parallax_deg >= 0.0 && min_parallax_deg < 90.0, "min_parallax_deg",
                "must be in [0, 90)");
  check.require(keyframe_parallax_deg > 0.0 && keyframe_parallax_deg < 90.0,
                "keyframe_parallax_deg", "must be in (0, 90)");
  check.require(keyframe_min_overlap >= 0.0 && keyframe_min_overlap <= 1.0, "keyframe_min_overlap",
                "must be in [0, 1]");
  check.require(keyframe_max_frames >= 1, "keyframe_max_frames", "must be >= 1");
  check.require(relocalisation_min_inliers >= min_matches, "relocalisation_min_inliers",
                "must be >= min_matches");
  check.require(relocalisation_min_inlier_share >= 0.0 && relocalisation_min_inlier_share <= 1.0,
                "relocalisation_min_inlier_share", "must be in [0, 1]");
  check.require(
      relocalisation_max_depth_error > 0.0 && std::isfinite(relocalisation_max_depth_error),
      "relocalisation_max_depth_error", "must be > 0");
  check.require(relocalisation_candidates >= 1 && relocalisation_candidates <= 100,
                "relocalisation_candidates", "must be in [1, 100]");
  check.require(kept_keyframe_baseline >= 0.0 && std::isfinite(kept_keyframe_baseline),
                "kept_keyframe_baseline", "must be >= 0");
  check.require(kept_keyframe_angle_deg >= 0.0 && kept_keyframe_angle_deg <= 180.0,
                "kept_keyframe_angle_deg", "must be in [0, 180]");
  check.require(max_kept_keyframes >= 1 && max_kept_keyframes <= 100000, "max_kept_keyframes",
                "must be in [1, 100000]");
}

const char* to_string(TrackStatus status) {
  switch (status) {
    case TrackStatus::kKeyframe:
      return "keyframe";
    case TrackStatus::kTracked:
      return "tracked";
    case TrackStatus::kTooFewFeatures:
      return "too few features";
    case TrackStatus::kTooFewMatches:
      return "too few matches";
    case TrackStatus::kNoDepth:
      return "no depth";
    case TrackStatus::kRelocalised:
      return "relocalised";
    case TrackStatus::kRefused:
      return "relocalisation refused";
    case TrackStatus::kLost:
      return "lost";
  }
  return "?";
}

KeyframeTracker::KeyframeTracker(const KeyframeTrackerConfig& config) : config_(config) {
  config_.validate({"tracker config", ""});
  orb_ = make_orb(config_.max_features, config_.fast_threshold, config_.pyramid_levels);
}

std::optional<Eigen::Vector3d> point_at(const TrackerFrame& f,
                                        const Eigen::Matrix3d& image_to_model,
                                        const cv::Point2f& px) {
  if (!f.depth.empty()) {
    const int x = static_cast<int>(std::lround(px.x)), y = static_cast<int>(std::lround(px.y));
    if (x < 0 || y < 0 || x >= f.depth.cols || y >= f.depth.rows) return std::nullopt;
    // The median of the valid depths around it: a corner often sits on a
    // depth edge, where one pixel may belong to either side or be a hole
    // (measured on generated 200-frame sets: docs/model_card.md, "A depth
    // camera for the tracker").
    std::array<float, 9> around{};
    std::size_t n = 0;
    for (int yy = std::max(0, y - 1); yy <= std::min(f.depth.rows - 1, y + 1); ++yy) {
      for (int xx = std::max(0, x - 1); xx <= std::min(f.depth.cols - 1, x + 1); ++xx) {
        const float q = f.depth.at<float>(yy, xx);
        if (std::isfinite(q) && q > 0.0f) around[n++] = q;
      }
    }
    if (n == 0) return std::nullopt;
    std::nth_element(around.begin(), around.begin() + n / 2, around.begin() + n);
    const float d = around[n / 2];
    const Eigen::Vector3d ray = f.K.inverse() * Eigen::Vector3d(px.x, px.y, 1.0);
    return ray * (static_cast<double>(d) / ray.z());
  }
  const Eigen::Vector3d m = image_to_model * Eigen::Vector3d(px.x, px.y, 1.0);
  const int u = static_cast<int>(std::lround(m.x() / m.z()));
  const int v = static_cast<int>(std::lround(m.y() / m.z()));
  if (u < 0 || v < 0 || u >= f.points_C.cols || v >= f.points_C.rows) return std::nullopt;
  const cv::Vec3f p = f.points_C.at<cv::Vec3f>(v, u);
  if (!std::isfinite(p[0]) || !std::isfinite(p[1]) || !std::isfinite(p[2])) return std::nullopt;
  return Eigen::Vector3d(p[0], p[1], p[2]);
}

double median_depth(const std::vector<std::optional<Eigen::Vector3d>>& points) {
  std::vector<double> z;
  for (const auto& p : points) {
    if (p) z.push_back(p->z());
  }
  const double m = median(std::move(z));
  return m > 0.0 && std::isfinite(m) ? m : 1.0;
}

void KeyframeTracker::reset() {
  keyframe_.reset();
  last_.reset();
  previous_.reset();
  lost_ = 0;
  last_scale_ = 1.0;
  keyframes_ = 0;
  kept_.clear();
  relocalising_ = false;
  next_candidate_ = 0;
}

void KeyframeTracker::lose() { relocalising_ = keyframe_.has_value() || !kept_.empty(); }

void KeyframeTracker::restore(std::vector<KeptKeyframe> kept) {
  for (std::size_t i = 0; i < kept.size(); ++i) {
    const KeptKeyframe& k = kept[i];
    const std::size_t n = k.pixels.size();
    if (k.bearings.size() != n || k.points.size() != n ||
        static_cast<std::size_t>(k.descriptors.rows) != n ||
        (n > 0 && (k.descriptors.type() != CV_8UC1 || k.descriptors.cols != 32))) {
      throw std::invalid_argument("KeyframeTracker::restore: kept keyframe " + std::to_string(i) +
                                  " has parts of different lengths or descriptors that are not "
                                  "ORB's (32 bytes each)");
    }
  }
  reset();
  kept_.assign(std::make_move_iterator(kept.begin()), std::make_move_iterator(kept.end()));
  while (kept_.size() > static_cast<std::size_t>(config_.max_kept_keyframes)) kept_.pop_front();
  relocalising_ = !kept_.empty();
}

void KeyframeTracker::rescale(double factor) {
  auto rescale_one = [factor](KeptKeyframe& k) {
    k.T_W_K.translation() *= factor;
    for (auto& p : k.points) {
      if (p) *p *= factor;
    }
    k.median_depth *= factor;
  };
  for (std::optional<Keyframe>* k : {&keyframe_, &last_}) {
    if (*k) rescale_one(**k);
  }
  for (KeptKeyframe& k : kept_) rescale_one(k);
  if (previous_) {
    previous_->T_W_C.translation() *= factor;
    previous_->scale *= factor;
  }
}

void KeyframeTracker::keep(const KeptKeyframe& k) {
  for (const KeptKeyframe& o : kept_) {
    const double baseline = (o.T_W_K.translation() - k.T_W_K.translation()).norm() / k.median_depth;
    const double angle =
        Eigen::AngleAxisd(o.T_W_K.linear().transpose() * k.T_W_K.linear()).angle() * kRadToDeg;
    if (baseline < config_.kept_keyframe_baseline && angle < config_.kept_keyframe_angle_deg) {
      return;
    }
  }
  kept_.push_back(k);
  while (kept_.size() > static_cast<std::size_t>(config_.max_kept_keyframes)) kept_.pop_front();
}

KeyframeTracker::Keyframe KeyframeTracker::make_keyframe(const TrackerFrame& frame,
                                                         const std::vector<cv::KeyPoint>& keypoints,
                                                         const cv::Mat& descriptors,
                                                         const Eigen::Isometry3d& T_W_C,
                                                         double scale) const {
  Keyframe k;
  k.T_W_K = T_W_C;
  k.descriptors = descriptors.clone();
  const Eigen::Matrix3d K_inv = frame.K.inverse();
  const Eigen::Matrix3d image_to_model = frame.model_to_image.inverse();
  k.pixels.reserve(keypoints.size());
  for (const cv::KeyPoint& kp : keypoints) {
    k.pixels.push_back(kp.pt);
    const Eigen::Vector3d ray = K_inv * Eigen::Vector3d(kp.pt.x, kp.pt.y, 1.0);  // z = 1
    k.bearings.push_back(ray.normalized());
    // The model's depth along the image's own ray: the full-resolution
    // feature keeps its position, the coarse pointmap gives the distance.
    const std::optional<Eigen::Vector3d> p = point_at(frame, image_to_model, kp.pt);
    if (p && p->z() > 0.0) {
      k.points.emplace_back(ray * (p->z() * scale));
    } else {
      k.points.emplace_back(std::nullopt);
    }
  }
  k.median_depth = median_depth(k.points);
  return k;
}

TrackResult KeyframeTracker::track(const TrackerFrame& frame,
                                   const Eigen::Isometry3d& T_W_C_prior) {
  if (frame.gray.empty() || frame.gray.type() != CV_8UC1) {
    throw std::invalid_argument("KeyframeTracker::track: the image must be CV_8UC1");
  }
  if (frame.points_C.empty() || frame.points_C.type() != CV_32FC3) {
    throw std::invalid_argument("KeyframeTracker::track: the pointmap must be CV_32FC3");
  }
  if (!frame.depth.empty() &&
      (frame.depth.type() != CV_32FC1 || frame.depth.size() != frame.gray.size())) {
    throw std::invalid_argument(
        "KeyframeTracker::track: the depth image must be CV_32FC1 of the image's size");
  }
  std::vector<cv::KeyPoint> keypoints;
  cv::Mat descriptors;
  const auto t0 = std::chrono::steady_clock::now();
  orb_->detectAndCompute(frame.gray, cv::noArray(), keypoints, descriptors);
  const std::chrono::duration<double, std::milli> features_time =
      std::chrono::steady_clock::now() - t0;
  TrackResult r = track_detected(frame, keypoints, descriptors, T_W_C_prior);
  // The bridge follows the flow from the frame just before only: across a
  // gap the motion is the gap's, too large for it (on real frames a second
  // apart it posed a frame 74 degrees off).
  if (!r.posed()) previous_.reset();
  r.features = static_cast<int>(keypoints.size());  // whichever path made r
  r.features_ms = features_time.count();
  return r;
}

TrackResult KeyframeTracker::track_detected(const TrackerFrame& frame,
                                            const std::vector<cv::KeyPoint>& keypoints,
                                            const cv::Mat& descriptors,
                                            const Eigen::Isometry3d& T_W_C_prior) {
  TrackResult r;
  r.scale = last_scale_;  // unless this frame measures its own
  r.features = static_cast<int>(keypoints.size());
  // previous_ is only kept while there is a keyframe (reset() and restore()
  // drop both).
  const bool bridge =
      config_.flow_bridge && config_.when_lost == WhenLost::kPrior && !relocalising_ && previous_;
  const bool too_few_features = r.features < config_.min_matches;
  if (too_few_features) {
    // Relocalising, nothing but the images may place a frame.
    r.status = relocalising_ ? TrackStatus::kRefused : TrackStatus::kTooFewFeatures;
    std::ostringstream why;
    why << r.features << " features in the image (at least " << config_.min_matches << " needed)";
    r.message = why.str();
    if (!bridge) return r;
  } else if (relocalising_) {
    r = relocalise(frame, keypoints, descriptors, T_W_C_prior);
    if (r.posed()) remember(frame, r);
    return r;
  } else if (!keyframe_) {
    if (share_in_front(frame.points_C) < kMinShareInFront) {
      r.status = TrackStatus::kNoDepth;
      r.message = "the pointmap lies behind the camera: not a keyframe";
      return r;
    }
    keyframe_ = make_keyframe(frame, keypoints, descriptors, T_W_C_prior, 1.0);
    keep(*keyframe_);
    ++keyframes_;
    last_scale_ = 1.0;
    r.status = TrackStatus::kKeyframe;
    r.T_W_C = T_W_C_prior;
    r.new_keyframe = true;
    remember(frame, r);
    return r;
  } else {
    r = match(frame, keypoints, descriptors, T_W_C_prior);
  }
  if (!r.posed() && bridge) {
    TrackResult f = by_flow(frame);
    if (f.posed()) return posed_by_flow(frame, keypoints, descriptors, std::move(f));
    r.message += "; " + f.message;
  }
  // Too few features to tell a lost view from a blank or dark image: the
  // keyframe waits for the next frame with features.
  if (too_few_features) return r;
  const bool in_front = share_in_front(frame.points_C) >= kMinShareInFront;
  if (!r.posed()) {
    if (r.status == TrackStatus::kTooFewMatches && config_.when_lost == WhenLost::kRelocalise) {
      // The view changed too much to say where it went (a cut to another
      // scene, or a fast move): only the images may place the next frames.
      relocalising_ = true;
      lost_ = 0;
      r.status = TrackStatus::kLost;
      r.message += "; relocalising against the kept keyframes";
      return r;
    }
    // Lost for a while (fast motion, a new scene): start again from here, at
    // the caller's pose for the frame, rather than wait for the old view.
    if (++lost_ >= kKeyframeAfterLostFrames && in_front) {
      keyframe_ = make_keyframe(frame, keypoints, descriptors, T_W_C_prior, last_scale_);
      last_.reset();
      keep(*keyframe_);
      ++keyframes_;
      lost_ = 0;
      r.new_keyframe = true;
    }
    return r;
  }
  lost_ = 0;
  last_.reset();
  Keyframe& kf = *keyframe_;
  last_scale_ = r.scale;

  // 5. A new keyframe?
  ++kf.frames_since;
  if (kf.reference_inliers == 0) kf.reference_inliers = r.inliers;
  const double overlap = static_cast<double>(r.inliers) / static_cast<double>(kf.reference_inliers);
  const bool due = kf.frames_since >= config_.keyframe_max_frames ||
                   r.parallax_deg >= config_.keyframe_parallax_deg ||
                   overlap < config_.keyframe_min_overlap;
  if (in_front && r.scale_measured) {
    Keyframe next = make_keyframe(frame, keypoints, descriptors, r.T_W_C, r.scale);
    if (due) {
      keyframe_ = std::move(next);
      keep(*keyframe_);
      ++keyframes_;
      r.new_keyframe = true;
    } else {
      last_ = std::move(next);
    }
  }
  remember(frame, r);
  return r;
}

TrackResult KeyframeTracker::match(const TrackerFrame& frame,
                                   const std::vector<cv::KeyPoint>& keypoints,
                                   const cv::Mat& descriptors,
                                   const Eigen::Isometry3d& T_W_C_prior) {
  TrackResult r = relative(*keyframe_, frame, keypoints, descriptors);
  if (!r.posed() && last_) {
    // The keyframe is out of sight: the last tracked frame may still see
    // this one; it becomes the keyframe then.
    TrackResult r_last = relative(*last_, frame, keypoints, descriptors);
    if (r_last.posed()) {
      keyframe_ = std::move(*last_);
      last_.reset();
      keep(*keyframe_);
      ++keyframes_;
      r = r_last;
    }
  }
  if (!r.posed() && config_.guided_matching) {
    // Neither places it by the ratio test's matches: the keyframe's points
    // where the caller's prior puts them may still find theirs.
    TrackResult r_prior = by_projection(*keyframe_, frame, keypoints, descriptors,
                                        T_W_C_prior.inverse() * keyframe_->T_W_K,
                                        config_.guided_radius_px * kPriorRadiusFactor, 0);
    if (r_prior.posed()) r = r_prior;
  }
  return r;
}

TrackResult KeyframeTracker::posed_by_flow(const TrackerFrame& frame,
                                           const std::vector<cv::KeyPoint>& keypoints,
                                           const cv::Mat& descriptors, TrackResult f) {
  // The keyframe does not see the frame: it becomes the keyframe where it
  // has the features (and the depth) for one, else the keyframe stays and
  // the next frame's bridge starts from this one.
  lost_ = 0;
  last_.reset();
  if (f.scale_measured) last_scale_ = f.scale;
  if (static_cast<int>(keypoints.size()) >= config_.min_matches && f.scale_measured &&
      share_in_front(frame.points_C) >= kMinShareInFront) {
    keyframe_ = make_keyframe(frame, keypoints, descriptors, f.T_W_C, f.scale);
    keep(*keyframe_);
    ++keyframes_;
    f.new_keyframe = true;
  }
  remember(frame, f);
  return f;
}

void KeyframeTracker::remember(const TrackerFrame& frame, const TrackResult& r) {
  if (!config_.flow_bridge) return;
  // Copies: the caller may reuse or rescale its buffers.
  Posed p;
  p.frame.gray = frame.gray.clone();
  p.frame.K = frame.K;
  p.frame.points_C = frame.points_C.clone();
  p.frame.model_to_image = frame.model_to_image;
  p.frame.depth = frame.depth.clone();
  p.T_W_C = r.T_W_C;
  p.scale = r.scale;
  previous_ = std::move(p);
}

TrackResult KeyframeTracker::by_flow(const TrackerFrame& frame) const {
  const Posed& p = *previous_;
  TrackResult r;
  r.status = TrackStatus::kTooFewMatches;
  r.scale = last_scale_;
  if (p.frame.gray.size() != frame.gray.size()) {
    r.message = "optical flow: the image's size changed since the last posed frame";
    return r;
  }
  std::vector<cv::Point2f> corners;
  cv::goodFeaturesToTrack(p.frame.gray, corners, kFlowCorners, kFlowQuality, kFlowMinDistancePx);
  std::vector<cv::Point2f> tracked, back;
  std::vector<uchar> found, found_back;
  std::vector<float> error;
  const cv::Size window(kFlowWindowPx, kFlowWindowPx);
  if (!corners.empty()) {
    cv::calcOpticalFlowPyrLK(p.frame.gray, frame.gray, corners, tracked, found, error, window,
                             kFlowLevels);
    back = corners;  // the flow back starts where the corners were
    cv::calcOpticalFlowPyrLK(
        frame.gray, p.frame.gray, tracked, back, found_back, error, window, kFlowLevels,
        cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 30, 0.01),
        cv::OPTFLOW_USE_INITIAL_FLOW);
  }
  // The last posed frame's corners as a keyframe's features, the tracked
  // pixels as the frame's, matched one to one.
  std::vector<cv::KeyPoint> from, to;
  std::vector<cv::DMatch> matches;
  const cv::Rect inside(0, 0, frame.gray.cols, frame.gray.rows);
  for (std::size_t i = 0; i < corners.size(); ++i) {
    if (!found[i] || !found_back[i] || cv::norm(back[i] - corners[i]) > kFlowBackPx ||
        !inside.contains(cv::Point(cvRound(tracked[i].x), cvRound(tracked[i].y)))) {
      continue;
    }
    const int j = static_cast<int>(from.size());
    matches.emplace_back(j, j, 0.0f);
    from.emplace_back(corners[i], 1.0f);
    to.emplace_back(tracked[i], 1.0f);
  }
  const Keyframe previous = make_keyframe(p.frame, from, cv::Mat(), p.T_W_C, p.scale);
  TrackResult f = solve(previous, frame, to, matches);
  f.flow = f.posed();
  if (!f.posed()) {
    f.message = "optical flow from the last posed frame: " + std::to_string(matches.size()) +
                " of " + std::to_string(corners.size()) + " corners followed; " + f.message;
  }
  return f;
}

TrackResult KeyframeTracker::relative(const KeptKeyframe& kf, const TrackerFrame& frame,
                                      const std::vector<cv::KeyPoint>& keypoints,
                                      const cv::Mat& descriptors, bool guide) const {
  // 1. Matches frame -> keyframe, ratio test, one frame feature per keyframe feature.
  const std::vector<cv::DMatch> matches =
      ratio_matches(descriptors, kf.descriptors, config_.ratio_test);
  TrackResult r = solve(kf, frame, keypoints, matches);
  if (!guide || !config_.guided_matching || !r.posed()) return r;
  // 1b. Matched again about the pose found; kept where more matches agree.
  TrackResult g = by_projection(kf, frame, keypoints, descriptors, r.T_W_C.inverse() * kf.T_W_K,
                                config_.guided_radius_px, matches.size());
  return g.posed() && g.inliers > r.inliers ? g : r;
}

TrackResult KeyframeTracker::by_projection(const KeptKeyframe& kf, const TrackerFrame& frame,
                                           const std::vector<cv::KeyPoint>& keypoints,
                                           const cv::Mat& descriptors,
                                           const Eigen::Isometry3d& T_C_K_guess, double radius_px,
                                           std::size_t more_than) const {
  // Search by projection: each keyframe point projected by the guess is
  // matched within the radius, which finds the matches the ratio test drops
  // among similar corners. The guided matches replace the ratio test's: kept
  // beside them instead, the paths were no better (docs/model_card.md,
  // "Guided matching").
  std::vector<cv::Point2f> predicted(kf.points.size(),
                                     cv::Point2f(std::numeric_limits<float>::quiet_NaN(), 0.0f));
  for (std::size_t i = 0; i < kf.points.size(); ++i) {
    if (!kf.points[i]) continue;
    const Eigen::Vector3d X = T_C_K_guess * *kf.points[i];
    if (X.z() <= 0.0) continue;
    const Eigen::Vector3d p = frame.K * (X / X.z());
    predicted[i] = cv::Point2f(static_cast<float>(p.x()), static_cast<float>(p.y()));
  }
  const std::vector<cv::DMatch> guided =
      projected_matches(keypoints, descriptors, predicted, kf.descriptors, radius_px,
                        kGuidedMaxDistance, kGuidedRatio);
  if (guided.size() <= more_than) {
    TrackResult r;
    r.status = TrackStatus::kTooFewMatches;
    r.scale = last_scale_;
    r.matches = static_cast<int>(guided.size());
    r.message = std::to_string(guided.size()) + " matches by projection";
    return r;
  }
  TrackResult g = solve(kf, frame, keypoints, guided);
  g.guided = g.posed();
  return g;
}

TrackResult KeyframeTracker::solve(const KeptKeyframe& kf, const TrackerFrame& frame,
                                   const std::vector<cv::KeyPoint>& keypoints,
                                   const std::vector<cv::DMatch>& matches) const {
  TrackResult r;
  r.scale = last_scale_;  // unless the frame measures its own (4.)
  std::ostringstream why;
  std::vector<cv::Point2f> px_k, px_f;
  std::vector<int> idx_k;
  for (const cv::DMatch& m : matches) {
    idx_k.push_back(m.trainIdx);
    px_k.push_back(kf.pixels[static_cast<std::size_t>(m.trainIdx)]);
    px_f.push_back(keypoints[static_cast<std::size_t>(m.queryIdx)].pt);
  }
  r.matches = static_cast<int>(px_k.size());
  if (r.matches < config_.min_matches) {
    r.status = TrackStatus::kTooFewMatches;
    why << r.matches << " matches with the keyframe (at least " << config_.min_matches << ")";
    r.message = why.str();
    return r;
  }

  cv::Mat K_cv;
  cv::eigen2cv(frame.K, K_cv);
  const Eigen::Matrix3d K_inv = frame.K.inverse();
  auto bearing_f = [&](int i) {
    return (K_inv * Eigen::Vector3d(px_f[i].x, px_f[i].y, 1.0)).normalized();
  };

  // A candidate relative pose T_C_K and the matches it explains.
  struct Candidate {
    Eigen::Isometry3d T_C_K = Eigen::Isometry3d::Identity();
    std::vector<int> inliers;  // indices into the matches
    TrackingSolver solver = TrackingSolver::kEssential;
  };
  auto parallax_of = [&](const Eigen::Matrix3d& R_C_K, const std::vector<int>& which) {
    std::vector<double> parallax;
    for (int i : which) {
      const Eigen::Vector3d rb = R_C_K * kf.bearings[static_cast<std::size_t>(idx_k[i])];
      parallax.push_back(std::acos(std::clamp(rb.dot(bearing_f(i)), -1.0, 1.0)) * kRadToDeg);
    }
    return median(parallax);
  };

  // 3. Rotation and direction from the essential matrix, the length from
  // the keyframe's points.
  std::optional<Candidate> essential;
  if (config_.solver == TrackingSolver::kEssential) {
    cv::theRNG().state = kRansacSeed;
    cv::Mat mask;
    const cv::Mat E = cv::findEssentialMat(px_k, px_f, K_cv, cv::RANSAC, 0.999,
                                           config_.ransac_threshold_px, mask);
    if (E.rows == 3 && E.cols == 3) {
      cv::Mat R, t;
      cv::recoverPose(E, px_k, px_f, K_cv, R, t, mask);
      Candidate c;
      c.T_C_K = isometry(R, t);
      const Eigen::Vector3d dir = c.T_C_K.translation().normalized();
      std::vector<std::pair<double, double>> lengths;
      for (int i = 0; i < r.matches; ++i) {
        if (!mask.at<uchar>(i)) continue;
        c.inliers.push_back(i);
        const auto& X = kf.points[static_cast<std::size_t>(idx_k[i])];
        if (!X) continue;
        // The length L with b x (R X + L dir) = 0, least squares per match.
        const Eigen::Vector3d b = bearing_f(i);
        const Eigen::Vector3d c_point = b.cross(c.T_C_K.linear() * *X);
        const Eigen::Vector3d c_dir = b.cross(dir);
        const double w = c_dir.squaredNorm();
        if (w < 1e-12) continue;
        lengths.emplace_back(-c_dir.dot(c_point) / w, w);
      }
      const double length = weighted_median(lengths);
      if (static_cast<int>(c.inliers.size()) >= config_.min_matches &&
          static_cast<int>(lengths.size()) >= kMinLiftedInliers &&
          parallax_of(c.T_C_K.linear(), c.inliers) >= config_.min_parallax_deg && length > 0.0 &&
          std::isfinite(length)) {
        c.T_C_K.translation() = dir * length;
        essential = c;
      }
    }
  }

  // 2. PnP of the lifted keyframe points.
  std::optional<Candidate> pnp;
  std::vector<cv::Point3f> object;
  std::vector<cv::Point2f> image;
  std::vector<int> which;
  for (int i = 0; i < r.matches; ++i) {
    const auto& X = kf.points[static_cast<std::size_t>(idx_k[i])];
    if (!X) continue;
    object.emplace_back(static_cast<float>(X->x()), static_cast<float>(X->y()),
                        static_cast<float>(X->z()));
    image.push_back(px_f[i]);
    which.push_back(i);
  }
  r.lifted = static_cast<int>(object.size());
  int pnp_inliers_found = 0;
  if (static_cast<int>(object.size()) >= kMinLiftedInliers) {
    cv::theRNG().state = kRansacSeed;
    cv::Mat rvec, tvec;
    std::vector<int> pnp_inliers;
    const bool ok = cv::solvePnPRansac(object, image, K_cv, cv::noArray(), rvec, tvec, false, 200,
                                       static_cast<float>(config_.pnp_reprojection_error_px), 0.999,
                                       pnp_inliers, cv::SOLVEPNP_EPNP);
    pnp_inliers_found = ok ? static_cast<int>(pnp_inliers.size()) : 0;
    if (pnp_inliers_found >= config_.min_matches) {
      Candidate c;
      c.solver = TrackingSolver::kPnp;
      std::vector<cv::Point3f> in_obj;
      std::vector<cv::Point2f> in_img;
      for (int j : pnp_inliers) {
        in_obj.push_back(object[static_cast<std::size_t>(j)]);
        in_img.push_back(image[static_cast<std::size_t>(j)]);
        c.inliers.push_back(which[static_cast<std::size_t>(j)]);
      }
      cv::solvePnPRefineLM(in_obj, in_img, K_cv, cv::noArray(), rvec, tvec);
      cv::Mat R;
      cv::Rodrigues(rvec, R);
      c.T_C_K = isometry(R, tvec);
      pnp = c;
    }
  }

  // Both: the one the images agree with, by the matches within the RANSAC
  // threshold of their epipolar plane (of the rotated ray, for a camera
  // that only turned). The depth cannot bias this choice.
  const double threshold_rad = config_.ransac_threshold_px / frame.K(0, 0);
  auto epipolar_inliers = [&](const Eigen::Isometry3d& T) {
    const double length = T.translation().norm();
    const Eigen::Vector3d dir =
        length > 1e-12 ? Eigen::Vector3d(T.translation() / length) : Eigen::Vector3d::Zero();
    int n = 0;
    for (int i = 0; i < r.matches; ++i) {
      const Eigen::Vector3d rb = T.linear() * kf.bearings[static_cast<std::size_t>(idx_k[i])];
      const Eigen::Vector3d b = bearing_f(i);
      const Eigen::Vector3d normal = dir.cross(rb);
      const double err =
          normal.norm() > 1e-9 ? std::abs(b.dot(normal.normalized())) : (b - rb).norm();
      n += err < threshold_rad ? 1 : 0;
    }
    return n;
  };
  std::optional<Candidate> chosen = essential ? essential : pnp;
  if (essential && pnp && epipolar_inliers(pnp->T_C_K) > epipolar_inliers(essential->T_C_K)) {
    chosen = pnp;
  }
  if (!chosen) {
    if (static_cast<int>(object.size()) < kMinLiftedInliers) {
      r.status = TrackStatus::kNoDepth;
      why << object.size() << " of " << r.matches << " matches have keyframe depth";
    } else {
      r.status = TrackStatus::kTooFewMatches;
      why << pnp_inliers_found << " PnP inliers of " << object.size()
          << " lifted matches (at least " << config_.min_matches << ")";
    }
    r.message = why.str();
    return r;
  }
  const std::optional<Eigen::Isometry3d> T_C_K = chosen->T_C_K;
  const std::vector<int>& inliers = chosen->inliers;
  r.solver = chosen->solver;
  r.parallax_deg = parallax_of(T_C_K->linear(), inliers);
  r.inliers = static_cast<int>(inliers.size());
  if (r.parallax_deg > kMaxParallaxDeg) {
    r.status = TrackStatus::kTooFewMatches;
    why << "the pose of " << r.inliers << " inliers sees them " << r.parallax_deg
        << " degrees from where the keyframe did (at most " << kMaxParallaxDeg << "): not taken";
    r.message = why.str();
    return r;
  }
  r.T_W_C = kf.T_W_K * T_C_K->inverse();
  r.status = TrackStatus::kTracked;

  // 4. The frame's scale: predicted over its own depth at the inliers.
  const Eigen::Matrix3d image_to_model = frame.model_to_image.inverse();
  std::vector<double> ratios;
  for (int i : inliers) {
    const auto& X = kf.points[static_cast<std::size_t>(idx_k[i])];
    if (!X) continue;
    const std::optional<Eigen::Vector3d> own = point_at(frame, image_to_model, px_f[i]);
    const double predicted = (*T_C_K * *X).z();
    if (own && own->z() > 0.0 && predicted > 0.0) ratios.push_back(predicted / own->z());
  }
  r.scale_measured = !ratios.empty();
  if (r.scale_measured) {
    r.scale = frame.depth.empty() ? median(ratios) : 1.0;
    // How far the frame's own depth, at its scale, lies from the
    // keyframe's points: a ratio of their depth.
    std::vector<double> errors;
    errors.reserve(ratios.size());
    for (double q : ratios) errors.push_back(std::abs(r.scale / q - 1.0));
    r.depth_error = median(std::move(errors));
  }
  return r;
}

std::string KeyframeTracker::relocalisation_failure(const TrackResult& r) const {
  std::ostringstream why;
  if (!r.posed()) {
    why << r.message;
  } else if (r.inliers < config_.relocalisation_min_inliers) {
    why << r.inliers << " inliers (at least " << config_.relocalisation_min_inliers << ")";
  } else if (r.inliers < config_.relocalisation_min_inlier_share * r.lifted) {
    why << r.inliers << " inliers of " << r.lifted << " lifted matches (at least "
        << config_.relocalisation_min_inlier_share * 100.0 << " %)";
  } else if (!r.scale_measured) {
    why << "no inlier with depth in the frame";
  } else if (r.depth_error > config_.relocalisation_max_depth_error) {
    why << "the frame's depth is " << r.depth_error * 100.0
        << " % off the keyframe's points at the inliers (at most "
        << config_.relocalisation_max_depth_error * 100.0 << " %)";
  }
  return why.str();
}

TrackResult KeyframeTracker::relocalise(const TrackerFrame& frame,
                                        const std::vector<cv::KeyPoint>& keypoints,
                                        const cv::Mat& descriptors,
                                        const Eigen::Isometry3d& T_W_C_prior) {
  // The candidates: the current keyframe, then the kept ones nearest the
  // caller's pose (a baseline of a tenth of the depth weighs as a degree),
  // then the others in turn across frames, so that a wrong prior (the
  // model's pose after a load) still reaches every kept keyframe.
  std::vector<const KeptKeyframe*> candidates;
  const std::size_t budget = static_cast<std::size_t>(config_.relocalisation_candidates);
  if (keyframe_) candidates.push_back(&*keyframe_);
  std::vector<std::pair<double, std::size_t>> near;
  for (std::size_t i = 0; i < kept_.size(); ++i) {
    const KeptKeyframe& k = kept_[i];
    const double baseline =
        (k.T_W_K.translation() - T_W_C_prior.translation()).norm() / k.median_depth;
    const double angle =
        Eigen::AngleAxisd(k.T_W_K.linear().transpose() * T_W_C_prior.linear()).angle() * kRadToDeg;
    near.emplace_back(10.0 * baseline + angle, i);
  }
  std::sort(near.begin(), near.end());
  std::vector<bool> chosen(kept_.size(), false);
  const std::size_t nearest = budget > 2 ? budget - 2 : budget / 2;
  for (std::size_t j = 0; j < near.size() && candidates.size() < nearest; ++j) {
    chosen[near[j].second] = true;
    candidates.push_back(&kept_[near[j].second]);
  }
  for (std::size_t tried = 0; tried < kept_.size() && candidates.size() < budget; ++tried) {
    const std::size_t i = next_candidate_++ % kept_.size();
    if (chosen[i]) continue;
    chosen[i] = true;
    candidates.push_back(&kept_[i]);
  }

  std::optional<std::pair<TrackResult, const KeptKeyframe*>> best;
  // The failing candidate with the most inliers (then matches), for the message.
  std::optional<std::pair<TrackResult, std::string>> closest;
  for (const KeptKeyframe* k : candidates) {
    // Without guidance: the checks below were measured on ratio-test matches.
    TrackResult r = relative(*k, frame, keypoints, descriptors, false);
    std::string why = relocalisation_failure(r);
    if (why.empty()) {
      if (!best || r.inliers > best->first.inliers) best.emplace(r, k);
    } else if (!closest || std::make_pair(r.inliers, r.matches) >
                               std::make_pair(closest->first.inliers, closest->first.matches)) {
      closest.emplace(r, std::move(why));
    }
  }
  if (!best) {
    TrackResult r;
    r.status = TrackStatus::kRefused;
    r.scale = last_scale_;
    std::ostringstream why;
    why << "not placed against " << candidates.size() << " of " << kept_.size()
        << " kept keyframes";
    if (closest) {
      const TrackResult& c = closest->first;
      r.matches = c.matches;
      r.inliers = c.inliers;
      r.lifted = c.lifted;
      r.depth_error = c.depth_error;
      why << " (the closest: " << closest->second << ")";
    }
    r.message = why.str();
    return r;
  }
  // Placed: tracking goes on from the keyframe that placed it.
  TrackResult r = best->first;
  r.status = TrackStatus::kRelocalised;
  Keyframe kf;
  static_cast<KeptKeyframe&>(kf) = *best->second;
  keyframe_ = std::move(kf);
  last_.reset();
  lost_ = 0;
  last_scale_ = r.scale;
  relocalising_ = false;
  return r;
}

}  // namespace long3r

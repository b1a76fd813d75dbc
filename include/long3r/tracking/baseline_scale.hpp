// BaselineScale: the metric scale of the model's depth from the motion of a
// camera whose poses are known in metres (wheel odometry placing the frames,
// pose_source odometry), without relying on the model's registration.
//
// Frames: W is the given poses' frame (metres); R the reference frame's
// camera, C the current one's (optical frames). Points of the pointmaps are
// in their own camera and the model's units.
//
// Per frame (add()): ORB features on the full-resolution grey image, matched
// with the reference frame's (the same detector and ratio test as the
// keyframe tracker); each match's two rays, placed by the metric poses, are
// triangulated (the midpoint of their closest points); once the matches'
// median parallax is large enough, every match whose rays meet within a
// pixel gives the triangulated depth in R over the model's depth at the
// reference pixel. Their median is a sample of metres per model unit.
// Every frame is kept as a reference (the last kMaxReferences); each new
// frame is measured against the oldest one it still sees, once their
// parallax suffices, and that reference is then used up: once the motion
// has built the parallax, every frame gives a sample, each over another
// pair of frames.
#pragma once

#include <Eigen/Geometry>
#include <opencv2/core/mat.hpp>
#include <opencv2/features2d.hpp>

#include <deque>
#include <optional>
#include <string>
#include <vector>

#include "long3r/tracking/keyframe_tracker.hpp"

namespace long3r {

struct BaselineScaleResult {
  std::optional<double> sample;  // metres per model unit, when measured
  int matches = 0, triangulated = 0;
  double parallax_deg = 0.0;  // median over the matches
  std::string message;        // why no sample, with the numbers
};

class BaselineScale {
 public:
  // Features and matching as the tracker's config says (max_features,
  // fast_threshold, ratio_test).
  explicit BaselineScale(const KeyframeTrackerConfig& features = {});

  // frame.points_C: the model's pointmap in C, in model units. T_W_C: the
  // frame's pose in metres. Throws std::invalid_argument for wrong types.
  BaselineScaleResult add(const TrackerFrame& frame, const Eigen::Isometry3d& T_W_C);
  void reset() { references_.clear(); }

  // A sample once the matches' median parallax reaches this; every match
  // of more than a quarter of it counts (choosing matches by their own
  // parallax would keep those whose noise shortened their depth).
  static constexpr double kMinParallaxDeg = 1.0;
  static constexpr int kMinTriangulated = 20;
  static constexpr std::size_t kMaxReferences = 30;
  static constexpr double kMaxRayGapPx = 1.5;  // the rays' closest distance, in pixels

 private:
  struct Reference {
    std::vector<cv::Point2f> pixels;
    cv::Mat descriptors;
    std::vector<Eigen::Vector3d> bearings;      // unit, in R
    std::vector<std::optional<double>> depths;  // the model's z in R, model units
    Eigen::Isometry3d T_W_R = Eigen::Isometry3d::Identity();
  };
  // One reference against the frame (no state changes).
  BaselineScaleResult measure(const Reference& ref, const TrackerFrame& frame,
                              const std::vector<cv::KeyPoint>& keypoints,
                              const cv::Mat& descriptors, const Eigen::Isometry3d& T_W_C) const;
  Reference make_reference(const TrackerFrame& frame, const std::vector<cv::KeyPoint>& keypoints,
                           const cv::Mat& descriptors, const Eigen::Isometry3d& T_W_C) const;

  KeyframeTrackerConfig features_;
  cv::Ptr<cv::ORB> orb_;
  std::deque<Reference> references_;  // oldest first
};

}  // namespace long3r

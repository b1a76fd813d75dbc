// KeyframeTracker: each frame's pose from image correspondences with a
// keyframe, lifted to 3D by the model's pointmaps, rather than from the
// model's own registration (pose.hpp's PnP on the world pointmap).
//
// Frames: W is the stream's world (camera 0's optical frame); C the frame's
// camera optical frame (x right, y down, z forward), K the keyframe's.
// Lengths are in the stream's scale: a keyframe's points are its own
// pointmap times the scale that made it agree with the keyframe before it.
//
// Per frame (track()):
//   1. ORB features on the full-resolution (rectified) grey image, matched
//      to the keyframe's by Hamming distance with Lowe's ratio test; then
//      (guided_matching) matched again by projection: the keyframe's points
//      projected by the pose those matches gave, or by the caller's prior
//      where neither the keyframe's nor the last tracked frame's place the
//      frame, each matched to the closest feature near its pixel, and the
//      pose solved again from these where more of them agree with it;
//   2. PnP-RANSAC (EPnP, then Levenberg-Marquardt on the inliers) of the
//      keyframe's points, lifted by its pointmap, against the frame's
//      matched features;
//   3. with solver `essential`, also the relative rotation R_C_K and the
//      translation's direction from the essential matrix of the 2-D
//      matches (RANSAC, then the cheirality test), which needs no depth
//      (on real footage the prototype found its rotation the better one),
//      the length from the keyframe's points (each inlier gives the length
//      that puts its point on the frame's ray; their weighted median); of
//      the two poses, the one more matches agree with by their epipolar
//      planes, which the depth cannot bias. Too little parallax (a still or
//      turning camera): PnP's;
//   4. the frame's own scale against the stream's: the median ratio of its
//      matched points' predicted depth to its pointmap's depth (Sim(3)), so
//      the map does not follow the model's per-frame scale (1 where a depth
//      camera's depth lifted the frame: the chain of ratios would only add
//      its noise to a depth already in the stream's scale);
//   5. a new keyframe when the parallax, the share of the keyframe's
//      features still matched, or the frames since the keyframe say so;
//      a frame the keyframe no longer sees is tried against the last
//      tracked frame, which then becomes the keyframe; after untracked
//      frames in a row, the frame becomes the keyframe where the caller
//      placed it.
// A frame with too few matches (a blank wall, a dark or blurred image, a cut
// to another scene) is not posed: the caller falls back (its motion prior).
// With flow_bridge, such a frame is first tracked by optical flow from the
// last frame the images posed (when_lost prior): Shi-Tomasi corners there,
// whose threshold follows the image's own contrast where FAST's is fixed,
// followed by pyramidal Lucas-Kanade (kept where the flow back returns to
// them), lifted by that frame's depth, then steps 2-4 as for a keyframe.
// Posed so, it becomes the keyframe where it has the features for one.
// A pointmap that lies behind its camera never makes a keyframe.
//
// Relocalisation by images: keyframes from new viewpoints are kept (a
// sparse set, bounded; what sessions save). After a restore (a loaded
// session) or lose() (the caller lost the frame's pose), a frame is posed
// only when the images place it against a kept keyframe (the current one
// first, then the nearest to the caller's pose, then the rest in turn) with
// enough PnP inliers, a large enough share of its lifted matches, and its
// own depth agreeing with the kept keyframe's points at them (the distance
// of its points to the saved map, as a ratio of their depth); otherwise it
// is refused (kRefused), and no keyframe is made from it.
// Nothing here knows the model: the pointmap comes in as a CV_32FC3 in C.
#pragma once

#include <Eigen/Geometry>
#include <opencv2/core/mat.hpp>
#include <opencv2/core/types.hpp>
#include <opencv2/features2d.hpp>

#include <array>
#include <cstdint>
#include <deque>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "long3r/config/config_fields.hpp"

namespace long3r {

// How a frame's relative pose is found (the steps above).
enum class TrackingSolver {
  kEssential,  // 2 and 3, the pose the epipolar geometry agrees with
  kPnp,        // 2 only: PnP on the lifted keyframe points
};
inline const std::array<std::pair<TrackingSolver, const char*>, 2>& enum_names(TrackingSolver) {
  static const std::array<std::pair<TrackingSolver, const char*>, 2> names{
      {{TrackingSolver::kEssential, "essential"}, {TrackingSolver::kPnp, "pnp"}}};
  return names;
}

// What a textured frame that shares too few matches with the keyframe and
// the last tracked frame leads to: the tracker cannot tell a cut to another
// scene from a fast move out of the mapped view.
enum class WhenLost {
  // Not posed, and the next frames are relocalised against the current and
  // the kept keyframes (posed only where the images agree; after
  // the live session's relocalise_for_s a new stream starts). A cut never
  // moves the path or the map.
  kRelocalise,
  // Placed by the caller's prior (MotionPrior); the second such frame in a
  // row becomes a new keyframe there.
  kPrior,
};
// "model_motion": the older name of "prior", still read.
inline const std::array<std::pair<WhenLost, const char*>, 3>& enum_names(WhenLost) {
  static const std::array<std::pair<WhenLost, const char*>, 3> names{
      {{WhenLost::kRelocalise, "relocalise"},
       {WhenLost::kPrior, "prior"},
       {WhenLost::kPrior, "model_motion"}}};
  return names;
}

// Where the caller puts a frame the tracker cannot place (when_lost prior),
// and where a keyframe made after lost frames sits. constant_velocity by
// measurement: on 200 generated frames at stride 4 it placed the lost frames
// within the tracked frames' own step error (the model's motion: 7 times too
// long) and the path's ATE fell to 0.71x a still camera on all three sets
// (0.78-0.96x with the model's motion); on 60 frames nothing changed
// (docs/model_card.md, "Poses from keyframes").
enum class MotionPrior {
  kModel,  // the model's own motion since the last placed frame
  // The motion between the last two frames the images placed, continued
  // (none before two are placed: the model's first motion would be carried
  // on; on a 160 x 120 robot path whose first frames have too few features
  // the path came out eight times too long).
  kConstantVelocity,
  // The motion a robot's odometry measured since the last placed frame (the
  // camera's pose in the odometry frame at both stamps): its rotation, and
  // its translation once the stream's lengths are metres (else the constant
  // velocity's). A frame without odometry: the constant velocity.
  kOdometry,
};
inline const std::array<std::pair<MotionPrior, const char*>, 3>& enum_names(MotionPrior) {
  static const std::array<std::pair<MotionPrior, const char*>, 3> names{
      {{MotionPrior::kModel, "model"},
       {MotionPrior::kConstantVelocity, "constant_velocity"},
       {MotionPrior::kOdometry, "odometry"}}};
  return names;
}

// Defaults by measurement on generated footage (docs/model_card.md,
// "Poses from keyframes").
struct KeyframeTrackerConfig {
  TrackingSolver solver = TrackingSolver::kPnp;
  int max_features = 1000;  // ORB features per frame
  int fast_threshold = 10;  // ORB's FAST corner threshold (grey levels)
  int pyramid_levels = 8;   // ORB's scale pyramid (factor 1.2 a level)
  double ratio_test = 0.8;  // Lowe's ratio of best to second-best distance
  // Step 1's guided matching. Off by default: on 200 generated frames at
  // stride 4 and on real video it placed the frames closer, but on 60
  // frames it was no better and on the 64-pixel pointmaps of the pipeline's
  // test fixtures it moved poses further off (docs/model_card.md, "Guided
  // matching").
  bool guided_matching = false;
  // Its search radius about a keyframe point's projection by the pose found
  // (3 times this about the caller's prior), source pixels.
  double guided_radius_px = 8.0;
  int min_matches = 30;                    // fewer (after RANSAC): the frame is not tracked
  double ransac_threshold_px = 1.0;        // essential-matrix RANSAC, source pixels
  double pnp_reprojection_error_px = 3.0;  // PnP-RANSAC fallback, source pixels
  double min_parallax_deg = 0.5;  // less: the essential matrix's direction is noise, PnP instead
  // A new keyframe when the median parallax passes this, or the inliers fall
  // below keyframe_min_overlap of those of the first frame tracked against
  // the keyframe, or keyframe_max_frames frames have passed.
  double keyframe_parallax_deg = 4.0;
  double keyframe_min_overlap = 0.4;
  int keyframe_max_frames = 4;
  // Relocalisation: a frame is placed against a kept keyframe only with at
  // least this many PnP inliers, this share of the matches with keyframe
  // depth among them, and its own depth at the inliers within this median
  // relative difference of the keyframe's points (after its Sim(3) scale).
  int relocalisation_min_inliers = 40;
  double relocalisation_min_inlier_share = 0.3;
  double relocalisation_max_depth_error = 0.2;
  int relocalisation_candidates = 6;  // kept keyframes tried per frame
  // A keyframe is kept unless a kept one is within this baseline (a share
  // of its median depth) and this angle; at most max_kept_keyframes are kept,
  // the oldest dropped first.
  double kept_keyframe_baseline = 0.15;
  double kept_keyframe_angle_deg = 10.0;
  int max_kept_keyframes = 500;
  // prior by measurement: on real frames a second apart the frames
  // that lose the keyframe share as many matches with it (21-23) as another
  // scene's do (0-29), and relocalising posed 2 of 25 of them against 25
  // (docs/model_card.md, "A cut to another scene").
  WhenLost when_lost = WhenLost::kPrior;
  MotionPrior motion_prior = MotionPrior::kConstantVelocity;
  // The optical-flow bridge above, for frames the features cannot place
  // (when_lost prior only: with relocalise a lost frame must be placed by
  // the kept keyframes).
  bool flow_bridge = true;

  // Throws ConfigError naming the field.
  void validate(const config::FieldCheck& check) const;
};

template <class S, class V>
config::FieldsOf<S, KeyframeTrackerConfig> visit_fields(S& s, V& v) {
  v("solver", s.solver);
  v("max_features", s.max_features);
  v("fast_threshold", s.fast_threshold);
  v("pyramid_levels", s.pyramid_levels);
  v("ratio_test", s.ratio_test);
  v("guided_matching", s.guided_matching);
  v("guided_radius_px", s.guided_radius_px);
  v("min_matches", s.min_matches);
  v("ransac_threshold_px", s.ransac_threshold_px);
  v("pnp_reprojection_error_px", s.pnp_reprojection_error_px);
  v("min_parallax_deg", s.min_parallax_deg);
  v("keyframe_parallax_deg", s.keyframe_parallax_deg);
  v("keyframe_min_overlap", s.keyframe_min_overlap);
  v("keyframe_max_frames", s.keyframe_max_frames);
  v("relocalisation_min_inliers", s.relocalisation_min_inliers);
  v("relocalisation_min_inlier_share", s.relocalisation_min_inlier_share);
  v("relocalisation_max_depth_error", s.relocalisation_max_depth_error);
  v("relocalisation_candidates", s.relocalisation_candidates);
  v("kept_keyframe_baseline", s.kept_keyframe_baseline);
  v("kept_keyframe_angle_deg", s.kept_keyframe_angle_deg);
  v("max_kept_keyframes", s.max_kept_keyframes);
  v("when_lost", s.when_lost);
  v("motion_prior", s.motion_prior);
  v("flow_bridge", s.flow_bridge);
}

// One frame as the tracker sees it.
struct TrackerFrame {
  cv::Mat gray;       // CV_8UC1, full resolution, rectified
  Eigen::Matrix3d K;  // its intrinsics (pixel centres at integers)
  cv::Mat points_C;   // CV_32FC3 [h, w]: the model's pointmap in C, its own scale
  Eigen::Matrix3d model_to_image = Eigen::Matrix3d::Identity();  // model pixel -> image pixel
  // A depth camera's depth (CV_32FC1, the image's size and registered to it,
  // in the stream's scale; 0 or NaN where there is none), or empty. Given,
  // it lifts each feature along its own ray by the median depth of its 3 x 3
  // pixels rather than by the pointmap's nearest point, and the frame's
  // scale is 1, not measured
  // against the keyframe's (step 4 still measures how far its depth lies
  // from the keyframe's points). points_C should then be at this depth too.
  cv::Mat depth;
};

enum class TrackStatus {
  kKeyframe,        // the stream's first keyframe: posed as the caller said
  kTracked,         // posed from the matches
  kTooFewFeatures,  // the image has too few features (blank, dark, blurred)
  kTooFewMatches,   // too few matches with the keyframe (or inliers after RANSAC)
  kNoDepth,         // too few matched keyframe points with depth to give the length
  kRelocalised,     // relocalising: posed against a kept keyframe, the checks passed
  kRefused,         // relocalising: no kept keyframe places the frame (not posed)
  kLost,            // too few matches in a textured image (when_lost relocalise): not
                    // posed, and the next frames are relocalised
};
const char* to_string(TrackStatus status);

struct TrackResult {
  TrackStatus status = TrackStatus::kTooFewFeatures;
  std::string message;  // why not, with the numbers; empty when posed
  bool posed() const {
    return status == TrackStatus::kKeyframe || status == TrackStatus::kTracked ||
           status == TrackStatus::kRelocalised;
  }
  Eigen::Isometry3d T_W_C = Eigen::Isometry3d::Identity();
  // The frame's pointmap times this is in the stream's scale: measured at
  // its inliers (scale_measured), else the last posed frame's (also when the
  // frame is not posed).
  double scale = 1.0;
  bool scale_measured = false;
  TrackingSolver solver = TrackingSolver::kEssential;  // what gave the pose
  int features = 0, matches = 0, inliers = 0;
  int lifted = 0;             // matches with a keyframe point
  double parallax_deg = 0.0;  // median over the inliers
  // Median over the inliers of |own depth x scale / keyframe point's depth - 1|.
  double depth_error = 0.0;
  bool new_keyframe = false;
  bool guided = false;       // the pose is from the guided matches (step 1)
  bool flow = false;         // the pose is from the optical-flow bridge
  double features_ms = 0.0;  // of track(), ORB's detection and descriptors
};

// A keyframe as kept for relocalisation and saved with sessions: its ORB
// features on the full-resolution image and their points in K.
struct KeptKeyframe {
  std::vector<cv::Point2f> pixels;
  cv::Mat descriptors;                                 // CV_8UC1 [features, 32]
  std::vector<Eigen::Vector3d> bearings;               // unit, in K's frame
  std::vector<std::optional<Eigen::Vector3d>> points;  // in K, stream scale
  Eigen::Isometry3d T_W_K = Eigen::Isometry3d::Identity();
  double median_depth = 1.0;  // of its points (1 without any): its viewpoint's scale
};
// The median depth of a keyframe's points (1 without any).
double median_depth(const std::vector<std::optional<Eigen::Vector3d>>& points);
// The frame's point under an image pixel: on the pixel's ray at its depth
// image's depth where the frame has one, else the pointmap's at the nearest
// model pixel; if finite. image_to_model is frame.model_to_image's inverse.
std::optional<Eigen::Vector3d> point_at(const TrackerFrame& frame,
                                        const Eigen::Matrix3d& image_to_model,
                                        const cv::Point2f& pixel);

class KeyframeTracker {
 public:
  explicit KeyframeTracker(const KeyframeTrackerConfig& config = {});

  // T_W_C_prior: the caller's pose for the frame should it not be tracked.
  // The first frame of a stream (or the first after reset()) becomes the
  // keyframe there; later ones are tracked. A frame with too few matches
  // is lost (config.when_lost: relocalising from the next frame, or placed
  // at its prior, the second such frame in a row becoming the keyframe
  // there); so is the second frame in a row without depth. Throws
  // std::invalid_argument
  // for a frame of the wrong types.
  TrackResult track(const TrackerFrame& frame,
                    const Eigen::Isometry3d& T_W_C_prior = Eigen::Isometry3d::Identity());

  // The world's scale changed by `factor` (Reconstruction::set_scale).
  void rescale(double factor);
  void reset();
  // The caller lost the pose of a frame: the next frames are relocalised
  // (when there is a keyframe to relocalise against).
  void lose();
  bool relocalising() const { return relocalising_; }
  // The kept keyframes, oldest first (sessions save them).
  const std::deque<KeptKeyframe>& kept() const { return kept_; }
  // A saved stream's kept keyframes replace this one's: the next frames are
  // relocalised against them (none: the next frame starts a keyframe, as a
  // new stream's first). Throws std::invalid_argument for a keyframe whose
  // parts differ in length or whose descriptors are not ORB's.
  void restore(std::vector<KeptKeyframe> kept);
  bool has_keyframe() const { return keyframe_.has_value(); }
  int keyframes() const { return keyframes_; }  // made in this stream
  const KeyframeTrackerConfig& config() const { return config_; }

 private:
  struct Keyframe : KeptKeyframe {
    int64_t frames_since = 0;
    int reference_inliers = 0;  // the first frame tracked against it
  };
  Keyframe make_keyframe(const TrackerFrame& frame, const std::vector<cv::KeyPoint>& keypoints,
                         const cv::Mat& descriptors, const Eigen::Isometry3d& T_W_C,
                         double scale) const;

  // track() after step 1's detection (track() sets the result's features
  // and features_ms).
  TrackResult track_detected(const TrackerFrame& frame, const std::vector<cv::KeyPoint>& keypoints,
                             const cv::Mat& descriptors, const Eigen::Isometry3d& T_W_C_prior);
  // Steps 1-4 against the keyframe, else the last tracked frame (which then
  // becomes the keyframe), else (guided_matching) about the caller's prior.
  TrackResult match(const TrackerFrame& frame, const std::vector<cv::KeyPoint>& keypoints,
                    const cv::Mat& descriptors, const Eigen::Isometry3d& T_W_C_prior);
  // Steps 1-4 against one keyframe (no state changes); guide false:
  // ratio-test matches only.
  TrackResult relative(const KeptKeyframe& kf, const TrackerFrame& frame,
                       const std::vector<cv::KeyPoint>& keypoints, const cv::Mat& descriptors,
                       bool guide = true) const;
  // Step 1's guided matching about a guess of the frame's pose relative to
  // kf, then steps 2-4 (not posed unless more than more_than matches).
  TrackResult by_projection(const KeptKeyframe& kf, const TrackerFrame& frame,
                            const std::vector<cv::KeyPoint>& keypoints, const cv::Mat& descriptors,
                            const Eigen::Isometry3d& T_C_K_guess, double radius_px,
                            std::size_t more_than) const;
  // Steps 2-4 from given matches (queryIdx: the frame's keypoints, trainIdx:
  // kf's features).
  TrackResult solve(const KeptKeyframe& kf, const TrackerFrame& frame,
                    const std::vector<cv::KeyPoint>& keypoints,
                    const std::vector<cv::DMatch>& matches) const;
  // Relocalising: the frame against the current and the kept keyframes.
  TrackResult relocalise(const TrackerFrame& frame, const std::vector<cv::KeyPoint>& keypoints,
                         const cv::Mat& descriptors, const Eigen::Isometry3d& T_W_C_prior);
  // Why a relocalisation candidate fails the checks (empty: it passes).
  std::string relocalisation_failure(const TrackResult& r) const;
  // The current keyframe changed to `k`: kept unless a kept one is near.
  void keep(const KeptKeyframe& k);
  // The optical-flow bridge from previous_ (posed unless too few tracks).
  TrackResult by_flow(const TrackerFrame& frame) const;
  // The state after a frame the bridge posed (f), which it returns.
  TrackResult posed_by_flow(const TrackerFrame& frame, const std::vector<cv::KeyPoint>& keypoints,
                            const cv::Mat& descriptors, TrackResult f);
  // A posed frame: the next frame's bridge starts from it (with flow_bridge).
  void remember(const TrackerFrame& frame, const TrackResult& r);

  KeyframeTrackerConfig config_;
  cv::Ptr<cv::ORB> orb_;  // made once: OpenCV's ORB defaults but the FAST threshold (theirs: 20)
  std::optional<Keyframe> keyframe_;
  // The last tracked frame as a keyframe would keep it: the next keyframe
  // when the current one goes out of sight.
  std::optional<Keyframe> last_;
  // The last frame the images posed (its own copies), where the bridge starts.
  struct Posed {
    TrackerFrame frame;
    Eigen::Isometry3d T_W_C = Eigen::Isometry3d::Identity();
    double scale = 1.0;
  };
  std::optional<Posed> previous_;
  double last_scale_ = 1.0;
  int lost_ = 0;  // untracked frames in a row
  int keyframes_ = 0;
  std::deque<KeptKeyframe> kept_;
  bool relocalising_ = false;
  std::size_t next_candidate_ = 0;  // the kept keyframes are tried in turn from here
};

}  // namespace long3r

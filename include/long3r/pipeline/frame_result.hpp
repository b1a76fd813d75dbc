// Everything the streaming pipeline produces for one frame, for the CLI, the
// ROS layer and logs.
//
// Frames: points_W in the world frame W (camera 0 of the stream); points_C in
// the camera optical frame of this frame (x right, y down, z forward),
// points_C = T_W_C^-1 points_W. All images are at model resolution. Lengths
// are in the stream's scale at the time of the result (`scale` metres per
// model unit; 1 = model units).
#pragma once

#include <opencv2/core/mat.hpp>

#include <cstddef>
#include <cstdint>
#include <optional>

#include "long3r/model/network/streaming.hpp"
#include "long3r/pipeline/intrinsics.hpp"
#include "long3r/pipeline/pose.hpp"
#include "long3r/tracking/baseline_scale.hpp"
#include "long3r/tracking/keyframe_tracker.hpp"

namespace long3r {

// Wall-clock time of the pipeline's stages, milliseconds (0 when a stage did
// not run). The model's own split (encode, decode, memory) is in
// FrameResult::model.
struct StageTimings {
  double preprocess_ms = 0.0;  // decode/convert, resize, crop, normalise
  double model_ms = 0.0;       // the whole model step (encode + decode + memory and overhead)
  double intrinsics_ms = 0.0;  // focal estimation (frame 0 without calibration)
  double pose_ms = 0.0;        // PnP-RANSAC + refinement, and the keyframe tracker
  double tracking_ms = 0.0;    // of it, the keyframe tracker (features, matches, solvers)
  double map_ms = 0.0;         // voxel map fusion (and eviction)
  double total_ms = 0.0;       // frame in to result out
};

struct FrameResult {
  std::int64_t frame_index = 0;   // 0-based within the stream
  double stamp = 0.0;             // seconds, the input image's time stamp
  bool from_coarse_head = false;  // the stream's last frame (flushed)

  cv::Mat points_W;  // CV_32FC3 [H, W], world frame
  cv::Mat points_C;  // CV_32FC3 [H, W], camera frame (empty when the pose failed)
  cv::Mat conf;      // CV_32FC1 [H, W], model confidence (>= 1)
  cv::Mat rgb;       // CV_8UC3 [H, W], RGB order: the model input's colours

  // T_W_C, PnP status, message, inliers, covariance. With a pose given to
  // push() (pose from odometry), T_W_C is that pose and the rest describes
  // the model's own PnP pose, model_T_W_C.
  PoseResult pose;
  Eigen::Isometry3d model_T_W_C = Eigen::Isometry3d::Identity();
  // T_W_C was given to push(): the frame is placed (in the path) even when
  // its PnP failed, though without points_C it is then not mapped.
  bool pose_given = false;
  // pose_method keyframes: what the keyframe tracker made of the frame. When
  // it posed it, T_W_C is its pose and points_C / points_W are in the
  // stream's scale by its Sim(3) (model_T_W_C stays the pointmap's pose);
  // otherwise the pointmap's pose stands. Empty without a tracker run.
  std::optional<TrackResult> tracking;
  // ReconstructionConfig::scale_from_given_poses, a frame placed by a given
  // pose: its sample of metres per model unit from the images (if any).
  std::optional<BaselineScaleResult> baseline_scale;
  // tracker motion_prior odometry: the camera's pose in the odometry frame
  // at this frame's stamp (metres), as the odometry source gave it.
  std::optional<Eigen::Isometry3d> T_O_C;
  bool posed() const { return pose.ok() || pose_given; }
  double scale = 1.0;
  PinholeIntrinsics intrinsics;  // at model resolution
  IntrinsicsSource intrinsics_source = IntrinsicsSource::kCalibration;
  bool added_to_map = false;   // false when PnP failed (or mapping is off)
  std::size_t map_points = 0;  // map size after this frame

  StageTimings timings;
  StepStats model;  // the model step as the model reports it: memory tokens, stage times
};

}  // namespace long3r

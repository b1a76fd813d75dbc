// Reading and validating the nodelet's ROS parameters.
//
// One function per config struct; each reads every field from the private
// node handle (through the struct's list of parameter names in params.cpp,
// which describe() uses too), falls back to the struct's default, validates,
// and throws ParamError naming the parameter when a value is out of range or
// of the wrong type, so a misconfigured launch fails at start-up with a clear
// message.
#pragma once

#include <ros/node_handle.h>

#include <stdexcept>
#include <string>

#include "long3r/model/inference_config.hpp"
#include "long3r/model/threads.hpp"
#include "long3r/pipeline/live_session.hpp"
#include "long3r/pipeline/metric_scale.hpp"
#include "long3r/pipeline/occupancy_grid.hpp"
#include "long3r/pipeline/reconstruction.hpp"
#include "long3r_ros/robot_frames.hpp"

namespace long3r_ros {

class ParamError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// Where the camera poses come from: PnP on LONG3R's pointmaps (the paper's
// way), or the robot's odometry in TF, which then places LONG3R's per-frame
// geometry (as voxblox and nvblox place depth).
enum class PoseSource { kModel, kOdometry };
inline const std::array<std::pair<PoseSource, const char*>, 2>& enum_names(PoseSource) {
  static const std::array<std::pair<PoseSource, const char*>, 2> names{
      {{PoseSource::kModel, "model"}, {PoseSource::kOdometry, "odometry"}}};
  return names;
}

// ROS-side settings: topics, input, queueing, timers, diagnostics.
struct NodeletConfig {
  std::string model_path;    // safetensors checkpoint; empty = package default
  std::string session_path;  // a saved session to continue at start; empty = none
  bool publish_tf = true;    // broadcast the one transform (robot_frames.hpp)
  PoseSource pose_source = PoseSource::kModel;
  bool use_camera_info = true;          // use camera_info intrinsics when published
  std::string image_transport = "raw";  // raw, compressed, ...
  int max_image_pixels = 4096 * 4096;   // larger frames are dropped
  int queue_size = 1;                   // bounded input queue; newest frame wins
  double flush_after_s = 1.0;           // publish the pending frame after this silence
  double map_publish_period_s = 1.0;    // republish the map (if changed) this often
  double map_display_voxel_m = 0.0;     // ~map downsampled to this voxel (PCL); 0 = the map's own
  double tf_publish_rate_hz = 20.0;     // map -> odom republished this often; 0 = with frames only
  double tf_delay_s = 0.0;              // map -> odom forward-dated by this (as rtabmap's tf_delay)
  // With a scale source: ~depth and ~frame_cloud wait for the metric scale
  // (false), or go out in model units meanwhile (true).
  bool publish_unscaled_depth = false;
  double no_input_warn_s = 5.0;  // diagnostics warn after this long without images
  double max_latency_s = 5.0;    // diagnostics: stamp delay beyond this is an error
};

NodeletConfig readNodeletConfig(const ros::NodeHandle& pnh);
// map_frame, odom_frame, base_frame, camera_frame, tf_timeout_s. The old name
// world_frame is read as map_frame.
FramesConfig readFramesConfig(const ros::NodeHandle& pnh);
long3r::StreamMonitorConfig readStreamMonitorConfig(const ros::NodeHandle& pnh);
// scale_source, scale, scale_min_baseline_m, ... (metric_scale.hpp).
long3r::MetricScaleConfig readMetricScaleConfig(const ros::NodeHandle& pnh);
// The two above, lost_reset_frames and image_is_rectified.
long3r::LiveSessionConfig readLiveSessionConfig(const ros::NodeHandle& pnh);
long3r::OccupancyGridConfig readOccupancyGridConfig(const ros::NodeHandle& pnh);
long3r::ThreadConfig readThreadConfig(const ros::NodeHandle& pnh);
long3r::InferenceConfig readInferenceConfig(const ros::NodeHandle& pnh);
long3r::ReconstructionConfig readReconstructionConfig(const ros::NodeHandle& pnh);

// One line per parameter, for the start-up log.
std::string describe(const NodeletConfig& config);
std::string describe(const FramesConfig& config);
std::string describe(const long3r::StreamMonitorConfig& config);
std::string describe(const long3r::LiveSessionConfig& config);
std::string describe(const long3r::MetricScaleConfig& config);
std::string describe(const long3r::OccupancyGridConfig& config);
std::string describe(const long3r::ThreadConfig& config);
std::string describe(const long3r::InferenceConfig& config);
std::string describe(const long3r::ReconstructionConfig& config);

}  // namespace long3r_ros

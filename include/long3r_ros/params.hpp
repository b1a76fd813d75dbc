// The nodelet's ROS parameters: every setting of every component, read from
// the private namespace through the components' own field lists
// (visit_fields beside each config struct), so that each parameter is named
// once. The flat ROS name of a field is the prefixes of the structs around it
// (NodeParams' list, then the struct's nested() ones) followed by its name:
// scale_min_samples is LiveSessionConfig's scale ("scale_"), field
// min_samples. A parameter left unset keeps the struct's default;
// config/default.yaml lists them all (a test checks it against the structs).
// A value of the wrong type, or out of range by a struct's validate(), throws
// ParamError naming the parameter, so a misconfigured launch fails at
// start-up with a clear message.
#pragma once

#include <ros/node_handle.h>

#include <stdexcept>
#include <string>
#include <vector>

#include "long3r/mapping/occupancy_map.hpp"
#include "long3r/model/runtime/inference_config.hpp"
#include "long3r/model/runtime/threads.hpp"
#include "long3r/pipeline/live_session.hpp"
#include "long3r/pipeline/metric_scale.hpp"
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
enum class PoseSource { kModel, kKeyframes, kOdometry };
inline const std::array<std::pair<PoseSource, const char*>, 3>& enum_names(PoseSource) {
  static const std::array<std::pair<PoseSource, const char*>, 3> names{
      {{PoseSource::kModel, "model"},
       {PoseSource::kKeyframes, "keyframes"},
       {PoseSource::kOdometry, "odometry"}}};
  return names;
}

// ROS-side settings: topics, input, queueing, timers, diagnostics.
struct NodeletConfig {
  std::string model_path;    // safetensors checkpoint; empty = package default
  std::string session_path;  // a saved session to continue at start; empty = none
  bool publish_tf = true;    // broadcast the one transform (robot_frames.hpp)
  PoseSource pose_source = PoseSource::kKeyframes;  // as ReconstructionConfig::pose_method
  bool use_camera_info = true;                      // use camera_info intrinsics when published
  std::string image_transport = "raw";              // raw, compressed, ...
  int max_image_pixels = 4096 * 4096;               // larger frames are dropped
  int queue_size = 1;                               // bounded input queue; newest frame wins
  double flush_after_s = 1.0;                       // publish the pending frame after this silence
  double map_publish_period_s = 1.0;                // republish the map (if changed) this often
  double map_display_voxel_m = 0.0;  // ~map downsampled to this voxel (PCL); 0 = the map's own
  // ~map without isolated points (PCL's StatisticalOutlierRemoval over this
  // many neighbours, beyond this many standard deviations); 0 = off.
  int map_display_outlier_neighbours = 0;
  double map_display_outlier_stddev = 1.0;
  // map -> odom published this often (rtabmap's tf_delay is its period,
  // 1 / rate); 0 = with frames only.
  double tf_publish_rate_hz = 20.0;
  // map -> odom forward-dated by this (rtabmap's tf_tolerance), for
  // consumers that look up slightly ahead of the odometry.
  double tf_tolerance_s = 0.0;
  // An image's camera_info: the one of its stamp, else the nearest within
  // this; none within it: the last calibration stands.
  double camera_info_max_dt_s = 0.1;
  // Outputs in model units where metres are meant (output_units.hpp): held
  // (false), or published in model units (true).
  bool publish_unscaled = false;
  double no_input_warn_s = 5.0;  // diagnostics warn after this long without images
  double max_latency_s = 5.0;    // diagnostics: stamp delay beyond this is an error

  // Throws long3r::ConfigError naming the field.
  void validate(const long3r::config::FieldCheck& check) const;
};

template <class S, class V>
long3r::config::FieldsOf<S, NodeletConfig> visit_fields(S& s, V& v) {
  v("model_path", s.model_path, "(package default)");
  v("session_path", s.session_path, "(none)");
  v("publish_tf", s.publish_tf);
  v("pose_source", s.pose_source);
  v("use_camera_info", s.use_camera_info);
  v("image_transport", s.image_transport);
  v("max_image_pixels", s.max_image_pixels);
  v("queue_size", s.queue_size);
  v("flush_after_s", s.flush_after_s);
  v("map_publish_period_s", s.map_publish_period_s);
  v("map_display_voxel_m", s.map_display_voxel_m, "(the map's voxels)");
  v("map_display_outlier_neighbours", s.map_display_outlier_neighbours, "(off)");
  v("map_display_outlier_stddev", s.map_display_outlier_stddev);
  v("tf_publish_rate_hz", s.tf_publish_rate_hz, "(with frames only)");
  v("tf_tolerance_s", s.tf_tolerance_s);
  v("camera_info_max_dt_s", s.camera_info_max_dt_s);
  v("publish_unscaled", s.publish_unscaled);
  v("no_input_warn_s", s.no_input_warn_s);
  v("max_latency_s", s.max_latency_s);
}

// Everything the nodelet reads.
struct NodeParams {
  NodeletConfig node;
  FramesConfig frames;
  long3r::LiveSessionConfig session;
  long3r::GridProjectionConfig grid;  // ~grid's band (the occupancy: reconstruction.occupancy)
  long3r::ThreadConfig threads;
  long3r::InferenceConfig inference;  // whether this machine serves it: at model load
  long3r::ReconstructionConfig reconstruction;

  void validate(const long3r::config::FieldCheck& check) const;
};

template <class S, class V>
long3r::config::FieldsOf<S, NodeParams> visit_fields(S& s, V& v) {
  v.nested("node", s.node, "");
  v.nested("frames", s.frames, "");
  v.nested("session", s.session, "");
  v.nested("grid", s.grid, "grid_");
  v.nested("threads", s.threads, "");
  v.nested("inference", s.inference, "");
  v.nested("reconstruction", s.reconstruction, "");
}

// Renamed parameters: the old name is still read (with a warning) when the
// new one is unset; both set differently is an error.
struct RenamedParam {
  const char* old_name;
  const char* name;
};
const std::vector<RenamedParam>& renamedParams();

NodeParams readParams(const ros::NodeHandle& pnh);

// What follows from other parameters, as readParams leaves it: map_frame
// empty -> map, or map_model_units with scale_source none; the pipeline's
// pose method from pose_source.
void resolveDefaults(NodeParams& params);

// One "name: value" line per parameter, for the start-up log.
std::string describe(const NodeParams& params);

// The flat names of all parameters, in list order.
std::vector<std::string> parameterNames();

// The parameters set in the private namespace that the nodelet does not
// read (typically typos), each with its full name.
std::vector<std::string> unknownParams(const ros::NodeHandle& pnh);

}  // namespace long3r_ros

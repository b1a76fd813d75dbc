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
#include "long3r/pipeline/reconstruction.hpp"

namespace long3r_ros {

class ParamError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// ROS-side settings: frames, topics, queueing, timers.
struct NodeletConfig {
  std::string model_path;               // safetensors checkpoint; empty = package default
  std::string world_frame = "map";      // fixed frame of the map and of T_W_C
  std::string camera_frame;             // empty = the image header's frame_id
  bool publish_tf = true;               // broadcast world_frame -> camera frame
  bool use_camera_info = true;          // use camera_info intrinsics when published
  std::string image_transport = "raw";  // raw, compressed, ...
  int queue_size = 1;                   // bounded input queue; newest frame wins
  double flush_after_s = 1.0;           // emit the pending last frame after this silence
  double map_publish_period_s = 1.0;    // republish the map (if changed) this often
};

NodeletConfig readNodeletConfig(const ros::NodeHandle& pnh);
long3r::ThreadConfig readThreadConfig(const ros::NodeHandle& pnh);
long3r::InferenceConfig readInferenceConfig(const ros::NodeHandle& pnh);
long3r::ReconstructionConfig readReconstructionConfig(const ros::NodeHandle& pnh);

// One line per parameter, for the start-up log.
std::string describe(const NodeletConfig& config);
std::string describe(const long3r::ThreadConfig& config);
std::string describe(const long3r::InferenceConfig& config);
std::string describe(const long3r::ReconstructionConfig& config);

}  // namespace long3r_ros

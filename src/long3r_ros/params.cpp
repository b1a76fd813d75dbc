#include "long3r_ros/params.hpp"

#include <cmath>
#include <sstream>
#include <type_traits>

#include "long3r/io/config_fields.hpp"

namespace long3r_ros {

namespace {

// The ROS parameter names of each config struct, listed once: reading and the
// start-up log both go through them. A third argument is what the log shows
// for an empty / zero value.
template <class S, class V>
long3r::config::FieldsOf<S, NodeletConfig> ros_fields(S& c, V& v) {
  v("model_path", c.model_path, "(package default)");
  v("session_path", c.session_path, "(none)");
  v("publish_tf", c.publish_tf);
  v("pose_source", c.pose_source);
  v("use_camera_info", c.use_camera_info);
  v("image_transport", c.image_transport);
  v("max_image_pixels", c.max_image_pixels);
  v("queue_size", c.queue_size);
  v("flush_after_s", c.flush_after_s);
  v("map_publish_period_s", c.map_publish_period_s);
  v("map_display_voxel_m", c.map_display_voxel_m, "(the map's voxels)");
  v("tf_publish_rate_hz", c.tf_publish_rate_hz, "(with frames only)");
  v("tf_delay_s", c.tf_delay_s);
  v("publish_unscaled_depth", c.publish_unscaled_depth);
  v("no_input_warn_s", c.no_input_warn_s);
  v("max_latency_s", c.max_latency_s);
}

template <class S, class V>
long3r::config::FieldsOf<S, FramesConfig> ros_fields(S& c, V& v) {
  v("map_frame", c.map_frame);
  v("odom_frame", c.odom_frame, "(none)");
  v("base_frame", c.base_frame, "(none)");
  v("camera_frame", c.camera_frame, "(from image header)");
  v("tf_timeout_s", c.tf_timeout_s);
  v("session_odometry_continues", c.session_odometry_continues);
}

template <class S, class V>
long3r::config::FieldsOf<S, long3r::MetricScaleConfig> ros_fields(S& c, V& v) {
  v("scale_source", c.source);
  v("scale", c.fixed_scale);
  v("scale_min_baseline_m", c.min_baseline_m);
  v("scale_min_samples", c.min_samples);
  v("scale_max_rel_stddev", c.max_rel_stddev);
  v("scale_freeze", c.freeze);
  v("scale_update_rel_change", c.update_rel_change);
}

template <class S, class V>
long3r::config::FieldsOf<S, long3r::StreamMonitorConfig> ros_fields(S& c, V& v) {
  v("max_backward_jump_s", c.max_backward_jump_s);
  v("max_stamp_jump_s", c.max_stamp_jump_s);
  v("size_change_frames", c.size_change_frames);
}

// The session's own fields; its stream and scale structs are read by theirs.
template <class S, class V>
long3r::config::FieldsOf<S, long3r::LiveSessionConfig> ros_fields(S& c, V& v) {
  v("image_is_rectified", c.image_is_rectified);
  v("lost_reset_frames", c.lost_reset_frames, "(no bound)");
  v("relocalise_for_s", c.relocalise_for_s, "(no bound)");
}

template <class S, class V>
long3r::config::FieldsOf<S, long3r::OccupancyGridConfig> ros_fields(S& c, V& v) {
  v("grid_resolution_m", c.resolution_m);
  v("grid_min_height_m", c.min_height_m);
  v("grid_max_height_m", c.max_height_m);
  v("grid_max_range_m", c.max_range_m);
  v("grid_min_points", c.min_points);
}

template <class S, class V>
long3r::config::FieldsOf<S, long3r::ThreadConfig> ros_fields(S& c, V& v) {
  v("torch_threads", c.torch_threads, "(all cores)");
  v("openblas_threads", c.openblas_threads);
  v("reuse_freed_memory", c.reuse_freed_memory);
}

template <class S, class V>
long3r::config::FieldsOf<S, long3r::InferenceConfig> ros_fields(S& c, V& v) {
  v("device", c.device);
  v("precision", c.precision);
  v("allow_emulated_precision", c.allow_emulated_precision);
  v("conv_precision", c.conv_precision);
}

// Flat parameter names for the nested pipeline settings. The one confidence
// threshold (conf_threshold) is copied to the map and PnP after reading.
template <class S, class V>
long3r::config::FieldsOf<S, long3r::ReconstructionConfig> ros_fields(S& c, V& v) {
  v("model_width", c.preprocess.width);
  v("model_height", c.preprocess.height);
  v("conf_threshold", c.conf_threshold);
  v("voxel_size_m", c.map.voxel_size_m);
  v("max_map_points", c.map.max_points);
  v("pnp_reprojection_error_px", c.pnp.reprojection_error_px);
  v("pnp_min_inliers", c.pnp.min_inliers);
  v("pnp_iterations", c.pnp.iterations);
  v("pnp_max_correspondences", c.pnp.max_correspondences);
}

// Reads each listed parameter that is set. A value of the wrong XML-RPC type
// is an error rather than a silent fallback to the default.
class RosReader {
 public:
  explicit RosReader(const ros::NodeHandle& pnh) : pnh_(pnh) {}

  template <class T>
  void operator()(const std::string& name, T& value, const char* /*empty_note*/ = nullptr) {
    if (pnh_.hasParam(name)) read(name, value);
  }

 private:
  template <class T>
  void read(const std::string& name, T& value) {
    if constexpr (std::is_enum<T>::value) {
      std::string text;
      read(name, text);
      if (!long3r::config::enum_from_name(text, &value)) {
        throw ParamError("parameter " + pnh_.resolveName(name) + " must be " +
                         long3r::config::enum_choices<T>() + ", got \"" + text + "\"");
      }
    } else if (!pnh_.getParam(name, value)) {
      throw ParamError("parameter " + pnh_.resolveName(name) + " has the wrong type");
    }
  }
  // Integers given as whole doubles (e.g. 2.0) are accepted; others are not.
  void read(const std::string& name, double& value) {
    int as_int = 0;
    if (pnh_.getParam(name, value)) return;
    if (pnh_.getParam(name, as_int)) {
      value = as_int;
      return;
    }
    throw ParamError("parameter " + pnh_.resolveName(name) + " must be a number");
  }
  void read(const std::string& name, float& value) {
    double d = value;
    read(name, d);
    value = static_cast<float>(d);
  }
  void read(const std::string& name, std::size_t& value) {
    int n = 0;
    read(name, n);
    if (n < 0) throw ParamError("parameter " + pnh_.resolveName(name) + " must be >= 1");
    value = static_cast<std::size_t>(n);
  }

  const ros::NodeHandle& pnh_;
};

// "name: value" lines.
class Describer {
 public:
  template <class T>
  void operator()(const std::string& name, const T& value, const char* empty_note = nullptr) {
    if (!first_) out_ << "\n";
    first_ = false;
    out_ << name << ": ";
    if constexpr (std::is_same<T, std::string>::value) {
      out_ << (value.empty() && empty_note ? empty_note : value);
    } else if constexpr (std::is_enum<T>::value) {
      out_ << long3r::config::enum_name(value);
    } else {
      out_ << std::boolalpha << value;
      if (empty_note && value == T{}) out_ << " " << empty_note;
    }
  }
  std::string str() const { return out_.str(); }

 private:
  std::ostringstream out_;
  bool first_ = true;
};

template <class T>
T read_all(const ros::NodeHandle& pnh) {
  T c;
  RosReader r(pnh);
  ros_fields(c, r);
  return c;
}

template <class T>
std::string describe_all(const T& c) {
  Describer d;
  ros_fields(c, d);
  return d.str();
}

void require(bool ok, const ros::NodeHandle& pnh, const std::string& name,
             const std::string& what) {
  if (!ok) throw ParamError("parameter " + pnh.resolveName(name) + " " + what);
}

}  // namespace

NodeletConfig readNodeletConfig(const ros::NodeHandle& pnh) {
  const NodeletConfig c = read_all<NodeletConfig>(pnh);
  require(!c.image_transport.empty(), pnh, "image_transport", "must not be empty");
  require(c.queue_size >= 1 && c.queue_size <= 1000, pnh, "queue_size", "must be in [1, 1000]");
  require(c.flush_after_s > 0.0, pnh, "flush_after_s", "must be > 0");
  require(c.map_publish_period_s > 0.0, pnh, "map_publish_period_s", "must be > 0");
  require(c.map_display_voxel_m >= 0.0 && std::isfinite(c.map_display_voxel_m), pnh,
          "map_display_voxel_m", "must be >= 0 (0 = the map's own voxels)");
  require(c.tf_publish_rate_hz >= 0.0 && c.tf_publish_rate_hz <= 1000.0, pnh, "tf_publish_rate_hz",
          "must be in [0, 1000] (0 = with frames only)");
  require(c.tf_delay_s >= 0.0 && c.tf_delay_s <= 10.0, pnh, "tf_delay_s", "must be in [0, 10]");
  require(c.max_image_pixels >= 16 * 16, pnh, "max_image_pixels", "must be >= 256");
  require(c.no_input_warn_s > 0.0, pnh, "no_input_warn_s", "must be > 0");
  require(c.max_latency_s > 0.0, pnh, "max_latency_s", "must be > 0");
  return c;
}

FramesConfig readFramesConfig(const ros::NodeHandle& pnh) {
  FramesConfig c = read_all<FramesConfig>(pnh);
  if (pnh.hasParam("world_frame")) {  // the name before map_frame
    std::string world;
    require(pnh.getParam("world_frame", world), pnh, "world_frame", "must be a string");
    require(!pnh.hasParam("map_frame") || world == c.map_frame, pnh, "world_frame",
            "is the old name of map_frame; set only map_frame");
    c.map_frame = world;
  }
  require(!c.map_frame.empty(), pnh, "map_frame", "must not be empty");
  const std::string names[] = {c.odom_frame, c.base_frame, c.camera_frame};
  for (const std::string& f : names) {
    require(f != c.map_frame, pnh, "map_frame",
            "must differ from odom_frame, base_frame and camera_frame");
  }
  require(c.odom_frame.empty() || !c.base_frame.empty(), pnh, "odom_frame",
          "needs base_frame (map -> odom -> base is what the node estimates)");
  require(c.odom_frame.empty() || c.odom_frame != c.base_frame, pnh, "odom_frame",
          "must differ from base_frame");
  require(c.tf_timeout_s >= 0.0 && c.tf_timeout_s <= 10.0, pnh, "tf_timeout_s",
          "must be in [0, 10]");
  return c;
}

long3r::MetricScaleConfig readMetricScaleConfig(const ros::NodeHandle& pnh) {
  const long3r::MetricScaleConfig c = read_all<long3r::MetricScaleConfig>(pnh);
  require(std::isfinite(c.fixed_scale) && c.fixed_scale > 0.0, pnh, "scale", "must be > 0");
  require(std::isfinite(c.min_baseline_m) && c.min_baseline_m > 0.0, pnh, "scale_min_baseline_m",
          "must be > 0");
  require(c.min_samples >= 1 && c.min_samples <= 500, pnh, "scale_min_samples",
          "must be in [1, 500]");
  require(c.max_rel_stddev > 0.0, pnh, "scale_max_rel_stddev", "must be > 0");
  require(c.update_rel_change >= 0.0, pnh, "scale_update_rel_change", "must be >= 0");
  return c;
}

long3r::StreamMonitorConfig readStreamMonitorConfig(const ros::NodeHandle& pnh) {
  const long3r::StreamMonitorConfig c = read_all<long3r::StreamMonitorConfig>(pnh);
  require(c.max_backward_jump_s >= 0.0, pnh, "max_backward_jump_s", "must be >= 0");
  require(c.max_stamp_jump_s > 0.0, pnh, "max_stamp_jump_s", "must be > 0");
  require(c.size_change_frames >= 1, pnh, "size_change_frames", "must be >= 1");
  return c;
}

long3r::LiveSessionConfig readLiveSessionConfig(const ros::NodeHandle& pnh) {
  long3r::LiveSessionConfig c = read_all<long3r::LiveSessionConfig>(pnh);
  try {
    c.validate({"parameter " + pnh.getNamespace(), ""});
  } catch (const long3r::ConfigError& e) {
    throw ParamError(e.what());
  }
  c.stream = readStreamMonitorConfig(pnh);
  c.scale = readMetricScaleConfig(pnh);
  return c;
}

long3r::OccupancyGridConfig readOccupancyGridConfig(const ros::NodeHandle& pnh) {
  const long3r::OccupancyGridConfig c = read_all<long3r::OccupancyGridConfig>(pnh);
  try {
    c.validate({"parameters " + pnh.getNamespace() + "/grid_*", ""});
  } catch (const long3r::ConfigError& e) {
    throw ParamError(e.what());
  }
  return c;
}

long3r::ThreadConfig readThreadConfig(const ros::NodeHandle& pnh) {
  const long3r::ThreadConfig c = read_all<long3r::ThreadConfig>(pnh);
  require(c.torch_threads >= 0 && c.torch_threads <= 256, pnh, "torch_threads",
          "must be in [0, 256] (0 = all cores)");
  require(
      c.openblas_threads >= long3r::ThreadConfig::kOpenblasThreadsAuto && c.openblas_threads <= 256,
      pnh, "openblas_threads",
      "must be -1 (by the OpenBLAS build), 0 (leave as the environment set it) or in [1, 256]");
  return c;
}

long3r::InferenceConfig readInferenceConfig(const ros::NodeHandle& pnh) {
  const long3r::InferenceConfig c = read_all<long3r::InferenceConfig>(pnh);
  // Whether this machine can serve it is checked when the model loads.
  require(long3r::is_device_name(c.device), pnh, "device",
          "must be cpu, cuda or cuda:N, got \"" + c.device + "\"");
  return c;
}

long3r::ReconstructionConfig readReconstructionConfig(const ros::NodeHandle& pnh) {
  long3r::ReconstructionConfig c = read_all<long3r::ReconstructionConfig>(pnh);
  auto multiple_of_16 = [](int v) { return v >= 16 && v <= 4096 && v % 16 == 0; };
  require(multiple_of_16(c.preprocess.width), pnh, "model_width",
          "must be a multiple of 16 in [16, 4096]");
  require(multiple_of_16(c.preprocess.height), pnh, "model_height",
          "must be a multiple of 16 in [16, 4096]");
  require(c.conf_threshold >= 1.0f, pnh, "conf_threshold",
          "must be >= 1 (the model's confidence starts at 1)");
  require(c.map.voxel_size_m > 0.0, pnh, "voxel_size_m", "must be > 0");
  require(c.map.max_points >= 1, pnh, "max_map_points", "must be >= 1");
  require(c.pnp.reprojection_error_px > 0.0, pnh, "pnp_reprojection_error_px", "must be > 0");
  require(c.pnp.min_inliers >= 4, pnh, "pnp_min_inliers", "must be >= 4");
  require(c.pnp.iterations >= 1, pnh, "pnp_iterations", "must be >= 1");
  require(c.pnp.max_correspondences >= c.pnp.min_inliers, pnh, "pnp_max_correspondences",
          "must be >= pnp_min_inliers");
  c.map.conf_threshold = c.conf_threshold;
  c.pnp.conf_threshold = c.conf_threshold;
  return c;
}

std::string describe(const NodeletConfig& c) { return describe_all(c); }
std::string describe(const FramesConfig& c) { return describe_all(c); }
std::string describe(const long3r::OccupancyGridConfig& c) { return describe_all(c); }
std::string describe(const long3r::MetricScaleConfig& c) { return describe_all(c); }
std::string describe(const long3r::StreamMonitorConfig& c) { return describe_all(c); }
std::string describe(const long3r::LiveSessionConfig& c) {
  return describe_all(c) + "\n" + describe_all(c.stream) + "\n" + describe_all(c.scale);
}
std::string describe(const long3r::ThreadConfig& c) { return describe_all(c); }
std::string describe(const long3r::InferenceConfig& c) { return describe_all(c); }
std::string describe(const long3r::ReconstructionConfig& c) { return describe_all(c); }

}  // namespace long3r_ros

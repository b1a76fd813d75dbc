#include "long3r_ros/params.hpp"

#include <ros/console.h>
#include <ros/param.h>

#include <algorithm>
#include <cmath>
#include <sstream>
#include <type_traits>

#include "long3r/config/config_fields.hpp"

namespace long3r_ros {

void NodeletConfig::validate(const long3r::config::FieldCheck& check) const {
  check.require(!image_transport.empty(), "image_transport", "must not be empty");
  check.require(queue_size >= 1 && queue_size <= 1000, "queue_size", "must be in [1, 1000]");
  check.require(flush_after_s > 0.0, "flush_after_s", "must be > 0");
  check.require(map_publish_period_s > 0.0, "map_publish_period_s", "must be > 0");
  check.require(map_display_voxel_m >= 0.0 && std::isfinite(map_display_voxel_m),
                "map_display_voxel_m", "must be >= 0 (0 = the map's own voxels)");
  check.require(map_display_outlier_neighbours >= 0 && map_display_outlier_neighbours <= 1000,
                "map_display_outlier_neighbours", "must be in [0, 1000] (0 = off)");
  check.require(map_display_outlier_stddev > 0.0 && std::isfinite(map_display_outlier_stddev),
                "map_display_outlier_stddev", "must be > 0");
  check.require(tf_publish_rate_hz >= 0.0 && tf_publish_rate_hz <= 1000.0, "tf_publish_rate_hz",
                "must be in [0, 1000] (0 = with frames only)");
  check.require(tf_tolerance_s >= 0.0 && tf_tolerance_s <= 10.0, "tf_tolerance_s",
                "must be in [0, 10]");
  check.require(camera_info_max_dt_s >= 0.0 && camera_info_max_dt_s <= 10.0, "camera_info_max_dt_s",
                "must be in [0, 10] (0 = the image's own stamp only)");
  check.require(max_image_pixels >= 16 * 16, "max_image_pixels", "must be >= 256");
  check.require(no_input_warn_s > 0.0, "no_input_warn_s", "must be > 0");
  check.require(max_latency_s > 0.0, "max_latency_s", "must be > 0");
}

void NodeParams::validate(const long3r::config::FieldCheck& check) const {
  long3r::config::validate_nested(*this, check);
  // pose_source, scale_source and tracker_motion_prior odometry read
  // map -> odom -> base.
  const bool robot_odometry = !frames.odom_frame.empty() && !frames.base_frame.empty();
  check.require(node.pose_source != PoseSource::kOdometry || robot_odometry, "pose_source",
                "odometry needs odom_frame and base_frame");
  check.require(session.scale.source != long3r::ScaleSource::kOdometry || robot_odometry,
                "scale_source", "odometry needs odom_frame and base_frame");
  check.require(node.pose_source != PoseSource::kKeyframes ||
                    reconstruction.tracker.motion_prior != long3r::MotionPrior::kOdometry ||
                    robot_odometry,
                "tracker_motion_prior", "odometry needs odom_frame and base_frame");
}

const std::vector<RenamedParam>& renamedParams() {
  // tf_delay_s: named after rtabmap's tf_delay, which is the publishing
  // period, while it forward-dates as rtabmap's tf_tolerance does.
  static const std::vector<RenamedParam> renamed{{"world_frame", "map_frame"},
                                                 {"scale", "scale_m_per_unit"},
                                                 {"tf_delay_s", "tf_tolerance_s"},
                                                 {"publish_unscaled_depth", "publish_unscaled"}};
  return renamed;
}

namespace {

const RenamedParam* renamedTo(const std::string& name) {
  for (const RenamedParam& r : renamedParams()) {
    if (name == r.name) return &r;
  }
  return nullptr;
}

// Reads each listed parameter that is set (or its old name). A value of the
// wrong XML-RPC type is an error rather than a silent fallback to the default.
class RosReader {
 public:
  explicit RosReader(const ros::NodeHandle& pnh) : pnh_(pnh) {}

  template <class T>
  void operator()(const std::string& full, T& value, const char* /*log_note*/) {
    if (pnh_.hasParam(full)) {
      read(full, value);
      if (const RenamedParam* r = renamedTo(full); r && pnh_.hasParam(r->old_name)) {
        T old = value;
        read(r->old_name, old);
        if (!(old == value)) {
          throw ParamError("parameter " + pnh_.resolveName(r->old_name) + " is the old name of " +
                           r->name + "; set only " + r->name);
        }
      }
    } else if (const RenamedParam* r = renamedTo(full); r && pnh_.hasParam(r->old_name)) {
      ROS_WARN("parameter %s is the old name of %s; read as that (rename it)",
               pnh_.resolveName(r->old_name).c_str(), r->name);
      read(r->old_name, value);
    }
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
    if (n < 0) throw ParamError("parameter " + pnh_.resolveName(name) + " must be >= 0");
    value = static_cast<std::size_t>(n);
  }

  const ros::NodeHandle& pnh_;
};

// "name: value" lines; a log note stands beside a zero or empty value.
class Describer {
 public:
  template <class T>
  void operator()(const std::string& name, const T& value, const char* log_note) {
    out_ << (out_.tellp() > 0 ? "\n" : "") << name << ": ";
    if constexpr (std::is_same<T, std::string>::value) {
      out_ << (value.empty() && log_note ? log_note : value);
    } else if constexpr (std::is_enum<T>::value) {
      out_ << long3r::config::enum_name(value);
    } else {
      out_ << std::boolalpha << value;
      if (log_note && value == T{}) out_ << " " << log_note;
    }
  }
  std::string str() const { return out_.str(); }

 private:
  std::ostringstream out_;
};

}  // namespace

NodeParams readParams(const ros::NodeHandle& pnh) {
  NodeParams p;
  RosReader reader(pnh);
  long3r::config::visit_flat(p, reader);
  resolveDefaults(p);
  try {
    p.validate({"parameter", pnh.getNamespace() + "/", true});
  } catch (const long3r::ConfigError& e) {
    throw ParamError(e.what());
  }
  return p;
}

void resolveDefaults(NodeParams& params) {
  // scale_source none: every length stays in model units, and the frame of
  // the map, path and poses says so unless the user named it.
  params.frames.resolveMapFrame(params.session.scale.source == long3r::ScaleSource::kNone);
  params.reconstruction.pose_method = params.node.pose_source == PoseSource::kKeyframes
                                          ? long3r::PoseMethod::kKeyframes
                                          : long3r::PoseMethod::kModel;
  // ~grid needs a z-up map (base_frame): without one the occupancy would be
  // kept for nothing.
  if (params.frames.base_frame.empty()) params.reconstruction.occupancy.enabled = false;
}

std::string describe(const NodeParams& params) {
  Describer d;
  long3r::config::visit_flat(params, d);
  return d.str();
}

std::vector<std::string> parameterNames() {
  std::vector<std::string> names;
  const NodeParams defaults;
  long3r::config::visit_flat(defaults, [&names](const std::string& name, const auto&, const char*) {
    names.push_back(name);
  });
  return names;
}

std::vector<std::string> unknownParams(const ros::NodeHandle& pnh) {
  std::vector<std::string> known = parameterNames();
  for (const RenamedParam& r : renamedParams()) known.push_back(r.old_name);
  std::vector<std::string> all;
  ros::param::getParamNames(all);
  const std::string ns = pnh.getNamespace() + "/";
  std::vector<std::string> unknown;
  for (const std::string& name : all) {
    if (name.compare(0, ns.size(), ns) != 0) continue;
    const std::string local = name.substr(ns.size());
    // Nested names (e.g. image_transport plugins' own) belong to others.
    if (local.find('/') != std::string::npos) continue;
    if (std::find(known.begin(), known.end(), local) == known.end()) unknown.push_back(name);
  }
  return unknown;
}

}  // namespace long3r_ros

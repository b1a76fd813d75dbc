#include "long3r_ros/robot_frames.hpp"

#include <tf2/exceptions.h>
#include <tf2_eigen/tf2_eigen.h>

#include <iterator>
#include <sstream>

#include "long3r_ros/log_throttle.hpp"

namespace long3r_ros {

void FramesConfig::validate(const long3r::config::FieldCheck& check) const {
  check.require(!map_frame.empty(), "map_frame", "must not be empty");
  for (const std::string* f : {&odom_frame, &base_frame, &camera_frame}) {
    check.require(*f != map_frame, "map_frame",
                  "must differ from odom_frame, base_frame and camera_frame");
  }
  check.require(odom_frame.empty() || !base_frame.empty(), "odom_frame",
                "needs base_frame (map -> odom -> base is what the node estimates)");
  check.require(odom_frame.empty() || odom_frame != base_frame, "odom_frame",
                "must differ from base_frame");
  check.require(tf_timeout_s >= 0.0 && tf_timeout_s <= 10.0, "tf_timeout_s", "must be in [0, 10]");
}

namespace {
constexpr double kTfPollS = 0.005;  // how often a lookup that waits asks TF again
}  // namespace

Eigen::Matrix3d bodyFromOptical() {
  // Columns: the optical axes in body axes (x right -> -y, y down -> -z, z forward -> x).
  Eigen::Matrix3d R;
  R << 0, 0, 1, -1, 0, 0, 0, -1, 0;
  return R;
}

Eigen::Isometry3d RobotFrames::lookup(const std::string& target, const std::string& source,
                                      const ros::Time& stamp) const {
  // The wait is wall time: tf2's own wait sleeps on ROS time, which stands
  // still while a replayed bag is paused or after it ends, and the worker
  // slept there for ever, even once the transform had arrived (a bag's last
  // frame and its odometry come together), with the frames behind it.
  auto unavailable = [&](const std::string& why) {
    return TfUnavailable("no transform " + target + " <- " + source +
                         atStamp(" at t=%.3f in TF (", stamp.toSec()) + why + ")");
  };
  const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(config_.tf_timeout_s);
  std::string error;
  while (!tf_.canTransform(target, source, stamp, &error)) {
    if (ros::WallTime::now() >= deadline) throw unavailable(error);
    error.clear();
    ros::WallDuration(kTfPollS).sleep();
  }
  try {
    return tf2::transformToEigen(tf_.lookupTransform(target, source, stamp));
  } catch (const tf2::TransformException& e) {
    throw unavailable(e.what());
  }
}

std::optional<std::string> RobotFrames::parentOf(const std::string& frame) const {
  std::string parent;
  // Latest data: the question is who owns the frame, not where it was.
  if (!tf_._getParent(frame, ros::Time(0), parent) || parent.empty() ||
      parent == config_.map_frame) {
    return std::nullopt;
  }
  return parent;
}

void RobotFrames::startStream(const std::string& image_frame, const ros::Time& stamp) {
  started_ = false;
  conflict_.clear();
  camera_frame_ = config_.camera_frame.empty() ? image_frame : config_.camera_frame;
  if (camera_frame_.empty()) {
    throw TfUnavailable("the image has no frame_id and ~camera_frame is empty");
  }
  if (!config_.base_frame.empty()) {
    T_body_cam_ = lookup(config_.base_frame, camera_frame_, stamp);
    if (!config_.odom_frame.empty()) {
      mode_ = Mode::kMapToOdom;
      published_child_ = config_.odom_frame;
      // map starts as odom: camera 0 sits where the odometry puts it.
      T_map_W_ = lookup(config_.odom_frame, config_.base_frame, stamp) * T_body_cam_;
      if (const auto p = parentOf(config_.odom_frame)) {
        conflict_ = config_.odom_frame + " already has the parent " + *p + "; publishing map -> " +
                    config_.odom_frame + " would give it a second one";
      }
    } else {
      mode_ = Mode::kMapToBase;
      published_child_ = config_.base_frame;
      T_map_W_ = T_body_cam_;  // map is the first frame's base pose
      if (const auto p = parentOf(config_.base_frame)) {
        conflict_ = config_.base_frame + " already has the parent " + *p +
                    "; set odom_frame:=" + *p + " to publish map -> " + *p + " instead";
      }
    }
  } else {
    T_body_cam_ = Eigen::Isometry3d::Identity();
    T_map_W_ = Eigen::Isometry3d::Identity();
    T_map_W_.linear() = bodyFromOptical();
    published_child_ = camera_frame_;
    mode_ = Mode::kMapToCamera;
    followRoot();
    if (mode_ == Mode::kMapToRoot) lookup(published_child_, camera_frame_, stamp);  // resolves now
  }
  extrinsics_.clear();
  extrinsics_[stamp] = T_body_cam_;
  T_map_odom_ = Eigen::Isometry3d::Identity();
  odom_anchored_ = true;
  if (continuing_) {  // the loaded session's map frame
    T_map_W_ = saved_T_map_W_;
    if (mode_ == Mode::kMapToOdom) {
      odom_anchored_ = config_.session_odometry_continues && saved_T_map_odom_;
      if (odom_anchored_) T_map_odom_ = *saved_T_map_odom_;
    }
    continuing_ = false;
  }
  started_ = true;
}

void RobotFrames::updateExtrinsics(const ros::Time& stamp) {
  if (config_.base_frame.empty()) return;
  const Eigen::Isometry3d T = lookup(config_.base_frame, camera_frame_, stamp);
  if (!T.isApprox(T_body_cam(stamp), 1e-9)) extrinsics_[stamp] = T;
}

Eigen::Isometry3d RobotFrames::T_body_cam(const ros::Time& stamp) const {
  const auto it = extrinsics_.upper_bound(stamp);
  if (it == extrinsics_.begin()) return it == extrinsics_.end() ? T_body_cam_ : it->second;
  return std::prev(it)->second;
}

void RobotFrames::continueSession(const Eigen::Isometry3d& T_map_W,
                                  const std::optional<Eigen::Isometry3d>& T_map_odom) {
  started_ = false;
  saved_T_map_W_ = T_map_W;
  saved_T_map_odom_ = T_map_odom;
  T_map_W_ = T_map_W;  // outputs of the loaded session (map, path) show in it at once
  continuing_ = true;
}

void RobotFrames::anchorOdometry(const Eigen::Isometry3d& T_W_C, const ros::Time& stamp) {
  T_map_odom_ = T_map_W_ * T_W_C * cameraInOdom(stamp).inverse();
  odom_anchored_ = true;
}

bool RobotFrames::followRoot() {
  if (mode_ != Mode::kMapToCamera && mode_ != Mode::kMapToRoot) return false;
  std::string root = camera_frame_;
  for (int depth = 0; depth < 64; ++depth) {  // a loop in TF must not hang us
    const auto p = parentOf(root);
    if (!p) break;
    root = *p;
  }
  if (root == published_child_) return false;
  published_child_ = root;
  mode_ = root == camera_frame_ ? Mode::kMapToCamera : Mode::kMapToRoot;
  return true;
}

Eigen::Isometry3d RobotFrames::cameraFromOdometry(const ros::Time& stamp) const {
  if (config_.odom_frame.empty() || config_.base_frame.empty()) {
    throw TfUnavailable("pose from odometry needs odom_frame and base_frame");
  }
  if (!odom_anchored_) {
    throw TfUnavailable(
        "map -> odom is not known yet in the loaded session (the first frame is "
        "placed by the model)");
  }
  return T_map_W_.inverse() * T_map_odom_ * cameraInOdom(stamp);
}

Eigen::Isometry3d RobotFrames::cameraInOdom(const ros::Time& stamp) const {
  return lookup(config_.odom_frame, config_.base_frame, stamp) * T_body_cam(stamp);
}

std::optional<geometry_msgs::TransformStamped> RobotFrames::transformFor(
    const Eigen::Isometry3d& T_W_C, const ros::Time& stamp) const {
  if (!conflict_.empty()) return std::nullopt;
  const Eigen::Isometry3d T_map_cam = T_map_W_ * T_W_C;
  Eigen::Isometry3d T_map_child;
  switch (mode_) {
    case Mode::kMapToOdom:
      T_map_child =
          bodyInMap(T_W_C, stamp) * lookup(config_.odom_frame, config_.base_frame, stamp).inverse();
      break;
    case Mode::kMapToBase:
      T_map_child = bodyInMap(T_W_C, stamp);
      break;
    case Mode::kMapToCamera:
      T_map_child = T_map_cam;
      break;
    case Mode::kMapToRoot:
      T_map_child = T_map_cam * lookup(published_child_, camera_frame_, stamp).inverse();
      break;
  }
  geometry_msgs::TransformStamped t = tf2::eigenToTransform(T_map_child);
  t.header.stamp = stamp;
  t.header.frame_id = config_.map_frame;
  t.child_frame_id = published_child_;
  return t;
}

std::string RobotFrames::describe() const {
  std::ostringstream s;
  switch (mode_) {
    case Mode::kMapToOdom:
      s << "publishing " << config_.map_frame << " -> " << config_.odom_frame << " (map -> odom -> "
        << config_.base_frame << " is LONG3R's pose; map starts as odom)";
      break;
    case Mode::kMapToBase:
      s << "publishing " << config_.map_frame << " -> " << config_.base_frame
        << " (map is the first frame's base pose)";
      break;
    case Mode::kMapToCamera:
      s << "publishing " << config_.map_frame << " -> " << camera_frame_
        << " (map is camera 0 turned to x forward, z up)";
      break;
    case Mode::kMapToRoot:
      s << "the camera frame " << camera_frame_ << " has a parent in TF: publishing "
        << config_.map_frame << " -> " << published_child_
        << ", the root of its tree (map is camera 0 turned to x forward, z up)";
      break;
  }
  if (!conflict_.empty()) s << "; NOT published: " << conflict_;
  return s.str();
}

}  // namespace long3r_ros

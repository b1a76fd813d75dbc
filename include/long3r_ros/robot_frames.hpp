// Where the reconstruction sits in the robot's TF tree (REP-105), and the one
// transform the node publishes for it.
//
// Frames: W is the pipeline's world, camera 0's optical frame of the stream;
// `map` (map_frame) is the fixed frame of every output. The node reads what
// it needs from TF (a tf2 buffer fed by a listener), at the image stamp with
// a bounded wait, and never gives an existing frame a second parent:
//
//   odom_frame and base_frame set  publishes map -> odom, so that
//       map -> odom -> base is the pose LONG3R estimates; map starts equal to
//       odom (T_map_odom = I at the first frame), so it is z-up as odom is;
//   base_frame set                 publishes map -> base; map is the first
//       frame's base pose (z-up when the base stands level);
//   neither                        publishes map -> camera frame when that
//       frame has no parent; when it has one (the camera driver or
//       robot_state_publisher gives it one), map -> the root of its tree.
//       map is camera 0 turned from optical (z forward, y down) to x forward,
//       y left, z up (REP-103).
//
// T_map_W is fixed per stream: T_map_cam(t) = T_map_W * T_W_C(t).
#pragma once

#include <geometry_msgs/TransformStamped.h>
#include <ros/time.h>
#include <tf2_ros/buffer.h>

#include <Eigen/Geometry>
#include <atomic>
#include <map>
#include <optional>
#include <stdexcept>
#include <string>

#include "long3r/config/config_fields.hpp"

namespace long3r_ros {

// map_frame's default names the unit of its lengths: metres (or held until
// they are metres) with a scale source, the model's own unit without one.
inline constexpr char kDefaultMapFrame[] = "map";
inline constexpr char kDefaultModelUnitsMapFrame[] = "map_model_units";

struct FramesConfig {
  // Empty: kDefaultMapFrame, or kDefaultModelUnitsMapFrame with scale_source
  // none (resolveMapFrame); the node always runs with it resolved.
  std::string map_frame;
  std::string odom_frame;     // empty: no odometry
  std::string base_frame;     // empty: no robot base
  std::string camera_frame;   // empty: the image header's frame_id
  double tf_timeout_s = 0.2;  // wait for a transform at an image stamp (wall time)
  // A loaded session's odometry: true = the odom frame it was saved with (a
  // bag replayed, a robot not restarted), map -> odom is kept; false = the
  // odometry started over, map -> odom follows from the first placed frame.
  bool session_odometry_continues = false;

  // An empty map_frame becomes its default for these units.
  void resolveMapFrame(bool lengths_in_model_units) {
    if (map_frame.empty()) {
      map_frame = lengths_in_model_units ? kDefaultModelUnitsMapFrame : kDefaultMapFrame;
    }
  }
  // Throws long3r::ConfigError naming the field (map_frame resolved first).
  void validate(const long3r::config::FieldCheck& check) const;
};

template <class S, class V>
long3r::config::FieldsOf<S, FramesConfig> visit_fields(S& s, V& v) {
  v("map_frame", s.map_frame, "(map; map_model_units with scale_source none)");
  v("odom_frame", s.odom_frame, "(none)");
  v("base_frame", s.base_frame, "(none)");
  v("camera_frame", s.camera_frame, "(from image header)");
  v("tf_timeout_s", s.tf_timeout_s);
  v("session_odometry_continues", s.session_odometry_continues);
}

// A transform the node needs is not (yet) in TF; says which and why.
class TfUnavailable : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

class RobotFrames {
 public:
  enum class Mode { kMapToOdom, kMapToBase, kMapToCamera, kMapToRoot };

  RobotFrames(const FramesConfig& config, const tf2_ros::Buffer& buffer)
      : config_(config), tf_(buffer) {}

  // The first frame of a stream: decides the mode and fixes T_map_W. Throws
  // TfUnavailable when a transform it needs is missing (the caller retries
  // with the next frame).
  void startStream(const std::string& camera_frame, const ros::Time& stamp);
  bool started() const { return started_; }
  // Without a base: whether the camera frame gained a parent since (its
  // static transform arrived late); then the root of its tree is published
  // from now on (T_map_W stays). Returns true when that changed.
  bool followRoot();
  void reset() {
    started_ = false;
    continuing_ = false;
  }
  // A loaded session: the next stream keeps the session's T_map_W (the map
  // frame it was saved in) instead of fixing a new one; in odom mode,
  // map -> odom is then unknown until anchorOdometry() (the robot's odometry
  // started over since), and cameraFromOdometry() waits for it.
  // T_map_odom: the session's map -> odom, kept when session_odometry_continues.
  void continueSession(const Eigen::Isometry3d& T_map_W,
                       const std::optional<Eigen::Isometry3d>& T_map_odom);
  const Eigen::Isometry3d& T_map_odom() const { return T_map_odom_; }
  // Whether T_map_W is known: a stream started or a session loaded.
  bool anchored() const { return started_ || continuing_; }
  // Whether map -> odom is known (always, but after a session load in odom
  // mode until anchorOdometry()).
  bool odometryAnchored() const { return odom_anchored_; }
  // map -> odom from a camera pose in W that the model estimated at `stamp`
  // (the first frame relocalised in a loaded session). Throws TfUnavailable.
  void anchorOdometry(const Eigen::Isometry3d& T_W_C, const ros::Time& stamp);

  const FramesConfig& config() const { return config_; }
  Mode mode() const { return mode_; }
  const std::string& cameraFrame() const { return camera_frame_; }
  // The frame ~pose, ~path and ~odometry describe: the base if set, else the camera.
  const std::string& bodyFrame() const {
    return config_.base_frame.empty() ? camera_frame_ : config_.base_frame;
  }
  // The child of the transform the node publishes.
  const std::string& publishedChild() const { return published_child_; }
  // One line for the log.
  std::string describe() const;

  const Eigen::Isometry3d& T_map_W() const { return T_map_W_; }
  // The camera's mounting on the base at `stamp`, looked up for every frame
  // (a pan-tilt camera moves; a static mount resolves from /tf_static at no
  // cost) and kept by stamp, when it changes, for that frame's result and the
  // path. Without a base: the identity. Throws TfUnavailable (the last one
  // known stays in use).
  void updateExtrinsics(const ros::Time& stamp);
  // T_body_cam of the frame at `stamp`: the last one known at or before it.
  Eigen::Isometry3d T_body_cam(const ros::Time& stamp) const;
  // The body pose in map for a camera pose in W at `stamp`.
  Eigen::Isometry3d bodyInMap(const Eigen::Isometry3d& T_W_C, const ros::Time& stamp) const {
    return T_map_W_ * T_W_C * T_body_cam(stamp).inverse();
  }
  // The camera pose in W from the odometry at `stamp` (pose_source odometry):
  // T_W_C = T_map_W^-1 * T_map_odom * T_odom_base(t) * T_base_cam (map
  // starts as odom, T_map_odom = I, except in a loaded session).
  // Needs odom and base frames. Throws TfUnavailable.
  Eigen::Isometry3d cameraFromOdometry(const ros::Time& stamp) const;
  // The camera pose in odom at `stamp` (for the odometry scale). Throws TfUnavailable.
  Eigen::Isometry3d cameraInOdom(const ros::Time& stamp) const;

  // The transform to publish for a camera pose in W at `stamp`; nullopt when
  // publishing would give a frame a second parent (conflict()). Throws
  // TfUnavailable (odometry or the root's transform missing at that stamp).
  std::optional<geometry_msgs::TransformStamped> transformFor(const Eigen::Isometry3d& T_W_C,
                                                              const ros::Time& stamp) const;
  // Why no transform is published ("" when one is), e.g. "base_link already
  // has the parent odom; set odom_frame to publish map -> odom".
  const std::string& conflict() const { return conflict_; }

 private:
  Eigen::Isometry3d lookup(const std::string& target, const std::string& source,
                           const ros::Time& stamp) const;
  // The frame's parent in TF other than map_frame, if any.
  std::optional<std::string> parentOf(const std::string& frame) const;

  FramesConfig config_;
  const tf2_ros::Buffer& tf_;
  std::atomic<bool> started_{false};  // reset() comes from the services' threads
  Mode mode_ = Mode::kMapToCamera;
  std::string camera_frame_, published_child_;
  Eigen::Isometry3d T_map_W_ = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d T_body_cam_ = Eigen::Isometry3d::Identity();  // at the stream's start
  std::map<ros::Time, Eigen::Isometry3d> extrinsics_;  // T_body_cam from each stamp it changed
  Eigen::Isometry3d T_map_odom_ = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d saved_T_map_W_ = Eigen::Isometry3d::Identity();
  std::optional<Eigen::Isometry3d> saved_T_map_odom_;
  std::atomic<bool> continuing_{false};  // continueSession() until the stream starts
  bool odom_anchored_ = true;
  std::string conflict_;
};

// Camera optical frame (x right, y down, z forward) to REP-103 body axes
// (x forward, y left, z up).
Eigen::Matrix3d bodyFromOptical();

}  // namespace long3r_ros

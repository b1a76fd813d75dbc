#include "long3r_ros/stream_placement.hpp"

#include <ros/console.h>

#include "long3r/pipeline/live_session.hpp"
#include "long3r/pipeline/pose.hpp"
#include "long3r_ros/log_throttle.hpp"

namespace long3r_ros {

namespace {

using Unavailable = long3r::LiveSessionClient::Unavailable;

}  // namespace

StreamPlacement::StreamPlacement(RobotFrames& frames, bool pose_from_odometry, std::string log_name,
                                 Warn warn)
    : frames_(frames),
      pose_from_odometry_(pose_from_odometry),
      log_name_(std::move(log_name)),
      warn_(std::move(warn)) {}

// Where the stream sits in the robot's TF tree, fixed by its first frame; with
// pose_source odometry, the frame's pose from the odometry.
std::optional<Eigen::Isometry3d> StreamPlacement::place(const std_msgs::Header& header) {
  const double t = header.stamp.toSec();
  try {
    if (!frames_.started()) {
      frames_.startStream(header.frame_id, header.stamp);
      ROS_INFO_NAMED(log_name_, "frames: %s", frames_.describe().c_str());
    } else if (frames_.followRoot()) {
      ROS_WARN_NAMED(log_name_, "frames: the camera frame gained a parent in TF: %s",
                     frames_.describe().c_str());
    }
  } catch (const TfUnavailable& e) {
    throw Unavailable("tf start", atStamp("frame at t=%.3f skipped: ", t) + e.what() +
                                      "; the stream starts once TF has it");
  }
  try {
    frames_.updateExtrinsics(header.stamp);  // a camera that moves on the base
  } catch (const TfUnavailable& e) {
    warn_("tf extrinsics", atStamp("frame at t=%.3f: the camera's mounting: ", t) + e.what() +
                               "; the last one known is used");
  }
  if (!pose_from_odometry_) return std::nullopt;
  if (!frames_.odometryAnchored()) {
    warn_("session odometry",
          atStamp("frame at t=%.3f placed by the model: in the loaded session, map -> "
                  "odom follows from the first frame the model places (pose_source "
                  "odometry resumes then)",
                  t));
    return std::nullopt;
  }
  try {
    return frames_.cameraFromOdometry(header.stamp);
  } catch (const TfUnavailable& e) {
    throw Unavailable("tf odometry",
                      atStamp("frame at t=%.3f skipped (pose_source odometry): ", t) + e.what());
  }
}

Eigen::Isometry3d StreamPlacement::cameraInOdom(const ros::Time& stamp) const {
  try {
    return frames_.cameraInOdom(stamp);
  } catch (const TfUnavailable& e) {
    throw Unavailable("tf odometry",
                      atStamp("the camera in odom at t=%.3f: ", stamp.toSec()) + e.what());
  }
}

void StreamPlacement::anchorOdometry(const Eigen::Isometry3d& T_W_C, const ros::Time& stamp) {
  if (frames_.odometryAnchored()) return;
  try {
    frames_.anchorOdometry(T_W_C, stamp);
    ROS_INFO_NAMED(log_name_,
                   "relocalised in the loaded session at t=%.3f: map -> %s follows from it",
                   stamp.toSec(), frames_.config().odom_frame.c_str());
  } catch (const TfUnavailable& e) {
    warn_("tf session", std::string("map -> odom not tied yet: ") + e.what());
  }
}

long3r::StateDict StreamPlacement::sessionState() const {
  long3r::StateDict state;
  if (frames_.anchored()) state["T_map_W"] = long3r::pose_to_tensor(frames_.T_map_W());
  if (frames_.started() && frames_.mode() == RobotFrames::Mode::kMapToOdom &&
      frames_.odometryAnchored()) {
    state["T_map_odom"] = long3r::pose_to_tensor(frames_.T_map_odom());
  }
  return state;
}

// The session's map frame, so that its map and path stay where they were;
// the robot's odometry is tied to it by the first placed frame.
void StreamPlacement::restoreSessionState(const long3r::StateDict& state) {
  auto pose = [&state](const char* key) -> std::optional<Eigen::Isometry3d> {
    const auto it = state.find(key);
    return it == state.end() ? std::nullopt : long3r::pose_from_tensor(it->second);
  };
  if (const std::optional<Eigen::Isometry3d> T_map_W = pose("T_map_W")) {
    frames_.continueSession(*T_map_W, pose("T_map_odom"));
  } else {
    ROS_WARN_NAMED(log_name_,
                   "the loaded session has no map frame of its own (saved by "
                   "long3r_reconstruct?): %s is fixed by the next frame, as for a new stream",
                   frames_.config().map_frame.c_str());
  }
}

}  // namespace long3r_ros

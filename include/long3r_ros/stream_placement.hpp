// StreamPlacement: the stream's place in the robot's TF tree as the core's
// LiveSession asks for it (LiveSessionClient::place and the calls beside
// it), answered from RobotFrames on the worker thread, session_mutex_ held:
//   - at a stream's first frame, where it starts (RobotFrames::startStream),
//     and later, a camera frame that gained a parent in TF;
//   - for every frame, the camera's mounting on the base at its stamp;
//   - with pose_source odometry, the frame's pose from the odometry; in a
//     loaded session from the first frame the model places, which ties
//     map -> odom (anchorOdometry());
//   - the camera in odom for the odometry scale and the tracker's odometry
//     motion prior;
//   - the map frame (T_map_W, map -> odom) saved with a session and restored.
// What TF cannot answer comes back as LiveSessionClient::Unavailable (the
// frame or the sample is skipped) or as a throttled warning (`warn`), naming
// the frame by its stamp. Frames: camera poses in W, the optical frame of
// the stream's frame 0.
#pragma once

#include <ros/time.h>
#include <std_msgs/Header.h>

#include <Eigen/Geometry>
#include <functional>
#include <optional>
#include <string>

#include "long3r/model/loading/state_dict.hpp"
#include "long3r_ros/log_throttle.hpp"
#include "long3r_ros/robot_frames.hpp"

namespace long3r_ros {

class StreamPlacement {
 public:
  // `log_name`: the nodelet's logger. pose_from_odometry: pose_source odometry.
  StreamPlacement(RobotFrames& frames, bool pose_from_odometry, std::string log_name, Warn warn);

  // The frame of `header` about to run: its pose in W from the odometry, or
  // nullopt for the model's own. Throws LiveSessionClient::Unavailable.
  std::optional<Eigen::Isometry3d> place(const std_msgs::Header& header);
  // The camera's pose in odom at `stamp` (scale_source odometry,
  // tracker_motion_prior odometry). Throws LiveSessionClient::Unavailable.
  Eigen::Isometry3d cameraInOdom(const ros::Time& stamp) const;
  // A pose the model estimated at `stamp`: while map -> odom is not tied
  // (a loaded session), the first one ties it. Nothing once it is.
  void anchorOdometry(const Eigen::Isometry3d& T_W_C, const ros::Time& stamp);

  // What a saved session keeps of the map frame: T_map_W (once known) and,
  // in odom mode, T_map_odom.
  long3r::StateDict sessionState() const;
  // After a load: the next stream continues in the session's map frame (a
  // warning when the file has none).
  void restoreSessionState(const long3r::StateDict& state);

 private:
  RobotFrames& frames_;
  const bool pose_from_odometry_;
  const std::string log_name_;
  Warn warn_;
};

}  // namespace long3r_ros

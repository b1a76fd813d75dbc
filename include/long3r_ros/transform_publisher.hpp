// TransformPublisher: the one transform the node publishes into the robot's
// TF tree (RobotFrames::transformFor: map -> odom, map -> base, or map -> the
// camera frame or the root of its tree). Every transform goes out through
// one path, send(), whose stamps only grow per child frame, so that a TF
// lookup anywhere in the latency window sees one history, never new, old,
// new.
//
// map -> odom, a slowly changing correction, is stamped at the time it is
// published (plus tf_tolerance_s), as SLAM nodes do (rtabmap's tf_tolerance):
// a lookup at an image's stamp sees the correction in force then, and
// map -> base resolves at the odometry's latest stamps (a stream's first
// one also at its image's stamp). A frame's correction is never stamped
// before the frame, so that map -> base resolves at every posed frame's
// stamp even where the clock lags the images (a replayed bag's last frame:
// its /clock ends before it). It is sent when a frame changes it and by
// a timer (tf_publish_rate_hz, on roscpp's callback
// thread; rtabmap's tf_delay is that period). map -> base and map -> camera
// (no odometry to correct) are stamped at their image's stamp, sent with
// each posed frame by the worker thread. Ours gives way while another node
// publishes the same transform (TfRivalWatch). Thread-safe: one lock, taken
// last.
#pragma once

#include <geometry_msgs/TransformStamped.h>
#include <ros/ros.h>
#include <tf2_ros/transform_broadcaster.h>

#include <Eigen/Geometry>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>

#include "long3r_ros/log_throttle.hpp"
#include "long3r_ros/robot_frames.hpp"
#include "long3r_ros/tf_rival_watch.hpp"

namespace long3r_ros {

class TransformPublisher {
 public:
  struct Config {
    bool publish_tf = true;    // false: nothing is published, nothing watched
    double rate_hz = 0.0;      // map -> odom published this often; 0 = with frames only
    double tolerance_s = 0.0;  // map -> odom forward-dated by this
  };

  // Watches for a rival and starts the timer on nh; `log_name`: the nodelet's logger.
  TransformPublisher(ros::NodeHandle& nh, const FramesConfig& frames, const Config& config,
                     const std::string& log_name, Warn warn);
  void shutdown();  // no callback runs after it returns

  // The transform for a camera pose in W at `stamp`; a throttled warning
  // when there is none to publish (a frame would get a second parent, or TF
  // misses a transform at that stamp).
  void publish(const RobotFrames& frames, const Eigen::Isometry3d& T_W_C, const ros::Time& stamp);
  // A new stream: map -> odom is not republished until its first posed frame.
  void forget();
  // For the diagnostics: who else publishes our transform; "" when no one.
  std::string rival() const;

 private:
  bool rivalPublishing() const;
  void timerCallback(const ros::TimerEvent& event);
  // The one way out; mutex_ held. Skips a stamp that is not after the last
  // one sent (equal stamps: TF_REPEATED_DATA in every listener).
  void send(geometry_msgs::TransformStamped t);
  // mutex_ held: map_to_odom_ stamped now (+ tolerance), and not before `not_before`.
  void sendMapToOdom(const ros::Time& not_before = ros::Time());

  const Config config_;
  Warn warn_;
  tf2_ros::TransformBroadcaster broadcaster_;
  // Another node publishing our transform: ours stops while it does.
  std::unique_ptr<TfRivalWatch> rival_;
  ros::Timer timer_;
  mutable std::mutex mutex_;
  std::optional<geometry_msgs::TransformStamped> map_to_odom_;
  ros::Time last_sent_;   // the stamp of the last transform sent
  ros::Time last_clock_;  // ros::Time::now() then
};

}  // namespace long3r_ros

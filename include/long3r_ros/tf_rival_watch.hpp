// TfRivalWatch: watches /tf and /tf_static for another node publishing the
// transform this node publishes (parent -> child: map -> odom, or map -> base
// without odometry), e.g. amcl or a second SLAM node. A frame with two
// publishers jumps between them; ours gives way while the other publishes
// (for good once it publishes statically), and the log (once per episode)
// and the diagnostics name it.
#pragma once

#include <ros/ros.h>
#include <tf2_msgs/TFMessage.h>

#include <atomic>
#include <mutex>
#include <string>

namespace long3r_ros {

class TfRivalWatch {
 public:
  // How long a rival's last message on /tf silences ours.
  static constexpr double kHoldS = 5.0;

  // Subscribes on nh; `log_name` is the nodelet's logger name.
  TfRivalWatch(ros::NodeHandle& nh, std::string parent, std::string child, std::string log_name);
  void shutdown();  // no callback runs after it returns

  // Another node publishes our transform now: ours must not.
  bool rivalPublishing() const;
  // What the diagnostics say while rivalPublishing(): who, and that ours stopped.
  std::string describe() const;

 private:
  void callback(const ros::MessageEvent<tf2_msgs::TFMessage const>& event, bool is_static);

  const std::string parent_, child_, log_name_;
  ros::Subscriber tf_sub_, tf_static_sub_;
  std::atomic<double> last_wall_s_{-1e9};
  std::atomic<bool> static_{false};
  mutable std::mutex mutex_;
  std::string what_;
};

}  // namespace long3r_ros

#include "long3r_ros/transform_publisher.hpp"

#include <algorithm>

#include "long3r_ros/log_throttle.hpp"

namespace long3r_ros {

TransformPublisher::TransformPublisher(ros::NodeHandle& nh, const FramesConfig& frames,
                                       const Config& config, const std::string& log_name, Warn warn)
    : config_(config), warn_(std::move(warn)) {
  if (config_.publish_tf && !(frames.odom_frame.empty() && frames.base_frame.empty())) {
    // The transform we publish: map -> odom, or map -> base without odometry.
    rival_ = std::make_unique<TfRivalWatch>(
        nh, frames.map_frame, frames.odom_frame.empty() ? frames.base_frame : frames.odom_frame,
        log_name);
  }
  if (config_.publish_tf && !frames.odom_frame.empty() && config_.rate_hz > 0.0) {
    timer_ = nh.createTimer(ros::Duration(1.0 / config_.rate_hz),
                            &TransformPublisher::timerCallback, this);
  }
}

void TransformPublisher::shutdown() {
  if (rival_) rival_->shutdown();
  timer_.stop();
}

bool TransformPublisher::rivalPublishing() const { return rival_ && rival_->rivalPublishing(); }

std::string TransformPublisher::rival() const { return rival_ ? rival_->describe() : ""; }

void TransformPublisher::publish(const RobotFrames& frames, const Eigen::Isometry3d& T_W_C,
                                 const ros::Time& stamp) {
  if (!config_.publish_tf) return;
  try {
    if (const auto t = frames.transformFor(T_W_C, stamp)) {
      std::lock_guard<std::mutex> lock(mutex_);
      if (frames.mode() == RobotFrames::Mode::kMapToOdom) {
        // A stream's first correction also at its image's stamp, so that
        // map -> base resolves at every posed frame's stamp.
        if (!map_to_odom_) send(*t);
        map_to_odom_ = *t;
        sendMapToOdom(stamp);  // now, not at the next tick
      } else {
        send(*t);
      }
    } else {
      warn_("tf conflict", "no TF published: " + frames.conflict());
    }
  } catch (const TfUnavailable& e) {
    warn_("tf publish", atStamp("no TF for the frame at t=%.3f: ", stamp.toSec()) + e.what());
  }
}

void TransformPublisher::forget() {
  std::lock_guard<std::mutex> lock(mutex_);
  map_to_odom_.reset();
}

void TransformPublisher::timerCallback(const ros::TimerEvent&) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (map_to_odom_) sendMapToOdom();
}

void TransformPublisher::sendMapToOdom(const ros::Time& not_before) {
  geometry_msgs::TransformStamped t = *map_to_odom_;
  t.header.stamp = std::max(ros::Time::now() + ros::Duration(config_.tolerance_s), not_before);
  send(t);
}

void TransformPublisher::send(geometry_msgs::TransformStamped t) {
  // A clock that went back (a looped bag on simulated time) starts the
  // history over, as tf2's listeners do.
  const ros::Time now = ros::Time::now();
  if (now < last_clock_) last_sent_ = ros::Time();
  last_clock_ = now;
  if (rivalPublishing() || t.header.stamp <= last_sent_) return;
  last_sent_ = t.header.stamp;
  broadcaster_.sendTransform(t);
}

}  // namespace long3r_ros

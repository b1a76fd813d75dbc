#include "long3r_ros/transform_publisher.hpp"

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
      if (!rivalPublishing()) broadcaster_.sendTransform(*t);
      if (frames.mode() == RobotFrames::Mode::kMapToOdom) {
        std::lock_guard<std::mutex> lock(mutex_);
        map_to_odom_ = *t;
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
  std::optional<geometry_msgs::TransformStamped> t;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    t = map_to_odom_;
  }
  if (!t || rivalPublishing()) return;
  // map -> odom is a slowly changing correction: kept valid at the current
  // time (and tf_delay_s ahead), so that map -> base resolves at the
  // odometry's latest stamps.
  t->header.stamp = ros::Time::now() + ros::Duration(config_.delay_s);
  broadcaster_.sendTransform(*t);
}

}  // namespace long3r_ros

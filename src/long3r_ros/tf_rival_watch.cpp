#include "long3r_ros/tf_rival_watch.hpp"

#include <boost/function.hpp>

namespace long3r_ros {

TfRivalWatch::TfRivalWatch(ros::NodeHandle& nh, std::string parent, std::string child,
                           std::string log_name)
    : parent_(std::move(parent)), child_(std::move(child)), log_name_(std::move(log_name)) {
  using Event = ros::MessageEvent<tf2_msgs::TFMessage const>;
  tf_sub_ = nh.subscribe<tf2_msgs::TFMessage>(
      "/tf", 100,
      boost::function<void(const Event&)>([this](const Event& e) { callback(e, false); }));
  tf_static_sub_ = nh.subscribe<tf2_msgs::TFMessage>(
      "/tf_static", 100,
      boost::function<void(const Event&)>([this](const Event& e) { callback(e, true); }));
}

void TfRivalWatch::shutdown() {
  tf_sub_.shutdown();
  tf_static_sub_.shutdown();
}

bool TfRivalWatch::rivalPublishing() const {
  return static_ || ros::WallTime::now().toSec() - last_wall_s_ < kHoldS;
}

std::string TfRivalWatch::describe() const {
  if (!rivalPublishing()) return "";
  std::lock_guard<std::mutex> lock(mutex_);
  return what_;
}

void TfRivalWatch::callback(const ros::MessageEvent<tf2_msgs::TFMessage const>& event,
                            bool is_static) {
  const std::string& publisher = event.getPublisherName();
  if (publisher == ros::this_node::getName()) return;
  for (const geometry_msgs::TransformStamped& t : event.getMessage()->transforms) {
    if (t.child_frame_id != child_ || t.header.frame_id != parent_) continue;
    const bool news = !rivalPublishing();
    const std::string what = parent_ + " -> " + child_ + " is also published by " + publisher +
                             (is_static ? " (static)" : "") +
                             ": ours stopped while it is, so that the frame has one publisher";
    {
      // Named before it counts: the diagnostics never see a nameless rival.
      std::lock_guard<std::mutex> lock(mutex_);
      what_ = what;
    }
    last_wall_s_ = ros::WallTime::now().toSec();
    if (is_static) static_ = true;
    if (news) ROS_ERROR_NAMED(log_name_, "%s", what.c_str());
    return;
  }
}

}  // namespace long3r_ros

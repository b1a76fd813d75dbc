#include "long3r_ros/image_subscriber.hpp"

#include <algorithm>
#include <vector>

namespace long3r_ros {

namespace {

// roscpp's own queue for the image topic. The callback only enqueues, but its
// thread can be held up (a loaded machine, the manager's other nodelets);
// frames that overflow here are lost without a trace, while the node's own
// queue (queue_size) drops them counted. So this one is generous.
constexpr std::uint32_t kSubscriberQueue = 30;

}  // namespace

ImageSubscriber::ImageSubscriber(ros::NodeHandle& nh, ros::NodeHandle& pnh,
                                 const std::string& transport, const std::string& log_name,
                                 Callback callback)
    : callback_(std::move(callback)) {
  it_ = std::make_unique<image_transport::ImageTransport>(nh);
  const std::vector<std::string> loadable = it_->getLoadableTransports();
  const bool installed =
      std::find(loadable.begin(), loadable.end(), "image_transport/" + transport) != loadable.end();
  if (!installed && transport == "compressed") {
    // Debian packages no compressed plugin: take the messages it would decode.
    const std::string topic = nh.resolveName("image") + "/compressed";
    compressed_sub_ =
        nh.subscribe(topic, kSubscriberQueue, &ImageSubscriber::compressedCallback, this);
    ROS_INFO_NAMED(log_name,
                   "subscribed to %s (sensor_msgs/CompressedImage, decoded by the node: the "
                   "compressed image_transport plugin is not installed)",
                   compressed_sub_.getTopic().c_str());
    return;
  }
  if (!installed) {
    std::string names;
    for (const std::string& l : loadable) names += (names.empty() ? "" : ", ") + l;
    throw TransportMissing("image_transport '" + transport +
                           "' is not installed (installed: " + names + ")");
  }
  image_sub_ =
      it_->subscribe("image", kSubscriberQueue, &ImageSubscriber::imageCallback, this,
                     image_transport::TransportHints(transport, ros::TransportHints(), pnh));
  ROS_INFO_NAMED(log_name, "subscribed to %s (transport %s)", image_sub_.getTopic().c_str(),
                 transport.c_str());
}

void ImageSubscriber::shutdown() {
  image_sub_.shutdown();
  compressed_sub_.shutdown();
}

void ImageSubscriber::imageCallback(const sensor_msgs::ImageConstPtr& msg) {
  callback_(InputFrame{msg, nullptr, ros::Time::now()});
}

void ImageSubscriber::compressedCallback(const sensor_msgs::CompressedImageConstPtr& msg) {
  callback_(InputFrame{nullptr, msg, ros::Time::now()});
}

}  // namespace long3r_ros

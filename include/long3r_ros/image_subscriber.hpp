// ImageSubscriber: the node's image input. Subscribes to `image` through
// image_transport with the transport asked for (~image_transport, hints from
// the private namespace) or, where that is `compressed` and its plugin is not
// installed (Debian packages none), to `image/compressed` as
// sensor_msgs/CompressedImage, which the worker decodes (image_input.hpp).
//
// Each message is handed on as an InputFrame stamped with the clock of its
// arrival. The callback runs on roscpp's callback threads and must only
// enqueue. Frames: the image's own (its header); nothing is transformed here.
#pragma once

#include <image_transport/image_transport.h>
#include <ros/ros.h>
#include <sensor_msgs/CompressedImage.h>
#include <sensor_msgs/Image.h>

#include <functional>
#include <memory>
#include <stdexcept>
#include <string>

#include "long3r_ros/image_input.hpp"

namespace long3r_ros {

// The image_transport asked for is not installed; the message names the
// ones that are.
class TransportMissing : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

class ImageSubscriber {
 public:
  using Callback = std::function<void(InputFrame frame)>;

  // Subscribes on nh and logs the topic under `log_name` (the nodelet's
  // logger). Throws TransportMissing.
  ImageSubscriber(ros::NodeHandle& nh, ros::NodeHandle& pnh, const std::string& transport,
                  const std::string& log_name, Callback callback);
  void shutdown();  // no callback runs after it returns

 private:
  void imageCallback(const sensor_msgs::ImageConstPtr& msg);
  void compressedCallback(const sensor_msgs::CompressedImageConstPtr& msg);

  const Callback callback_;
  std::unique_ptr<image_transport::ImageTransport> it_;
  image_transport::Subscriber image_sub_;
  ros::Subscriber compressed_sub_;
};

}  // namespace long3r_ros

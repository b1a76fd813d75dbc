#include "long3r_ros/long3r_nodelet.hpp"

#include <cv_bridge/cv_bridge.h>
#include <sensor_msgs/image_encodings.h>
#include <pluginlib/class_list_macros.hpp>

#include <chrono>

namespace long3r_ros {

namespace {
bool supportedEncoding(const std::string& enc) {
  namespace e = sensor_msgs::image_encodings;
  return enc == e::RGB8 || enc == e::BGR8 || enc == e::RGBA8 || enc == e::BGRA8 ||
         enc == e::MONO8 || enc == e::MONO16;
}
}  // namespace

Long3rNodelet::~Long3rNodelet() { shutdown(); }

void Long3rNodelet::onInit() {
  ros::NodeHandle& nh = getNodeHandle();
  ros::NodeHandle& pnh = getPrivateNodeHandle();
  try {
    config_ = readNodeletConfig(pnh);
    thread_config_ = readThreadConfig(pnh);
  } catch (const ParamError& e) {
    NODELET_FATAL("invalid configuration: %s", e.what());
    throw;
  }
  NODELET_INFO_STREAM("configuration:\n" << describe(config_) << "\n" << describe(thread_config_));

  queue_ = std::make_unique<long3r::BoundedQueue<sensor_msgs::ImageConstPtr>>(
      static_cast<std::size_t>(config_.queue_size));
  running_ = true;
  worker_ = std::thread(&Long3rNodelet::workerLoop, this);

  it_ = std::make_unique<image_transport::ImageTransport>(nh);
  image_sub_ = it_->subscribe(
      "image", 5, &Long3rNodelet::imageCallback, this,
      image_transport::TransportHints(config_.image_transport, ros::TransportHints(), pnh));
  NODELET_INFO("subscribed to %s (transport %s)", image_sub_.getTopic().c_str(),
               config_.image_transport.c_str());
}

void Long3rNodelet::imageCallback(const sensor_msgs::ImageConstPtr& msg) {
  // Only enqueue: the worker does all conversion and model work.
  if (queue_->push(msg)) {
    NODELET_WARN_THROTTLE(5.0, "input queue full (size %zu): dropped %lu frame(s) so far",
                          queue_->capacity(), static_cast<unsigned long>(queue_->dropped()));
  }
}

void Long3rNodelet::workerLoop() {
  const int threads = long3r::apply_thread_config(thread_config_);
  NODELET_DEBUG("worker thread started with %d torch thread(s)", threads);
  while (running_) {
    auto msg = queue_->pop(std::chrono::milliseconds(100));
    if (!msg) continue;
    try {
      processFrame(*msg);
    } catch (const std::exception& e) {
      // Bad input or a failure in one frame must never take the node down.
      NODELET_ERROR_THROTTLE(5.0, "frame at t=%.3f skipped: %s", (*msg)->header.stamp.toSec(),
                             e.what());
    }
  }
}

void Long3rNodelet::processFrame(const sensor_msgs::ImageConstPtr& msg) {
  if (!supportedEncoding(msg->encoding)) {
    NODELET_ERROR_THROTTLE(5.0,
                           "unsupported image encoding '%s' (supported: rgb8, bgr8, rgba8, "
                           "bgra8, mono8, mono16); frame skipped",
                           msg->encoding.c_str());
    return;
  }
  cv_bridge::CvImageConstPtr image = cv_bridge::toCvShare(msg);
  if (image->image.empty()) throw std::runtime_error("empty image");
  ++frames_processed_;
}

void Long3rNodelet::shutdown() {
  if (!running_.exchange(false)) return;
  image_sub_.shutdown();
  if (queue_) queue_->close();
  if (worker_.joinable()) worker_.join();
}

}  // namespace long3r_ros

PLUGINLIB_EXPORT_CLASS(long3r_ros::Long3rNodelet, nodelet::Nodelet)

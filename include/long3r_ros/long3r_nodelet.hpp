// Long3rNodelet: the ROS front door of long3r_ros.
//
// Subscribes to `image` (image_transport), queues frames in a bounded queue
// (callbacks only enqueue) and processes them on one worker thread, so ROS
// callbacks never block on the model. Frames: images arrive in the camera
// optical frame (the header's frame_id unless `camera_frame` overrides it);
// the map and poses T_W_C live in `world_frame`.
#pragma once

#include <image_transport/image_transport.h>
#include <nodelet/nodelet.h>
#include <sensor_msgs/Image.h>

#include <atomic>
#include <memory>
#include <thread>

#include "long3r/bounded_queue.hpp"
#include "long3r_ros/params.hpp"

namespace long3r_ros {

class Long3rNodelet : public nodelet::Nodelet {
 public:
  Long3rNodelet() = default;
  ~Long3rNodelet() override;

 private:
  void onInit() override;
  void imageCallback(const sensor_msgs::ImageConstPtr& msg);
  void workerLoop();
  void processFrame(const sensor_msgs::ImageConstPtr& msg);
  void shutdown();

  NodeletConfig config_;
  long3r::ThreadConfig thread_config_;

  std::unique_ptr<image_transport::ImageTransport> it_;
  image_transport::Subscriber image_sub_;

  std::unique_ptr<long3r::BoundedQueue<sensor_msgs::ImageConstPtr>> queue_;
  std::thread worker_;
  std::atomic<bool> running_{false};
  std::uint64_t frames_processed_ = 0;  // worker thread only
};

}  // namespace long3r_ros

// Long3rNodelet: the ROS front door of long3r_ros.
//
// Subscribes to `image` (image_transport) and optionally `camera_info`,
// queues frames in a bounded queue (callbacks only enqueue) and runs the core
// long3r::Reconstruction on one worker thread, so ROS callbacks never block on
// the model. Frames: `points_C` and `~frame_cloud` are in the camera optical
// frame (the image header's frame_id unless `camera_frame` overrides it); the
// map, `~pose`, `~path` and TF T_W_C live in `world_frame` (= camera 0 of the
// current stream).
#pragma once

#include <diagnostic_updater/diagnostic_updater.h>
#include <image_transport/image_transport.h>
#include <nodelet/nodelet.h>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <std_srvs/Trigger.h>
#include <tf2_ros/transform_broadcaster.h>

#include <nav_msgs/Path.h>
#include <atomic>
#include <deque>
#include <memory>
#include <mutex>
#include <optional>
#include <thread>

#include "long3r/pipeline/bounded_queue.hpp"
#include "long3r/pipeline/reconstruction.hpp"
#include "long3r_ros/SaveMap.h"
#include "long3r_ros/params.hpp"
#include "long3r_ros/stream_monitor.hpp"

namespace long3r_ros {

class Long3rNodelet : public nodelet::Nodelet {
 public:
  Long3rNodelet() = default;
  ~Long3rNodelet() override;

 private:
  void onInit() override;
  void imageCallback(const sensor_msgs::ImageConstPtr& msg);
  void cameraInfoCallback(const sensor_msgs::CameraInfoConstPtr& msg);
  bool resetService(std_srvs::Trigger::Request& req, std_srvs::Trigger::Response& res);
  bool saveMapService(SaveMap::Request& req, SaveMap::Response& res);
  void mapTimerCallback(const ros::WallTimerEvent& event);
  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& stat);

  void workerLoop();
  void processFrame(const sensor_msgs::ImageConstPtr& msg);
  void flushPending();
  void publishResult(const long3r::FrameResult& result);
  void resetStream(const std::string& why);  // recon_mutex_ held
  void shutdown();

  NodeletConfig config_;
  long3r::ThreadConfig thread_config_;
  long3r::InferenceConfig inference_config_;
  long3r::ReconstructionConfig recon_config_;

  std::unique_ptr<image_transport::ImageTransport> it_;
  image_transport::Subscriber image_sub_;
  ros::Subscriber camera_info_sub_;
  ros::Publisher frame_cloud_pub_, pointmap_pub_, map_pub_, pose_pub_, path_pub_, camera_info_pub_;
  ros::ServiceServer reset_srv_, save_map_srv_;
  ros::WallTimer map_timer_;
  tf2_ros::TransformBroadcaster tf_broadcaster_;
  std::unique_ptr<diagnostic_updater::Updater> diagnostics_;

  // The reconstruction and everything tied to its stream, guarded together:
  // the worker pushes frames, the services reset and save.
  std::mutex recon_mutex_;
  std::unique_ptr<long3r::Reconstruction> recon_;
  std::deque<std_msgs::Header> pending_headers_;  // headers of frames awaiting their result
  nav_msgs::Path path_;
  StreamMonitor monitor_{0.0};

  std::mutex camera_info_mutex_;
  std::optional<long3r::PinholeIntrinsics> calibration_;  // source resolution, from camera_info

  std::unique_ptr<long3r::BoundedQueue<sensor_msgs::ImageConstPtr>> queue_;
  std::thread worker_;
  std::atomic<bool> running_{false};
  std::uint64_t last_map_revision_ = 0;

  // Statistics for diagnostics (atomics: written by callbacks and worker).
  std::atomic<std::uint64_t> frames_received_{0}, frames_processed_{0}, frames_failed_{0};
  std::atomic<double> last_latency_s_{0.0};
  std::atomic<std::int64_t> mem_short_{0}, mem_long_{0}, mem_relevant_{-1};
  ros::WallTime stats_since_;
};

}  // namespace long3r_ros

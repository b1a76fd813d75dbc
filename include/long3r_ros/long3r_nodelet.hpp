// Long3rNodelet: the ROS front door of long3r_ros.
//
// Subscribes to `image` (image_transport; or sensor_msgs/CompressedImage on
// `image/compressed`, decoded here, where the compressed plugin is missing),
// `camera_info` and, for the depth scale, `depth`; callbacks only enqueue.
// One worker thread decodes each frame, pairs it with the camera_info of its
// stamp and hands it to the core's long3r::LiveSession, which holds the
// policy (stream continuity, calibration and rectification, tracking loss,
// metric scale; live_session.hpp) and calls back here for what only ROS
// knows (TF, depth images) and with each result to publish. Frames
// (robot_frames.hpp): `~pointmap`, `~depth`, `~frame_cloud` are in the camera
// optical frame (the image header's frame_id unless `camera_frame` overrides
// it); the map, `~pose`, `~path`, `~odometry` in `map_frame`, the last three
// for the body (base_frame, else the camera); the node publishes one
// transform per frame into the robot's TF tree. Lengths are in metres once a
// metric scale is in use (metric_scale.hpp), else in model units.
//
// The map and the memory are what the user builds: a pause of any length
// continues the stream (the pending frame is published after
// `flush_after_s`), odd single messages are dropped with a warning naming the
// problem, and only `~reset` or a condition named in a warning (time jumping
// far back, a lasting size change, `lost_reset_frames`) starts a new stream.
#pragma once

#include <diagnostic_updater/diagnostic_updater.h>
#include <diagnostic_updater/publisher.h>
#include <image_transport/image_transport.h>
#include <nav_msgs/Odometry.h>
#include <nav_msgs/Path.h>
#include <nodelet/nodelet.h>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/CompressedImage.h>
#include <sensor_msgs/Image.h>
#include <std_srvs/Trigger.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/transform_broadcaster.h>
#include <tf2_ros/transform_listener.h>

#include <atomic>
#include <deque>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>

#include "long3r/pipeline/bounded_queue.hpp"
#include "long3r/pipeline/live_session.hpp"
#include "long3r_ros/LoadSession.h"
#include "long3r_ros/SaveMap.h"
#include "long3r_ros/SaveSession.h"
#include "long3r_ros/SaveTrajectory.h"
#include "long3r_ros/frame_publisher.hpp"
#include "long3r_ros/image_input.hpp"
#include "long3r_ros/log_throttle.hpp"
#include "long3r_ros/map_publisher.hpp"
#include "long3r_ros/node_status.hpp"
#include "long3r_ros/params.hpp"
#include "long3r_ros/robot_frames.hpp"
#include "long3r_ros/stamped_inputs.hpp"
#include "long3r_ros/tf_rival_watch.hpp"
#include "long3r_ros/window_stats.hpp"

namespace long3r_ros {

class Long3rNodelet : public nodelet::Nodelet, private long3r::LiveSessionClient {
 public:
  Long3rNodelet() = default;
  ~Long3rNodelet() override;

 private:
  void onInit() override;
  void loadModel();
  void advertise();
  void loadStartSession();  // ~session_path
  void subscribe();

  // Callbacks: they only enqueue (or count a frame dropped while paused).
  void imageCallback(const sensor_msgs::ImageConstPtr& msg);
  void compressedCallback(const sensor_msgs::CompressedImageConstPtr& msg);
  void enqueue(InputFrame frame);
  void tfTimerCallback(const ros::TimerEvent& event);

  bool resetService(std_srvs::Trigger::Request& req, std_srvs::Trigger::Response& res);
  bool pauseService(std_srvs::Trigger::Request& req, std_srvs::Trigger::Response& res);
  bool resumeService(std_srvs::Trigger::Request& req, std_srvs::Trigger::Response& res);
  bool saveMapService(SaveMap::Request& req, SaveMap::Response& res);
  bool saveSessionService(SaveSession::Request& req, SaveSession::Response& res);
  bool loadSessionService(LoadSession::Request& req, LoadSession::Response& res);
  bool saveTrajectoryService(SaveTrajectory::Request& req, SaveTrajectory::Response& res);
  void mapTimerCallback(const ros::WallTimerEvent& event);
  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& stat);

  // Worker thread; session_mutex_ is held around every call into the session,
  // and so around the LiveSessionClient calls it makes back.
  void workerLoop();
  void handleFrame(const InputFrame& frame);
  void flushPending();
  void copyStatus();  // session_mutex_ held

  // long3r::LiveSessionClient: what the session asks of ROS, and its results.
  std::optional<Eigen::Isometry3d> place(const long3r::LiveFrame& frame) override;
  Eigen::Vector3d odometry_camera_position_m(const long3r::LiveResult& result) override;
  cv::Mat depth(const long3r::LiveResult& result) override;
  void on_result(long3r::LiveResult& result) override;
  std::optional<Eigen::Isometry3d> T_map_W() override;
  void on_new_stream(const std::string& why) override;
  long3r::StateDict session_state() override;
  void restore_session_state(const long3r::StateDict& state) override;
  void on_event(const long3r::LiveEvent& event) override;

  void publishOutputs(const long3r::FrameResult& r, const std_msgs::Header& header);
  nav_msgs::Path pathMessage();  // session_mutex_ held
  void shutdown();

  // A warning per kind of problem, throttled per kind (LogThrottle).
  void warnThrottled(const std::string& kind, const std::string& message);

  NodeParams params_;

  std::unique_ptr<image_transport::ImageTransport> it_;
  image_transport::Subscriber image_sub_;
  ros::Subscriber compressed_sub_;
  std::unique_ptr<StampedInputs> stamped_;  // camera_info, depth, odometry by stamp
  std::unique_ptr<FramePublisher> frame_pub_;
  std::unique_ptr<MapPublisher> map_pub_;
  ros::Publisher path_pub_;
  ros::ServiceServer reset_srv_, pause_srv_, resume_srv_, save_map_srv_, save_trajectory_srv_;
  ros::ServiceServer save_session_srv_, load_session_srv_;
  ros::WallTimer map_timer_;
  ros::Timer tf_timer_;  // republishes map -> odom (odometry mode), as SLAM nodes do
  // Another node publishing our transform: ours stops while it does.
  std::unique_ptr<TfRivalWatch> tf_rival_;
  bool rivalPublishing() const;
  tf2_ros::TransformBroadcaster tf_broadcaster_;
  tf2_ros::Buffer tf_buffer_;
  std::unique_ptr<tf2_ros::TransformListener> tf_listener_;
  std::unique_ptr<diagnostic_updater::Updater> diagnostics_;
  // Output rate and stamp delay of ~pointmap over a sliding window (library tasks).
  double min_rate_hz_ = 0.0, max_rate_hz_ = 0.0;
  std::unique_ptr<diagnostic_updater::TopicDiagnostic> output_diagnostic_;

  // The session and what is tied to its stream, guarded together: the worker
  // pushes frames, the services reset and save.
  std::mutex session_mutex_;
  std::unique_ptr<long3r::LiveSession> session_;
  std::unique_ptr<RobotFrames> frames_;
  // The map in map, the ended streams' included (LiveSession::ended_maps():
  // without odom_frame each stream's map frame starts at its own first
  // frame, so those are not registered to the current one). Locks itself.
  long3r::MapSnapshot mapSnapshot();

  std::unique_ptr<long3r::BoundedQueue<InputFrame>> queue_;
  std::thread worker_;
  std::atomic<bool> running_{false};
  std::atomic<bool> paused_{false};

  // Statistics for diagnostics (written by callbacks and worker).
  WindowStats window_;
  LogThrottle throttle_{5.0};
  std::atomic<std::uint64_t> frames_received_{0}, frames_processed_{0}, frames_failed_{0};
  std::atomic<std::uint64_t> frames_dropped_paused_{0}, frames_dropped_input_{0};
  std::atomic<double> last_input_wall_s_{0.0};  // wall clock of the newest image; 0 = none yet
  // What the timers and diagnostics read, one snapshot under one lock, so
  // that they never wait for session_mutex_ (held for a whole model step).
  struct State {
    long3r::LiveStatus session;
    std::string frames = "not started";
    Eigen::Isometry3d T_map_W = Eigen::Isometry3d::Identity();
    std::optional<geometry_msgs::TransformStamped> map_to_odom;
    std::string session_file = "none";  // the last session saved or loaded, for diagnostics
    // Camera positions of the path in map (for ~grid).
    std::vector<Eigen::Vector3d> cameras_map;
    std::string grid = "not subscribed";
  };
  std::mutex state_mutex_;
  State state_;
  ros::WallTime started_;
};

}  // namespace long3r_ros

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
//
// The nodelet wires its helpers together and holds no policy of its own:
// ImageSubscriber (image input), StampedInputs (camera_info, depth, odometry
// by stamp), StreamPlacement and RobotFrames (the TF tree), FramePublisher,
// MapPublisher and TransformPublisher (outputs), SessionServices (services)
// and NodeDiagnostics (counters, throttled warnings, /diagnostics).
#pragma once

#include <nav_msgs/Path.h>
#include <nodelet/nodelet.h>
#include <ros/ros.h>
#include <std_msgs/Header.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/transform_listener.h>

#include <atomic>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "long3r/pipeline/bounded_queue.hpp"
#include "long3r/pipeline/live_session.hpp"
#include "long3r_ros/frame_publisher.hpp"
#include "long3r_ros/image_input.hpp"
#include "long3r_ros/image_subscriber.hpp"
#include "long3r_ros/log_throttle.hpp"
#include "long3r_ros/map_publisher.hpp"
#include "long3r_ros/node_status.hpp"
#include "long3r_ros/output_units.hpp"
#include "long3r_ros/params.hpp"
#include "long3r_ros/robot_frames.hpp"
#include "long3r_ros/session_services.hpp"
#include "long3r_ros/stamped_inputs.hpp"
#include "long3r_ros/stream_placement.hpp"
#include "long3r_ros/transform_publisher.hpp"

namespace long3r_ros {

class Long3rNodelet : public nodelet::Nodelet,
                      private long3r::LiveSessionClient,
                      private SessionServices::Node {
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
  void enqueue(InputFrame frame);
  void mapTimerCallback(const ros::WallTimerEvent& event);
  void fillStatus(NodeStatus& status);  // the node's part of the diagnostics
  // The helpers' warnings, throttled per kind (NodeDiagnostics::warn).
  Warn warner();

  // Worker thread; session_mutex_ is held around every call into the session,
  // and so around the LiveSessionClient calls it makes back.
  void workerLoop();
  void handleFrame(const InputFrame& frame);
  void flushPending();
  void copyStatus();  // session_mutex_ held

  // long3r::LiveSessionClient: what the session asks of ROS, and its results.
  std::optional<Eigen::Isometry3d> place(const long3r::LiveFrame& frame) override;
  Eigen::Isometry3d odometry_camera_m(const std::any& tag) override;
  cv::Mat depth(const std::any& tag) override;
  void on_result(long3r::LiveResult& result) override;
  std::optional<Eigen::Isometry3d> T_map_W() override;
  void on_new_stream(const std::string& why) override;
  long3r::StateDict session_state() override;
  void restore_session_state(const long3r::StateDict& state) override;
  void on_event(const long3r::LiveEvent& event) override;

  // SessionServices::Node: the services' way into the session.
  void readSession(const SessionServices::Reader& f) override;
  void changeSession(const SessionServices::Changer& f) override;
  void sessionFileChanged(const std::string& what) override;
  void clearQueue() override;
  bool setPaused(bool paused) override;
  std::uint64_t pausedDrops() const override;
  // The map in map, the ended streams' included (LiveSession::ended_maps():
  // without odom_frame each stream's map frame starts at its own first
  // frame, so those are not registered to the current one). Locks itself.
  long3r::MapSnapshot mapSnapshot() override;
  long3r::ColoredMesh surfaceMesh() override;

  void publishOutputs(const long3r::FrameResult& r, const std_msgs::Header& header);
  // What is held, not in metres (output_units.hpp), under the node's settings.
  OutputUnits outputUnits(bool scale_metric, bool pose_given) const;
  std::string heldWhy(const OutputUnits& units) const;
  nav_msgs::Path pathMessage();  // session_mutex_ held
  void shutdown();

  NodeParams params_;
  // Counters, throttled warnings and /diagnostics; everything else reports
  // through it, so it goes last.
  std::unique_ptr<NodeDiagnostics> diagnostics_;

  std::unique_ptr<ImageSubscriber> images_;
  std::unique_ptr<StampedInputs> stamped_;  // camera_info, depth, odometry by stamp
  std::unique_ptr<FramePublisher> frame_pub_;
  std::unique_ptr<MapPublisher> map_pub_;
  ros::Publisher path_pub_;
  std::unique_ptr<SessionServices> services_;
  ros::WallTimer map_timer_;
  std::unique_ptr<TransformPublisher> tf_pub_;  // the one transform into the robot's TF tree
  tf2_ros::Buffer tf_buffer_;
  std::unique_ptr<tf2_ros::TransformListener> tf_listener_;

  // The session and what is tied to its stream, guarded together: the worker
  // pushes frames, the services reset and save.
  std::mutex session_mutex_;
  std::unique_ptr<long3r::LiveSession> session_;
  std::unique_ptr<RobotFrames> frames_;
  std::unique_ptr<StreamPlacement> placement_;  // frames_ as the session asks for them

  std::unique_ptr<long3r::BoundedQueue<InputFrame>> queue_;
  std::thread worker_;
  std::atomic<bool> running_{false};
  std::atomic<bool> paused_{false};

  // What the timers and diagnostics read, one snapshot under one lock, so
  // that they never wait for session_mutex_ (held for a whole model step).
  // Taken inside session_mutex_, never the other way round.
  struct State {
    long3r::LiveStatus session;
    std::string frames = "not started";
    Eigen::Isometry3d T_map_W = Eigen::Isometry3d::Identity();
    std::string session_file = "none";  // the last session saved or loaded, for diagnostics
    std::string grid = "not subscribed";
  };
  std::mutex state_mutex_;
  State state_;
};

}  // namespace long3r_ros

// The node's diagnostics (diagnostic_updater's "reconstruction" task): one
// summary level and message chosen by precedence (a rival TF publisher, a
// pause, no input, lost tracking, a map held for the scale, a refused
// calibration, dropped or failed frames), then every figure, from one
// snapshot of the node's state taken under one lock.
//
// NodeDiagnostics holds what they count and publishes them: the frame
// counters (totals and WindowStats' window), the time of the last image, the
// node's throttled warnings (LogThrottle) and the diagnostic_updater tasks,
// "reconstruction" and "pointmap" (rate and stamp delay of ~pointmap).
// Counters are written by roscpp's callback threads and the worker
// (atomics); update() runs on the map timer's thread and asks the node for
// its part of the status (Fill), which must not wait for the model step.
#pragma once

#include <diagnostic_updater/DiagnosticStatusWrapper.h>
#include <diagnostic_updater/diagnostic_updater.h>
#include <diagnostic_updater/publisher.h>
#include <ros/ros.h>

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>

#include "long3r/pipeline/live_session.hpp"
#include "long3r_ros/log_throttle.hpp"
#include "long3r_ros/window_stats.hpp"

namespace long3r_ros {

struct NodeStatus {
  long3r::LiveStatus session;
  long3r::ScaleSource scale_source = long3r::ScaleSource::kNone;
  bool pose_from_odometry = false;  // pose_source odometry
  bool publish_unscaled = false;
  WindowStats::Counts window;  // the last diagnostics period's
  double quiet_s = 0.0;        // since the last image (or the start)
  bool input_seen = false;
  double no_input_warn_s = 5.0;
  bool paused = false;
  std::string frames = "not started";  // RobotFrames::describe()
  std::string session_file = "none";   // the last session saved or loaded
  std::string grid = "not subscribed";
  std::string tf_rival;  // the node also publishing our transform; empty: none
  std::size_t map_points = 0, ended_map_points = 0;
  std::uint64_t received = 0, processed = 0, failed = 0;  // totals
  std::uint64_t dropped_input = 0, dropped_queue = 0, dropped_paused = 0;
};

void fillDiagnostics(const NodeStatus& s, diagnostic_updater::DiagnosticStatusWrapper& stat);

class NodeDiagnostics {
 public:
  struct Config {
    double no_input_warn_s = 5.0;  // warn after this long without images
    double max_latency_s = 5.0;    // a ~pointmap stamp delay beyond this is an error
    long3r::ScaleSource scale_source = long3r::ScaleSource::kNone;
    bool pose_from_odometry = false;
    bool publish_unscaled = false;
  };
  // The node's part of a report: its state snapshot, the TF rival, the
  // pause, the map's size, the queue's drops.
  using Fill = std::function<void(NodeStatus& status)>;

  // `log_name`: the nodelet's name (its logger, the updater's node name).
  NodeDiagnostics(const Config& config, std::string log_name);
  // Starts the updater on nh / pnh (/diagnostics).
  void advertise(ros::NodeHandle& nh, ros::NodeHandle& pnh, Fill fill);
  // The quiet time before the first image counts from now.
  void start();
  void update();    // publishes the tasks every diagnostic_period of wall time (the map timer)
  void shutdown();  // the updater goes; counting and warnings go on

  // A warning per kind of problem, throttled per kind (LogThrottle).
  void warn(const std::string& kind, const std::string& message);

  // What happened to a frame.
  void received();                         // an image arrived
  void droppedPaused();                    // it arrived while paused
  void droppedQueue();                     // it overflowed the queue (the queue counts the total)
  void badInput();                         // it did not decode
  void droppedInput();                     // the session dropped it (LiveEvent::frame_dropped)
  void failed();                           // it, or the pending frame, failed in the session
  void processed(const ros::Time& stamp);  // its result was published
  std::uint64_t pausedDrops() const { return dropped_paused_; }

 private:
  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& stat);

  const Config config_;
  const std::string log_name_;
  Fill fill_;
  std::unique_ptr<diagnostic_updater::Updater> updater_;
  double last_report_wall_s_ = 0.0;  // update(): the map timer's thread only
  // Output rate and stamp delay of ~pointmap over a sliding window (library tasks).
  double min_rate_hz_ = 0.0, max_rate_hz_ = 0.0;
  std::unique_ptr<diagnostic_updater::TopicDiagnostic> output_diagnostic_;

  WindowStats window_;
  LogThrottle throttle_{5.0};
  std::atomic<std::uint64_t> received_{0}, processed_{0}, failed_{0};
  std::atomic<std::uint64_t> dropped_paused_{0}, dropped_input_{0};
  std::atomic<double> last_input_wall_s_{0.0};  // wall clock of the newest image; 0 = none yet
  std::atomic<double> started_wall_s_{0.0};
};

}  // namespace long3r_ros

// The node's diagnostics (diagnostic_updater's "reconstruction" task): one
// summary level and message chosen by precedence (a rival TF publisher, a
// pause, no input, lost tracking, a map held for the scale, a refused
// calibration, dropped or failed frames), then every figure, from one
// snapshot of the node's state taken under one lock.
#pragma once

#include <diagnostic_updater/DiagnosticStatusWrapper.h>

#include <cstddef>
#include <cstdint>
#include <string>

#include "long3r/pipeline/live_session.hpp"
#include "long3r_ros/window_stats.hpp"

namespace long3r_ros {

struct NodeStatus {
  long3r::LiveStatus session;
  long3r::ScaleSource scale_source = long3r::ScaleSource::kNone;
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

}  // namespace long3r_ros

// The node's diagnostics from a status snapshot: the summary's precedence and
// the figures it reports.
#include <diagnostic_msgs/DiagnosticStatus.h>
#include <gtest/gtest.h>

#include <string>

#include "long3r_ros/node_status.hpp"
#include "long3r_ros/output_units.hpp"

using long3r_ros::fillDiagnostics;
using long3r_ros::NodeStatus;
using S = diagnostic_msgs::DiagnosticStatus;

namespace {

diagnostic_updater::DiagnosticStatusWrapper diagnose(const NodeStatus& n) {
  diagnostic_updater::DiagnosticStatusWrapper stat;
  fillDiagnostics(n, stat);
  return stat;
}

std::string value(const diagnostic_updater::DiagnosticStatusWrapper& stat, const std::string& key) {
  for (const auto& kv : stat.values) {
    if (kv.key == key) return kv.value;
  }
  return "(missing)";
}

}  // namespace

TEST(NodeStatus, SummaryTakesTheMostUrgentCondition) {
  NodeStatus n;
  n.input_seen = true;
  EXPECT_EQ(diagnose(n).level, S::OK);
  EXPECT_EQ(diagnose(n).message, "running, in model units (scale_source none)");
  n.scale_source = long3r::ScaleSource::kDepth;
  n.session.scale_metric = true;
  EXPECT_EQ(diagnose(n).message, "running");
  n.window.dropped = 2;
  EXPECT_EQ(diagnose(n).message, "dropped 2 and failed 0 frame(s) in the window");
  n.session.calibration_refused = true;
  n.session.calibration = "camera_info refused: K is zero";
  EXPECT_EQ(diagnose(n).message, "camera_info refused: K is zero");
  // The scale pending: what is held says so, with the samples so far.
  n.session.scale_metric = false;
  n.session.scale_estimate.samples = 3;
  EXPECT_EQ(diagnose(n).level, S::WARN);
  EXPECT_EQ(diagnose(n).message,
            "held until the metric scale is known (scale_source depth, 3 samples so far): TF, "
            "~pose, ~odometry, ~pose_with_covariance, ~path, ~depth, ~frame_cloud, ~map, ~grid");
  n.pose_from_odometry = true;  // the odometry's poses are metres already
  EXPECT_EQ(diagnose(n).message,
            "held until the metric scale is known (scale_source depth, 3 samples so far): "
            "~depth, ~frame_cloud, ~map, ~grid");
  n.publish_unscaled = true;
  EXPECT_EQ(diagnose(n).message,
            "publishing in model units until the metric scale is known (scale_source depth, 3 "
            "samples so far): publish_unscaled");
  EXPECT_EQ(value(diagnose(n), "units"),
            "model units until the metric scale is known (publish_unscaled)");
  n.session.lost_frames = 4;
  n.session.lost_for_s = 1.5;
  EXPECT_EQ(diagnose(n).message, "tracking lost for 4 frame(s) (1.5 s)");
  EXPECT_EQ(diagnose(n).level, S::WARN);
  n.quiet_s = 12.0;
  EXPECT_EQ(diagnose(n).message, "no input for 12 s");
  n.input_seen = false;
  EXPECT_EQ(diagnose(n).message, "no image received in 12 s");
  n.paused = true;  // a pause is asked for: not a fault
  EXPECT_EQ(diagnose(n).level, S::OK);
  EXPECT_EQ(diagnose(n).message, "paused (~resume to continue)");
  n.tf_rival = "map -> odom is also published by /amcl";
  EXPECT_EQ(diagnose(n).level, S::ERROR);
  EXPECT_EQ(diagnose(n).message, "map -> odom is also published by /amcl");
  EXPECT_EQ(value(diagnose(n), "tf"), "map -> odom is also published by /amcl");
}

TEST(NodeStatus, FiguresAreReported) {
  NodeStatus n;
  n.scale_source = long3r::ScaleSource::kOdometry;
  n.session.scale = 0.5;
  n.session.scale_metric = true;
  n.map_points = 1234;
  n.dropped_queue = 7;
  n.grid = "20 x 30 cells, 5 occupied, 100 free";
  n.window.processed = 2;
  n.window.latency_sum_s = 0.3;
  n.window.latency_min_s = 0.1;
  n.window.latency_max_s = 0.2;
  n.session.keyframe_tracked = 40;
  n.session.keyframe_untracked = 3;
  n.session.keyframe_flow = 5;
  n.session.keyframe_lost = 2;
  const auto stat = diagnose(n);
  EXPECT_EQ(value(stat, "frames tracked by keyframes (total)"), "40");
  EXPECT_EQ(value(stat, "of them followed by optical flow (total)"), "5");
  EXPECT_EQ(value(stat, "frames not tracked: placed by the motion prior (total)"), "3");
  EXPECT_EQ(value(stat, "frames that lost the keyframes: relocalising (total)"), "2");
  EXPECT_EQ(value(stat, "scale source"), "odometry");
  EXPECT_EQ(value(stat, "scale in use (m per model unit)"), "0.5");
  EXPECT_EQ(value(stat, "scale metric"), "True");
  EXPECT_EQ(value(stat, "map points"), "1234");
  EXPECT_EQ(value(stat, "frames dropped: queue full or cleared (total)"), "7");
  EXPECT_EQ(value(stat, "grid"), "20 x 30 cells, 5 occupied, 100 free");
  EXPECT_EQ(value(stat, "latency min / mean / max (s)"), "0.100 / 0.150 / 0.200");
  EXPECT_EQ(value(stat, "tf"), "publishing");
}

TEST(OutputUnits, MetresOrHeld) {
  using long3r::ScaleSource;
  using long3r_ros::outputUnits;
  // scale_source none: model units by choice; ~depth alone is REP-118 metres.
  auto u = outputUnits(ScaleSource::kNone, false, false, false);
  EXPECT_TRUE(u.depth_held);
  EXPECT_FALSE(u.frame_cloud_held || u.map_held || u.poses_held);
  EXPECT_EQ(u.held(), "~depth");
  EXPECT_FALSE(outputUnits(ScaleSource::kNone, false, false, true).anyHeld());
  // A scale source, the scale pending: everything in metres is held, the
  // odometry's own poses excepted; publish_unscaled sends it all.
  for (ScaleSource s : {ScaleSource::kOdometry, ScaleSource::kDepth, ScaleSource::kFixed}) {
    u = outputUnits(s, false, false, false);
    EXPECT_TRUE(u.depth_held && u.frame_cloud_held && u.map_held && u.poses_held);
    u = outputUnits(s, false, true, false);
    EXPECT_TRUE(u.depth_held && u.frame_cloud_held && u.map_held);
    EXPECT_FALSE(u.poses_held);
    EXPECT_FALSE(outputUnits(s, false, false, true).anyHeld());
    EXPECT_FALSE(outputUnits(s, true, false, false).anyHeld());  // metric: nothing held
  }
  EXPECT_EQ(long3r_ros::describeUnits(ScaleSource::kDepth, true, false), "metres");
  EXPECT_EQ(long3r_ros::describeUnits(ScaleSource::kNone, false, false),
            "model units (scale_source none; ~depth not published)");
}

#include "long3r_ros/node_status.hpp"

#include <diagnostic_msgs/DiagnosticStatus.h>

#include <limits>
#include <string>

#include "long3r_ros/output_units.hpp"

namespace long3r_ros {

namespace {

double wallNow() { return ros::WallTime::now().toSec(); }

}  // namespace

void fillDiagnostics(const NodeStatus& n, diagnostic_updater::DiagnosticStatusWrapper& stat) {
  using S = diagnostic_msgs::DiagnosticStatus;
  const long3r::LiveStatus& s = n.session;
  const WindowStats::Counts& w = n.window;
  const bool rival = !n.tf_rival.empty();
  if (rival) {
    stat.summary(S::ERROR, n.tf_rival);
  } else if (n.paused) {
    stat.summary(S::OK, "paused (~resume to continue)");
  } else if (n.quiet_s > n.no_input_warn_s) {
    stat.summaryf(S::WARN, n.input_seen ? "no input for %.0f s" : "no image received in %.0f s",
                  n.quiet_s);
  } else if (s.lost_frames > 0) {
    stat.summaryf(S::WARN, "tracking lost for %d frame(s) (%.1f s)", s.lost_frames, s.lost_for_s);
  } else if (n.scale_source != long3r::ScaleSource::kNone && !s.scale_metric) {
    const std::string held =
        outputUnits(n.scale_source, false, n.pose_from_odometry, n.publish_unscaled).held();
    const std::string waiting = std::string("until the metric scale is known (scale_source ") +
                                long3r::config::enum_name(n.scale_source) + ", " +
                                std::to_string(s.scale_estimate.samples) + " samples so far)";
    stat.summary(S::WARN, held.empty()
                              ? "publishing in model units " + waiting + ": publish_unscaled"
                              : "held " + waiting + ": " + held);
  } else if (s.calibration_refused) {
    stat.summary(S::WARN, s.calibration);
  } else if (w.dropped + w.failed > 0) {
    stat.summaryf(S::WARN, "dropped %lu and failed %lu frame(s) in the window",
                  static_cast<unsigned long>(w.dropped), static_cast<unsigned long>(w.failed));
  } else {
    stat.summary(S::OK, n.scale_source == long3r::ScaleSource::kNone
                            ? "running, in model units (scale_source none)"
                            : "running");
  }
  stat.add("frames received (window)", w.received);
  stat.add("frames processed (window)", w.processed);
  stat.add("frames dropped (window)", w.dropped);
  stat.add("frames failed (window)", w.failed);
  if (w.processed > 0) {
    stat.addf("latency min / mean / max (s)", "%.3f / %.3f / %.3f", w.latency_min_s,
              w.latencyMean(), w.latency_max_s);
  } else {
    stat.add("latency min / mean / max (s)", "no frame in the window");
  }
  stat.addf("seconds since the last image", "%.1f", n.quiet_s);
  stat.add("paused", n.paused);
  stat.add("tracking", s.tracking);
  stat.add("tracking lost (frames)", s.lost_frames);
  stat.addf("tracking lost (s)", "%.1f", s.lost_for_s);
  stat.add("calibration", s.calibration);
  stat.add("frames", n.frames);
  const long3r::ScaleEstimate& e = s.scale_estimate;
  stat.add("scale source", long3r::config::enum_name(n.scale_source));
  stat.add("units", describeUnits(n.scale_source, s.scale_metric, n.publish_unscaled));
  stat.addf("scale in use (m per model unit)", "%.6g", s.scale);
  stat.add("scale metric", s.scale_metric);
  stat.add("map held for the scale", s.mapping_held);
  stat.addf("scale estimate", "%.6g +- %.3g (%d samples, %d rejected)", e.scale, e.stddev,
            e.samples, e.rejected);
  stat.add("stream frames", s.stream_frames);
  stat.add("streams started", s.streams);
  stat.add("relocalisation attempts", s.relocalisation_attempts);
  stat.add("relocalisations", s.relocalisations);
  stat.add("relocalisations refused by the images", s.relocalisations_refused);
  stat.add("frames tracked by keyframes (total)", s.keyframe_tracked);
  stat.add("of them followed by optical flow (total)", s.keyframe_flow);
  stat.add("frames not tracked: placed by the motion prior (total)", s.keyframe_untracked);
  stat.add("frames that lost the keyframes: relocalising (total)", s.keyframe_lost);
  stat.add("map points kept from ended streams", n.ended_map_points);
  stat.add("session file", n.session_file);
  stat.add("grid", n.grid);
  stat.add("tf", rival ? n.tf_rival : std::string("publishing"));
  stat.add("memory tokens short", s.mem_short_tokens);
  stat.add("memory tokens long", s.mem_long_tokens);
  stat.add("relevant tokens", s.relevant_tokens);
  stat.add("map points", n.map_points);
  stat.add("frames received (total)", n.received);
  stat.add("frames processed (total)", n.processed);
  stat.add("frames failed (total)", n.failed);
  stat.add("frames dropped: bad input (total)", n.dropped_input);
  stat.add("frames dropped: queue full or cleared (total)", n.dropped_queue);
  stat.add("frames dropped: paused (total)", n.dropped_paused);
}

NodeDiagnostics::NodeDiagnostics(const Config& config, std::string log_name)
    : config_(config), log_name_(std::move(log_name)) {}

void NodeDiagnostics::advertise(ros::NodeHandle& nh, ros::NodeHandle& pnh, Fill fill) {
  fill_ = std::move(fill);
  updater_ = std::make_unique<diagnostic_updater::Updater>(nh, pnh, log_name_);
  updater_->setHardwareID("long3r");
  updater_->add("reconstruction", this, &NodeDiagnostics::diagnose);
  min_rate_hz_ = 0.0;
  max_rate_hz_ = std::numeric_limits<double>::infinity();
  output_diagnostic_ = std::make_unique<diagnostic_updater::TopicDiagnostic>(
      "pointmap", *updater_,
      diagnostic_updater::FrequencyStatusParam(&min_rate_hz_, &max_rate_hz_, 0.1, 5),
      diagnostic_updater::TimeStampStatusParam(-1.0, config_.max_latency_s));
}

void NodeDiagnostics::start() { started_wall_s_ = wallNow(); }

// By the wall clock: the updater's own period runs on ROS time, which stops
// with a replayed bag's /clock, and the report after the bag's end (the
// last frames, "no input") must still go out.
void NodeDiagnostics::update() {
  if (!updater_) return;
  const double now = wallNow();
  if (now - last_report_wall_s_ < updater_->getPeriod()) return;
  last_report_wall_s_ = now;
  updater_->force_update();
}

void NodeDiagnostics::shutdown() {
  updater_.reset();
  output_diagnostic_.reset();
}

void NodeDiagnostics::warn(const std::string& kind, const std::string& message) {
  std::uint64_t repeats = 0;
  if (!throttle_.ready(kind, wallNow(), &repeats)) return;
  if (repeats > 0) {
    ROS_WARN_NAMED(log_name_, "%s (and %lu more like it since the last report)", message.c_str(),
                   static_cast<unsigned long>(repeats));
  } else {
    ROS_WARN_NAMED(log_name_, "%s", message.c_str());
  }
}

void NodeDiagnostics::received() {
  ++received_;
  window_.received();
  last_input_wall_s_ = wallNow();
}

void NodeDiagnostics::droppedPaused() {
  ++dropped_paused_;
  window_.dropped();
}

void NodeDiagnostics::droppedQueue() { window_.dropped(); }

void NodeDiagnostics::badInput() {
  ++dropped_input_;
  window_.failed();
}

void NodeDiagnostics::droppedInput() {
  ++dropped_input_;
  window_.dropped();
}

void NodeDiagnostics::failed() {
  ++failed_;
  window_.failed();
}

void NodeDiagnostics::processed(const ros::Time& stamp) {
  ++processed_;
  window_.processed((ros::Time::now() - stamp).toSec());
  if (output_diagnostic_) output_diagnostic_->tick(stamp);
}

void NodeDiagnostics::diagnose(diagnostic_updater::DiagnosticStatusWrapper& stat) {
  NodeStatus n;
  if (fill_) fill_(n);
  n.window = window_.window();
  window_.rotate();
  const double last_input = last_input_wall_s_;
  n.input_seen = last_input > 0.0;
  n.quiet_s = wallNow() - (n.input_seen ? last_input : started_wall_s_.load());
  n.no_input_warn_s = config_.no_input_warn_s;
  n.scale_source = config_.scale_source;
  n.pose_from_odometry = config_.pose_from_odometry;
  n.publish_unscaled = config_.publish_unscaled;
  n.received = received_;
  n.processed = processed_;
  n.failed = failed_;
  n.dropped_input = dropped_input_;
  n.dropped_paused = dropped_paused_;
  fillDiagnostics(n, stat);
}

}  // namespace long3r_ros

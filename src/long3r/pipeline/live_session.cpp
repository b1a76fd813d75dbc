// A live camera stream turned into one reconstruction; see live_session.hpp.
#include "long3r/pipeline/live_session.hpp"

#include "long3r/mapping/state_geometry.hpp"

#include <ATen/ATen.h>

#include <cmath>
#include <cstdio>
#include <limits>
#include <utility>
#include <vector>

namespace long3r {

namespace {

// The reconstruction's config as this session uses it: frames placed by
// odometry measure the scale by their images when the scale comes from it.
ReconstructionConfig with_scale_source(ReconstructionConfig c, ScaleSource source) {
  c.scale_from_given_poses = source == ScaleSource::kOdometry;
  return c;
}

// Whether the keyframe tracker lifts its features by the depth images.
bool tracks_by_depth(const LiveSessionConfig& config, const ReconstructionConfig& reconstruction) {
  return config.tracker_depth_images && config.scale.source == ScaleSource::kDepth &&
         reconstruction.pose_method == PoseMethod::kKeyframes;
}

// The scale policy's settings: a tracker lifted by metric depth needs the
// stream metric before it and never rescaled after (its keyframes' points
// are the camera's metres), so the first depth sample is applied at once.
MetricScaleConfig scale_policy_config(const LiveSessionConfig& config,
                                      const ReconstructionConfig& reconstruction) {
  MetricScaleConfig c = config.scale;
  if (tracks_by_depth(config, reconstruction)) {
    c.min_samples = 1;
    c.freeze = true;
  }
  return c;
}

std::string format(const char* fmt, double a, double b = 0.0) {
  char buf[256];
  std::snprintf(buf, sizeof(buf), fmt, a, b);
  return buf;
}

// A registered depth image in metres (NaN where there is none): CV_16UC1 is
// millimetres, as RGB-D drivers publish (REP 118), CV_32FC1 metres.
cv::Mat depth_in_metres(const cv::Mat& depth) {
  cv::Mat metres;
  if (depth.type() == CV_16UC1) {
    depth.convertTo(metres, CV_32FC1, 0.001);
    metres.setTo(std::numeric_limits<float>::quiet_NaN(), depth == 0);
  } else if (depth.type() == CV_32FC1) {
    metres = depth;
  } else {
    throw std::invalid_argument("a depth image must be 16UC1 (mm) or 32FC1 (m)");
  }
  return metres;
}

// A stream's map (in its W) as the client's map frame has it.
MapSnapshot snapshot_in(const VoxelMap& map, const Eigen::Isometry3d& T_map_W) {
  MapSnapshot snap = map.snapshot();
  const Eigen::Isometry3f T = T_map_W.cast<float>();
  for (Eigen::Vector3f& p : snap.points) p = T * p;
  return snap;
}

}  // namespace

void LiveSessionConfig::validate(const config::FieldCheck& check) const {
  config::validate_nested(*this, check);
  check.require(lost_reset_frames >= 0, "lost_reset_frames", "must be >= 0 (0 = no bound)");
  check.require(relocalise_for_s >= 0.0 && std::isfinite(relocalise_for_s), "relocalise_for_s",
                "must be >= 0 (0 = no bound)");
}

std::optional<Eigen::Isometry3d> LiveSessionClient::place(const LiveFrame&) { return std::nullopt; }

Eigen::Isometry3d LiveSessionClient::odometry_camera_m(const std::any&) {
  throw Unavailable("odometry", "odometry: this input has none");
}

cv::Mat LiveSessionClient::depth(const std::any&) {
  throw Unavailable("depth missing", "depth scale: this input has no depth images");
}

LiveSession::LiveSession(std::unique_ptr<StreamingModel> model,
                         const ReconstructionConfig& reconstruction,
                         const LiveSessionConfig& config, LiveSessionClient& client)
    : config_(config),
      client_(client),
      recon_(std::move(model), with_scale_source(reconstruction, config.scale.source)),
      ended_maps_(reconstruction.map),
      monitor_(config.stream),
      scale_policy_(scale_policy_config(config, reconstruction)),
      scale_sampler_(config.scale) {
  config_.validate(config::FieldCheck{"live session config", ""});
  start_stream_scale();
  if (tracks_by_depth(config_, recon_.config())) {
    recon_.set_tracker_depth_source(
        [this](double stamp_s) {
          if (!scale_policy_.metric()) return cv::Mat();  // lengths in model units still
          const Pending* p = pending_at(stamp_s);
          return p ? registered_depth(p->tag, stamp_s, p->image_size) : cv::Mat();
        },
        config_.map_depth_images ? Reconstruction::DepthImageUse::kPoints
                                 : Reconstruction::DepthImageUse::kScale);
    info("scale", std::string("the keyframe tracker lifts its features by the depth images "
                              "(tracker_depth_images): the first depth image's scale is applied "
                              "at once and kept for the stream (scale_min_samples and "
                              "scale_freeze do not apply), and each frame's points reach the "
                              "map ") +
                      (config_.map_depth_images
                           ? "at its depth image's depth where it has one (map_depth_images)"
                           : "at its depth image's scale"));
  }
  if (recon_.config().pose_method == PoseMethod::kKeyframes &&
      recon_.config().tracker.motion_prior == MotionPrior::kOdometry) {
    recon_.set_odometry_source(
        [this](double stamp_s) -> std::optional<Reconstruction::OdometryPose> {
          const Pending* p = pending_at(stamp_s);
          if (!p) return std::nullopt;
          try {
            return Reconstruction::OdometryPose{client_.odometry_camera_m(p->tag),
                                                scale_policy_.metric()};
          } catch (const LiveSessionClient::Unavailable& e) {
            warn(e.kind(), std::string(e.what()) +
                               "; a frame the images cannot place follows the constant "
                               "velocity (tracker_motion_prior odometry)");
            return std::nullopt;
          }
        });
  }
}

const LiveSession::Pending* LiveSession::pending_at(double stamp_s) const {
  for (const Pending& p : pending_) {
    if (p.stamp_s == stamp_s) return &p;
  }
  return nullptr;
}

void LiveSession::info(const std::string& kind, const std::string& message) {
  LiveEvent e;
  e.level = LiveEvent::Level::kInfo;
  e.kind = kind;
  e.message = message;
  client_.on_event(e);
}

void LiveSession::warn(const std::string& kind, const std::string& message, bool dropped) {
  LiveEvent e;
  e.level = LiveEvent::Level::kWarning;
  e.kind = kind;
  e.message = message;
  e.frame_dropped = dropped;
  client_.on_event(e);
}

// ---------------------------------------------------------------- input

void LiveSession::push(LiveFrame frame) {
  const double stamp_s = frame.stamp_s;
  const StreamMonitor::Decision d =
      monitor_.check(stamp_s, frame.clock_s, frame.image.cols, frame.image.rows);
  std::optional<LiveFrame> held;
  if (d.held != StreamMonitor::Held::kNone) held.swap(held_);
  if (held && d.held == StreamMonitor::Held::kProcess) {
    process(std::move(*held));
  } else if (held) {
    warn("outlier stamp",
         format("frame at t=%.3f dropped: its stamp was far ahead of the frames around it "
                "(max_stamp_jump_s)",
                held->stamp_s),
         true);
  }

  using A = StreamMonitor::Action;
  switch (d.action) {
    case A::kProcess:
      process(std::move(frame));
      return;
    case A::kNewStreamTimeBackwards:
    case A::kNewStreamSizeChanged:
      flush();  // the old stream's last frame is delivered, not lost
      new_stream(format("frame at t=%.3f: ", stamp_s) + StreamMonitor::describe(d.action),
                 /*keep_map=*/true);
      process(std::move(frame));
      return;
    case A::kHold:
      warn("stamp jump", format("frame at t=%.3f: its stamp ran ahead of the clock by more than "
                                "max_stamp_jump_s (%.1f s); held until the next frame shows "
                                "whether time moved on",
                                stamp_s, config_.stream.max_stamp_jump_s));
      held_ = std::move(frame);
      return;
    case A::kDropZeroStamp:
    case A::kDropOutOfOrder:
    case A::kDropStraySize:
      warn(StreamMonitor::describe(d.action),
           format("frame at t=%.3f dropped: ", stamp_s) + StreamMonitor::describe(d.action) +
               (d.action == A::kDropStraySize ? " (" + std::to_string(frame.image.cols) + "x" +
                                                    std::to_string(frame.image.rows) + ")"
                                              : std::string()),
           true);
      return;
  }
}

void LiveSession::process(LiveFrame frame) {
  const cv::Mat image = calibrate(frame);
  std::optional<Eigen::Isometry3d> T_W_C;
  try {
    T_W_C = client_.place(frame);
  } catch (const LiveSessionClient::Unavailable& e) {
    warn(e.kind(), e.what(), true);
    return;
  }
  // A given pose is in metres: mapping waits for a metric scale, and says so.
  if (T_W_C) {
    const bool metric = scale_policy_.metric();
    recon_.set_mapping(metric);
    status_.mapping_held = !metric;
    if (!metric) {
      const ScaleEstimate& e = scale_policy_.estimate();
      char line[320];
      std::snprintf(line, sizeof line,
                    "frame at t=%.3f placed by the given pose but not mapped: the map waits for "
                    "a metric scale (%s; %d of %d samples, standard error %.1f %% of %.4g, "
                    "converged at %.1f %%)",
                    frame.stamp_s, config::enum_name(config_.scale.source), e.samples,
                    config_.scale.min_samples, e.scale > 0.0 ? 100.0 * e.stddev / e.scale : 0.0,
                    e.scale, 100.0 * config_.scale.max_rel_stddev);
      warn("map waits for scale", line);
    }
  }
  std::optional<FrameResult> result = recon_.push(image, frame.encoding, frame.stamp_s, T_W_C);
  // Only a frame the model took awaits a result.
  pending_.push_back({std::move(frame.tag), image.size(), frame.stamp_s});
  status_.stream_frames = recon_.frames_pushed();
  if (result) deliver(std::move(*result));
}

void LiveSession::flush() {
  if (pending_.empty()) return;
  if (std::optional<FrameResult> result = recon_.flush()) deliver(std::move(*result));
}

// The calibration of this frame, validated against its image; a valid new
// one applies from this frame on. Returns the image the model sees.
cv::Mat LiveSession::calibrate(const LiveFrame& frame) {
  const cv::Mat& image = frame.image;
  const std::string& source = config_.calibration_source;
  if (rectifier_.valid() && (rectifier_.intrinsics().width != image.cols ||
                             rectifier_.intrinsics().height != image.rows)) {
    rectifier_ = CameraRectifier();  // of another image size: a new stream began
    recon_.set_calibration(std::nullopt);
  }
  if (frame.camera) {
    const std::string problem = CameraRectifier::problem(*frame.camera, image.cols, image.rows);
    if (!problem.empty()) {
      status_.calibration_refused = true;
      status_.calibration = source + " not used: " + problem;
      warn(source + " " + problem,
           source + " not used: " + problem +
               (rectifier_.valid() ? "; keeping the last valid calibration"
                                   : "; the focal length is estimated from the images instead"));
    } else {
      status_.calibration_refused = false;
      const bool first = !rectifier_.valid();
      if (rectifier_.set(*frame.camera, config_.image_is_rectified)) {
        info("calibration", "camera calibration " + (first ? "from " + source : "changed") + ": " +
                                rectifier_.describe());
        recon_.set_calibration(rectifier_.intrinsics());
      }
      status_.calibration = rectifier_.describe();
    }
  }
  return rectifier_.prepare(image);
}

void LiveSession::reset(const std::string& why) {
  monitor_.reset();
  ended_maps_.clear();
  set_ended({});
  new_stream(why, /*keep_map=*/false);
}

void LiveSession::new_stream(const std::string& why, bool keep_map) {
  LiveEvent e;
  e.level = LiveEvent::Level::kWarning;
  e.kind = "new stream";
  e.message = why + ": starting a new stream (memory, map and path start over)";
  e.throttle = false;  // each one is news
  client_.on_event(e);
  if (keep_map) keep_ended_map();
  client_.on_stream_ending(recon_);
  recon_.reset();
  // Frames that went in and will never come out are counted as dropped, so
  // that every frame pushed ends in a result or a drop.
  const std::size_t unfinished = pending_.size() + (held_ ? 1 : 0);
  for (std::size_t i = 0; i < unfinished; ++i) {
    warn("dropped with the stream",
         "a frame awaiting its result was dropped with the ended stream (" + why + ")",
         /*dropped=*/true);
  }
  pending_.clear();
  held_.reset();
  depth_.reset();
  status_.lost_frames = 0;
  status_.lost_for_s = 0.0;
  status_.stream_frames = 0;
  start_stream_scale();
  client_.on_new_stream(why);
}

// The ending stream's map joins the maps of ended streams, where the client's
// map frame has it.
void LiveSession::keep_ended_map() {
  if (recon_.map().empty()) return;
  const std::optional<Eigen::Isometry3d> T_map_W = client_.T_map_W();
  if (!T_map_W) return;
  EndedStream ended;
  ended.T_map_W = *T_map_W;
  if (recon_.config().occupancy.enabled && recon_.occupancy().voxels() > 0) {
    ended.occupancy = recon_.occupancy().clone();
  }
  // The stream is about to be reset: its surface is handed over, not copied.
  if (recon_.config().surface.enabled && recon_.surface().frames_kept() > 0) {
    ended.surface = recon_.take_surface();
  }
  if (ended.occupancy || ended.surface) {
    std::lock_guard<std::mutex> lock(ended_mutex_);
    ended_.push_back(std::move(ended));
    ++ended_revision_;
  }
  const MapSnapshot snap = snapshot_in(recon_.map(), *T_map_W);
  ended_maps_.integrate(snap.points, snap.colors,
                        static_cast<std::int64_t>(ended_maps_.revision()));
  info("kept map", "the ending stream's " + std::to_string(snap.points.size()) +
                       " map points stay in the map (" + std::to_string(ended_maps_.size()) +
                       " kept from ended streams, until a reset)");
}

MapSnapshot LiveSession::map_snapshot(const Eigen::Isometry3d& T_map_W) const {
  MapSnapshot snap = snapshot_in(recon_.map(), T_map_W);
  if (!ended_maps_.empty()) {
    append(snap, ended_maps_.snapshot());
  }
  return snap;
}

// Both revisions only grow: their sum changes whenever either does.
std::uint64_t LiveSession::map_revision() const {
  return recon_.map().revision() + ended_maps_.revision();
}

// One part of every stream's surface (SurfaceMap::points or ::mesh), each
// placed in the map frame.
template <class Part>
Part LiveSession::surfaces_in_map(Part (SurfaceMap::*part)() const,
                                  const Eigen::Isometry3d& T_map_W) const {
  Part all = transformed((recon_.surface().*part)(), T_map_W);
  std::lock_guard<std::mutex> lock(ended_mutex_);
  for (const EndedStream& e : ended_) {
    if (e.surface) append(all, transformed((*e.surface.*part)(), e.T_map_W));
  }
  return all;
}

ColoredPoints LiveSession::surface_points(const Eigen::Isometry3d& T_map_W) const {
  return surfaces_in_map(&SurfaceMap::points, T_map_W);
}

ColoredMesh LiveSession::surface_mesh(const Eigen::Isometry3d& T_map_W) const {
  return surfaces_in_map(&SurfaceMap::mesh, T_map_W);
}

// Both revisions only grow: their sum changes whenever either does.
std::uint64_t LiveSession::surface_revision() const {
  std::lock_guard<std::mutex> lock(ended_mutex_);
  return recon_.surface().revision() + ended_revision_;
}

LiveSession::GridProjection LiveSession::occupancy_grid(const Eigen::Isometry3d& T_map_W,
                                                        const GridProjectionConfig& config) const {
  std::lock_guard<std::mutex> lock(ended_mutex_);
  // Every stream's occupancy with where it sits in the map frame.
  std::vector<std::pair<const OccupancyMap*, Eigen::Isometry3d>> maps{
      {&recon_.occupancy(), T_map_W}};
  for (const EndedStream& e : ended_) {
    if (e.occupancy) maps.emplace_back(e.occupancy.get(), e.T_map_W);
  }
  GridProjection p;
  // The floor of the current stream, else of the latest ended one that has one.
  if (config.floor == GridFloor::kFit) {
    for (std::size_t k = 0; k < maps.size(); ++k) {
      const auto& [occupancy, T] = maps[k == 0 ? 0 : maps.size() - k];
      if (const std::optional<double> floor = occupancy->floor_z(T)) {
        p.floor_z_m = *floor;
        p.floor_fitted = true;
        break;
      }
    }
  }
  GridBand band;
  band.floor_z_m = p.floor_z_m;
  band.min_height_m = config.min_height_m;
  band.max_height_m = config.max_height_m;
  std::vector<OccupancyGrid> grids;
  for (const auto& [occupancy, T] : maps) grids.push_back(occupancy->project(band, T));
  p.grid = grids.size() == 1 ? std::move(grids.front()) : merge_grids(grids);
  return p;
}

// Both revisions only grow: their sum changes whenever either does.
std::uint64_t LiveSession::occupancy_revision() const {
  std::lock_guard<std::mutex> lock(ended_mutex_);
  return recon_.occupancy().revision() + ended_revision_;
}

// The ended streams' parts for sessions: "ended.count", and per stream i
// "ended.<i>.T_map_W" with "ended.<i>.occupancy.ot" and "ended.<i>.surface.*"
// where it has them.
StateDict LiveSession::ended_state() const {
  std::lock_guard<std::mutex> lock(ended_mutex_);
  StateDict out;
  put_int(out, "count", static_cast<int64_t>(ended_.size()));
  for (std::size_t i = 0; i < ended_.size(); ++i) {
    const EndedStream& e = ended_[i];
    const std::string at = std::to_string(i) + ".";
    out[at + "T_map_W"] = pose_to_tensor(e.T_map_W);
    if (e.occupancy) out[at + "occupancy.ot"] = bytes_tensor(e.occupancy->write());
    if (e.surface) put_state(out, at + "surface.", e.surface->state());
  }
  return out;
}

// Read whole before anything changes; parts this run has off are left out.
// Throws StateError naming the part.
std::vector<LiveSession::EndedStream> LiveSession::read_ended(const StateDict& file) const {
  const StateReader r(file, "session", "ended.");
  std::vector<EndedStream> ended;
  if (!r.has("count")) return ended;  // files of earlier versions
  constexpr int64_t kMaxStreams = 1 << 20;
  const int64_t n = r.integer("count", 0, kMaxStreams);
  for (int64_t i = 0; i < n; ++i) {
    const std::string at = std::to_string(i) + ".";
    EndedStream e;
    e.T_map_W = read_pose(r, at + "T_map_W");
    if (recon_.config().occupancy.enabled && r.has(at + "occupancy.ot")) {
      auto occupancy = std::make_shared<OccupancyMap>(recon_.config().occupancy);
      occupancy->restore(r, at + "occupancy.ot");
      e.occupancy = std::move(occupancy);
    }
    if (recon_.config().surface.enabled && r.has(at + "surface.frames")) {
      auto surface = std::make_shared<SurfaceMap>(recon_.config().surface);
      surface->restore(r.child(at + "surface."));
      e.surface = std::move(surface);
    }
    if (e.occupancy || e.surface) ended.push_back(std::move(e));
  }
  return ended;
}

void LiveSession::set_ended(std::vector<EndedStream> ended) {
  std::lock_guard<std::mutex> lock(ended_mutex_);
  ended_ = std::move(ended);
  ++ended_revision_;
}

void LiveSession::start_stream_scale() {
  scale_policy_.reset();
  scale_sampler_.reset();
  recon_.set_scale(scale_policy_.applied());  // fixed: the given scale; otherwise 1
  recon_.set_mapping(true);
  status_.scale_estimate = scale_policy_.estimate();
  status_.scale = scale_policy_.applied();
  status_.scale_metric = scale_policy_.metric();
  ++status_.streams;
}

// ---------------------------------------------------------------- sessions

SessionIdentity LiveSession::identity() const {
  SessionIdentity id;
  id.model = recon_.model().identity();
  id.input_width = recon_.config().preprocess.width;
  id.input_height = recon_.config().preprocess.height;
  id.voxel_size_m = recon_.config().map.voxel_size_m;
  return id;
}

void LiveSession::save(const std::string& path) {
  flush();
  StateDict state;
  try {
    put_state(state, "reconstruction.", recon_.state());
  } catch (const std::logic_error& e) {
    throw SessionError("session not saved to " + path + ": " + e.what());
  }
  const ScalePolicy::State scale = scale_policy_.state();
  state["live.scale.samples"] = at::tensor(scale.samples, at::kDouble);
  put_real(state, "live.scale.applied", scale.applied);
  put_int(state, "live.scale.metric", scale.metric ? 1 : 0);
  if (!ended_maps_.empty()) put_state(state, "ended_maps.", ended_maps_.state());
  put_state(state, "ended.", ended_state());
  put_state(state, "client.", client_.session_state());
  char scale_text[64];
  std::snprintf(scale_text, sizeof scale_text, "%.6g%s", recon_.scale(),
                scale.metric ? " m per model unit" : " (model units)");
  write_session(path, identity(), state,
                {{"frames", std::to_string(recon_.frames_pushed())},
                 {"map_points", std::to_string(recon_.map().size())},
                 {"path_poses", std::to_string(recon_.trajectory().size())},
                 {"scale", scale_text}});
  info("session", "session saved to " + path + ": " + std::to_string(recon_.frames_pushed()) +
                      " frames, " + std::to_string(recon_.map().size()) + " map points");
}

void LiveSession::load(const std::string& path) {
  const StateDict file = read_session(path, identity());
  ScalePolicy::State scale;
  VoxelMap ended(recon_.config().map);
  std::vector<EndedStream> ended_parts;
  try {
    const StateReader r(file, "session", "live.scale.");
    const at::Tensor samples = r.floating("samples", {-1}).to(at::kDouble).contiguous();
    scale.samples.assign(samples.data_ptr<double>(), samples.data_ptr<double>() + samples.numel());
    scale.applied = r.real("applied");
    scale.metric = r.integer("metric", 0, 1) == 1;
    if (!(scale.applied > 0.0) || !std::isfinite(scale.applied)) {
      r.fail("applied", "must be positive and finite");
    }
    // Validated whole before anything changes. Files of earlier versions kept
    // them with the node's state.
    for (const char* prefix : {"ended_maps.", "client.archive."}) {
      const StateReader r(file, "session", prefix);
      if (r.has("index")) {
        ended.restore(r);
        break;
      }
    }
    ended_parts = read_ended(file);
    recon_.restore(sub_state(file, "reconstruction."));
  } catch (const StateError& e) {
    throw SessionError(path + ": damaged session: " + e.what());
  }
  // The stream now is the file's: stamps start over, and so does what the
  // client keeps per stream.
  ended_maps_.restore(ended.records());
  set_ended(std::move(ended_parts));
  monitor_.reset();
  held_.reset();
  pending_.clear();
  depth_.reset();
  status_.lost_frames = 0;
  status_.lost_for_s = 0.0;
  status_.tracking = recon_.frames_pushed() > 0 ? "ok" : "not started";
  status_.stream_frames = recon_.frames_pushed();
  scale_sampler_.reset();
  if (scale.metric) {
    scale_policy_.restore(scale);
  } else {  // not metric yet: this run's scale source decides, from the file's samples
    scale_policy_.reset();
    scale.applied = scale_policy_.applied();
    scale.metric = scale_policy_.metric();
    scale_policy_.restore(scale);
    recon_.set_scale(scale_policy_.applied());
  }
  recon_.set_mapping(true);
  status_.scale_estimate = scale_policy_.estimate();
  status_.scale = scale_policy_.applied();
  status_.scale_metric = scale_policy_.metric();
  status_.mapping_held = false;
  ++status_.streams;
  info("session", "session loaded from " + path + ": " + std::to_string(recon_.frames_pushed()) +
                      " frames, " + std::to_string(recon_.map().size()) + " map points, " +
                      std::to_string(recon_.trajectory().size()) +
                      " poses; the next frames "
                      "continue it");
  client_.on_new_stream("session loaded from " + path);
  client_.restore_session_state(sub_state(file, "client."));
}

// ---------------------------------------------------------------- results

void LiveSession::deliver(FrameResult frame) {
  // Results come back in push order: the oldest pending frame is this one.
  if (pending_.empty()) return;
  LiveResult r;
  r.tag = std::move(pending_.front().tag);
  r.image_size = pending_.front().image_size;
  pending_.pop_front();
  r.frame = std::move(frame);
  const FrameResult& f = r.frame;
  status_.mem_short_tokens = f.model.mem_short_tokens;
  status_.mem_long_tokens = f.model.mem_long_tokens;
  status_.relevant_tokens = f.model.relevant_tokens;

  if (f.intrinsics.fx > 0.0) {
    const std::string line =
        f.intrinsics_source == IntrinsicsSource::kCalibration
            ? "from " + config_.calibration_source +
                  format(": fx %.2f, fy %.2f px", f.intrinsics.fx, f.intrinsics.fy) +
                  format(", cx %.2f, cy %.2f at model resolution", f.intrinsics.cx, f.intrinsics.cy)
            : format(
                  "estimated from the first frame (no usable calibration): focal %.2f px at "
                  "model resolution",
                  f.intrinsics.fx);
    if (line != intrinsics_logged_) {
      info("intrinsics", "intrinsics in use " + line);
      intrinsics_logged_ = line;
    }
  }
  track_loss(f);
  if (const auto& k = f.tracking) {
    if (k->posed()) {
      ++status_.keyframe_tracked;
      if (k->flow) ++status_.keyframe_flow;
    } else if (k->status == TrackStatus::kLost) {  // track_loss() says so
      ++status_.keyframe_lost;
    } else if (k->status != TrackStatus::kRefused) {  // refused: track_loss() says so
      ++status_.keyframe_untracked;
      warn("keyframes", "frame " + std::to_string(f.frame_index) +
                            ": not tracked against the keyframes (" + to_string(k->status) + ": " +
                            k->message + "); placed by the motion prior (tracker_motion_prior)");
    }
  }
  if (f.pose.ok()) update_scale(r);
  client_.on_result(r);
}

void LiveSession::track_loss(const FrameResult& r) {
  int& lost = status_.lost_frames;
  // Relocalisation by images (pose_method keyframes): tried on this frame.
  const bool by_images = r.tracking && (r.tracking->status == TrackStatus::kRelocalised ||
                                        r.tracking->status == TrackStatus::kRefused);
  if (lost > 0 || by_images) ++status_.relocalisation_attempts;
  if (by_images && r.tracking->status == TrackStatus::kRefused) ++status_.relocalisations_refused;
  if (r.pose.ok()) {
    if (lost > 0 || by_images) {
      ++status_.relocalisations;
      const std::string how = by_images ? " by the images (" + std::to_string(r.tracking->inliers) +
                                              " inliers against a kept keyframe)"
                                        : std::string();
      info("tracking",
           format("relocalised at frame %.0f", static_cast<double>(r.frame_index)) + how +
               (lost > 0 ? " after " + std::to_string(lost) +
                               format(" unposed frame(s) (%.1f s)", r.stamp - lost_since_stamp_)
                         : std::string()) +
               ": the stream goes on in its map");
    }
    lost = 0;
  } else {
    if (lost++ == 0) lost_since_stamp_ = r.stamp;
    const double lost_s = r.stamp - lost_since_stamp_;
    warn("pose", "frame " + std::to_string(r.frame_index) + ": pose estimation failed (" +
                     r.pose.message + "); " +
                     (r.pose_given ? "placed by the given pose, its points not mapped"
                                   : "not added to the map") +
                     " (tracking lost for " + std::to_string(lost) +
                     " frame(s); each new frame is tried against the memory and map)");
    if (config_.lost_reset_frames > 0 && lost >= config_.lost_reset_frames) {
      new_stream(
          "tracking lost for " + std::to_string(lost) + " consecutive frames (lost_reset_frames)",
          /*keep_map=*/true);
    } else if (config_.relocalise_for_s > 0.0 && lost_s >= config_.relocalise_for_s) {
      new_stream(format("tracking lost for %.1f s without relocalising (relocalise_for_s %g)",
                        lost_s, config_.relocalise_for_s),
                 /*keep_map=*/true);
    }
  }
  status_.lost_for_s = lost > 0 ? r.stamp - lost_since_stamp_ : 0.0;
  status_.tracking = lost > 0 ? "lost" : "ok";
}

// This result's sample of the metric scale, and the scale itself when the
// policy applies one: the stream is rescaled, and so is this result.
void LiveSession::update_scale(LiveResult& result) {
  FrameResult& r = result.frame;
  std::optional<double> sample;
  if (config_.scale.source == ScaleSource::kDepth) {
    // Once metric, a tracker lifted by the depth images keeps the scale for
    // the stream: each frame's own depth image scales its points.
    if (!(tracks_by_depth(config_, recon_.config()) && scale_policy_.metric())) {
      sample = depth_sample(result);
    }
  } else if (config_.scale.source == ScaleSource::kOdometry && r.baseline_scale) {
    // Placed by odometry: the images over its baseline, not the model's motion.
    sample = r.baseline_scale->sample;
  } else if (config_.scale.source == ScaleSource::kOdometry) {
    try {
      // The pose the tracker's prior already asked for, else the client.
      const Eigen::Vector3d odom =
          (r.T_O_C ? *r.T_O_C : client_.odometry_camera_m(result.tag)).translation();
      const Eigen::Vector3d model = r.model_T_W_C.translation() / r.scale;
      sample = scale_sampler_.add(odom, model);
    } catch (const LiveSessionClient::Unavailable& e) {
      warn(e.kind(), e.what());
    }
  }
  if (sample) scale_policy_.add_sample(*sample);
  const std::optional<double> scale = scale_policy_.scale_to_apply();
  const ScaleEstimate& e = scale_policy_.estimate();
  if (scale) {
    recon_.set_scale(*scale);
    recon_.set_mapping(true);
  }
  status_.scale_estimate = e;
  status_.scale = scale_policy_.applied();
  status_.scale_metric = scale_policy_.metric();
  if (!scale) return;
  char line[256];
  std::snprintf(line, sizeof line,
                "metric scale %.4f +- %.4f m per model unit from %d samples (%s, %d rejected): "
                "map and path rescaled",
                e.scale, e.stddev, e.samples, config::enum_name(config_.scale.source), e.rejected);
  info("scale", line);
  Reconstruction::rescale(r, *scale);
  result.scale_changed = true;
}

// measured / predicted depth for this result (metric_scale.hpp).
std::optional<double> LiveSession::depth_sample(const LiveResult& result) {
  const FrameResult& r = result.frame;
  const cv::Mat metres = registered_depth(result.tag, r.stamp, result.image_size);
  if (metres.empty()) return std::nullopt;
  const ReconstructionConfig& rc = recon_.config();
  const ResizeCropPlan plan = plan_resize_crop(metres.cols, metres.rows, rc.preprocess);
  const cv::Mat measured =
      depth_at_model_pixels(metres, plan.model_to_source, r.conf.cols, r.conf.rows);
  std::vector<cv::Mat> xyz;
  cv::split(r.points_C, xyz);
  const cv::Mat predicted = xyz[2] / r.scale;  // model units
  return depth_scale_sample(predicted, measured, r.conf, rc.conf_threshold);
}

// The frame's depth image in metres, rectified as its image was; empty (with
// a warning) where there is none or it cannot be used. Asked of the client
// once a frame: the tracker's and the scale's use the same.
cv::Mat LiveSession::registered_depth(const std::any& tag, double stamp_s,
                                      const cv::Size& image_size) {
  if (depth_ && depth_->stamp_s == stamp_s) return depth_->metres;
  depth_ = DepthImage{stamp_s, cv::Mat()};
  cv::Mat metres;
  try {
    metres = depth_in_metres(client_.depth(tag));
  } catch (const LiveSessionClient::Unavailable& e) {
    warn(e.kind(), e.what());
    return {};
  } catch (const std::invalid_argument& e) {
    warn("depth encoding", std::string("depth image not used: ") + e.what());
    return {};
  }
  // Registered to the raw image: rectified as the image was, without blending depths.
  if (metres.size() == image_size && rectifier_.rectifies()) {
    metres = rectifier_.prepare(metres, cv::INTER_NEAREST);
  }
  if (metres.size() != image_size) {
    warn("depth size", "depth image of " + std::to_string(metres.cols) + "x" +
                           std::to_string(metres.rows) + " is not registered to the images (" +
                           std::to_string(image_size.width) + "x" +
                           std::to_string(image_size.height) + ")");
    return {};
  }
  depth_->metres = metres;
  return metres;
}

}  // namespace long3r

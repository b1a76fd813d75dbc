#include "long3r_ros/long3r_nodelet.hpp"

#include <geometry_msgs/PoseStamped.h>
#include <ros/package.h>
#include <tf2_eigen/tf2_eigen.h>
#include <pluginlib/class_list_macros.hpp>

#include <any>
#include <chrono>
#include <cstdio>

#include "long3r/model/loading/safetensors.hpp"
#include "long3r/model/runtime/inference.hpp"
#include "long3r_ros/log_throttle.hpp"

namespace long3r_ros {

namespace {

std::string defaultModelPath() {
  const std::string pkg = ros::package::getPath("long3r_ros");
  return pkg.empty() ? std::string() : pkg + "/models/default.safetensors";
}

// A start-up fault: the last line the nodelet writes, whatever the buffering
// of the manager's stdout (its earlier INFO lines are flushed first).
void logFatal(const std::string& name, const std::string& what) {
  std::fflush(stdout);
  ROS_FATAL_NAMED(name, "%s", what.c_str());
  std::fflush(stderr);
}

// The image header each frame carries through the session (LiveFrame::tag).
const std_msgs::Header& headerOf(const std::any& tag) {
  return std::any_cast<const std_msgs::Header&>(tag);
}

}  // namespace

Long3rNodelet::~Long3rNodelet() { shutdown(); }

// ---------------------------------------------------------------- start-up

void Long3rNodelet::onInit() {
  ros::NodeHandle& pnh = getPrivateNodeHandle();
  try {
    params_ = readParams(pnh);
  } catch (const ParamError& e) {
    logFatal(getName(), std::string("invalid configuration: ") + e.what());
    throw;
  }
  params_.session.calibration_source = "camera_info";
  for (const std::string& name : unknownParams(pnh)) {
    NODELET_WARN("parameter %s is not one of the node's (README, Parameters): ignored",
                 name.c_str());
  }
  const bool pose_from_odometry = params_.node.pose_source == PoseSource::kOdometry;
  if (pose_from_odometry && params_.session.scale.source == long3r::ScaleSource::kNone) {
    NODELET_WARN(
        "pose_source odometry places frames in metres but scale_source is none: frames "
        "are not mapped until a metric scale is set (scale_source odometry, depth or "
        "fixed)");
  }
  NODELET_INFO_STREAM("configuration:\n" << describe(params_));
  diagnostics_ = std::make_unique<NodeDiagnostics>(
      NodeDiagnostics::Config{params_.node.no_input_warn_s, params_.node.max_latency_s,
                              params_.session.scale.source, pose_from_odometry,
                              params_.node.publish_unscaled},
      getName());
  tf_listener_ = std::make_unique<tf2_ros::TransformListener>(tf_buffer_, getNodeHandle());
  frames_ = std::make_unique<RobotFrames>(params_.frames, tf_buffer_);
  placement_ = std::make_unique<StreamPlacement>(*frames_, pose_from_odometry, getName(), warner());
  // Before the services: ~reset and ~load_session clear it.
  queue_ = std::make_unique<long3r::BoundedQueue<InputFrame>>(
      static_cast<std::size_t>(params_.node.queue_size));
  loadModel();
  advertise();
  loadStartSession();
  diagnostics_->start();
  running_ = true;
  worker_ = std::thread(&Long3rNodelet::workerLoop, this);
  subscribe();
}

// A model that cannot be loaded stops the nodelet here (the launch files
// mark it required), with one line that names the file and the reason.
void Long3rNodelet::loadModel() {
  const std::string path =
      params_.node.model_path.empty() ? defaultModelPath() : params_.node.model_path;
  try {
    if (path.empty()) {
      throw std::runtime_error("~model_path is empty and the package's default model is not found");
    }
    if (long3r::has_random_weights(long3r::read_safetensors_metadata(path))) {
      NODELET_WARN("%s holds RANDOM weights (long3r_make_random_model): its maps are meaningless",
                   path.c_str());
    }
    long3r::LiveSessionClient& client = *this;
    session_ =
        std::make_unique<long3r::LiveSession>(long3r::make_streaming_model(path, params_.inference),
                                              params_.reconstruction, params_.session, client);
  } catch (const long3r::InferenceUnsupportedError& e) {
    const std::string what =
        "cannot run " + path + " as configured (~device, ~precision): " + e.what();
    logFatal(getName(), what);
    throw std::runtime_error(what);
  } catch (const std::exception& e) {
    const std::string reason = e.what();
    const std::string what =
        "cannot load the model: " + (reason.find(path) == std::string::npos ? path + ": " : "") +
        reason;
    logFatal(getName(), what);
    throw std::runtime_error(what);
  }
  const long3r::PreprocessConfig& input = session_->reconstruction().config().preprocess;
  const bool recorded = session_->reconstruction().model().recorded_input_size()[0] > 0;
  NODELET_INFO("model loaded from %s, running on %s in %s at %dx%d (%s)", path.c_str(),
               params_.inference.device.c_str(),
               long3r::config::enum_name(params_.inference.precision), input.width, input.height,
               !params_.reconstruction.preprocess.follows_checkpoint()
                   ? "~model_width, ~model_height"
                   : (recorded ? "the size the checkpoint was trained at" : "the default"));
}

// A session named at start must continue, or the node must not start:
// mapping into a new map frame would mislead whatever navigates on it.
void Long3rNodelet::loadStartSession() {
  if (params_.node.session_path.empty()) return;
  try {
    changeSession([this](long3r::LiveSession& session) {
      session.load(params_.node.session_path);
      sessionFileChanged("loaded from " + params_.node.session_path);
    });
  } catch (const std::exception& e) {
    const std::string what =
        std::string("cannot continue the session (~session_path): ") + e.what();
    logFatal(getName(), what);
    throw std::runtime_error(what);
  }
}

void Long3rNodelet::advertise() {
  ros::NodeHandle& nh = getNodeHandle();
  ros::NodeHandle& pnh = getPrivateNodeHandle();
  frame_pub_ = std::make_unique<FramePublisher>(pnh, warner());
  map_pub_ = std::make_unique<MapPublisher>(
      pnh,
      MapPublisher::Config{
          params_.frames.map_frame, params_.node.map_display_voxel_m,
          params_.node.map_display_outlier_neighbours, params_.node.map_display_outlier_stddev,
          !params_.frames.base_frame.empty(), params_.grid, params_.reconstruction.surface.enabled},
      warner());
  path_pub_ = pnh.advertise<nav_msgs::Path>("path", 1, /*latch=*/true);  // latched, newest only
  SessionServices::Node& node = *this;
  services_ = std::make_unique<SessionServices>(pnh, params_.frames.map_frame, getName(), node,
                                                params_.reconstruction.surface.enabled);
  map_timer_ = nh.createWallTimer(ros::WallDuration(params_.node.map_publish_period_s),
                                  &Long3rNodelet::mapTimerCallback, this);
  tf_pub_ = std::make_unique<TransformPublisher>(
      nh, params_.frames,
      TransformPublisher::Config{params_.node.publish_tf, params_.node.tf_publish_rate_hz,
                                 params_.node.tf_tolerance_s},
      getName(), warner());
  diagnostics_->advertise(nh, pnh, [this](NodeStatus& status) { fillStatus(status); });
}

void Long3rNodelet::subscribe() {
  ros::NodeHandle& nh = getNodeHandle();
  StampedInputs::Config stamped;
  stamped.camera_info = params_.node.use_camera_info;
  stamped.camera_info_max_dt_s = params_.node.camera_info_max_dt_s;
  stamped.depth = params_.session.scale.source == long3r::ScaleSource::kDepth;
  stamped.odometry = params_.node.pose_source == PoseSource::kOdometry;
  // The worker pairs each queued image with the messages of its stamp, so
  // the caches reach back as far as the image queue does.
  stamped.reach = static_cast<unsigned>(params_.node.queue_size) + StampedInputs::kReachMargin;
  stamped.odom_frame = params_.frames.odom_frame;
  stamped.base_frame = params_.frames.base_frame;
  stamped_ = std::make_unique<StampedInputs>(nh, stamped, warner());
  if (stamped.depth) {
    NODELET_INFO("metric scale from the depth images on %s", stamped_->depthTopic().c_str());
  }
  if (stamped.odometry) {
    NODELET_INFO("covariance of the odometry-placed poses from %s (nav_msgs/Odometry)",
                 stamped_->odomTopic().c_str());
  }
  try {
    images_ = std::make_unique<ImageSubscriber>(
        nh, getPrivateNodeHandle(), params_.node.image_transport, getName(),
        [this](InputFrame frame) { enqueue(std::move(frame)); });
  } catch (const TransportMissing& e) {
    logFatal(getName(), e.what());
    throw std::runtime_error(e.what());
  }
}

Warn Long3rNodelet::warner() {
  return [this](const std::string& kind, const std::string& message) {
    diagnostics_->warn(kind, message);
  };
}

// ---------------------------------------------------------------- callbacks

void Long3rNodelet::enqueue(InputFrame frame) {
  diagnostics_->received();
  if (paused_) {
    diagnostics_->droppedPaused();
    return;
  }
  if (queue_->push(std::move(frame))) {
    diagnostics_->droppedQueue();
    diagnostics_->warn("queue", "input queue full (queue_size " +
                                    std::to_string(queue_->capacity()) +
                                    "): the oldest frame was dropped, " +
                                    std::to_string(queue_->dropped()) + " so far");
  }
}

void Long3rNodelet::mapTimerCallback(const ros::WallTimerEvent&) {
  diagnostics_->update();
  if (!session_) return;
  bool metric = false;
  Eigen::Isometry3d T_map_W;
  {
    std::lock_guard<std::mutex> lock(state_mutex_);
    metric = state_.session.scale_metric;
    T_map_W = state_.T_map_W;
  }
  const OutputUnits units = outputUnits(metric, /*pose_given=*/false);
  // The maps lock themselves: no wait for the model step.
  const std::uint64_t revision = session_->map_revision();
  if (map_pub_->wants(revision) && !units.map_held) map_pub_->publish(mapSnapshot(), revision);
  const std::uint64_t occupancy = session_->occupancy_revision();
  if (map_pub_->gridWanted(occupancy)) {
    if (units.map_held) {
      map_pub_->hold("held until the metric scale is known");
    } else {
      map_pub_->publishGrid(
          occupancy, [&] { return session_->occupancy_grid(T_map_W, params_.grid); }, metric);
    }
  }
  if (params_.reconstruction.surface.enabled) {
    // As ~map: not sent while it is not in metres.
    if (!units.map_held) {
      map_pub_->publishSurface(
          session_->surface_revision(), [&] { return session_->surface_points(T_map_W); },
          [&] { return session_->surface_mesh(T_map_W); });
    }
  }
  std::lock_guard<std::mutex> lock(state_mutex_);
  state_.grid = map_pub_->gridStatus();
}

void Long3rNodelet::fillStatus(NodeStatus& n) {
  {
    std::lock_guard<std::mutex> lock(state_mutex_);
    n.session = state_.session;
    n.frames = state_.frames;
    n.session_file = state_.session_file;
    n.grid = state_.grid;
  }
  n.tf_rival = tf_pub_->rival();
  n.paused = paused_;
  n.map_points = session_ ? session_->reconstruction().map().size() : 0;
  n.ended_map_points = session_ ? session_->ended_maps().size() : 0;
  n.dropped_queue = queue_ ? queue_->dropped() : 0;
}

// ---------------------------------------------------------------- worker

void Long3rNodelet::workerLoop() {
  const long3r::ThreadState threads = long3r::apply_thread_config(params_.threads);
  NODELET_INFO("worker thread running with %s", long3r::describe(threads).c_str());
  auto last_frame = std::chrono::steady_clock::now();
  while (running_) {
    std::optional<InputFrame> frame = queue_->pop(std::chrono::milliseconds(50));
    if (!frame) {
      const double idle_s =
          std::chrono::duration<double>(std::chrono::steady_clock::now() - last_frame).count();
      if (idle_s >= params_.node.flush_after_s) flushPending();
      continue;
    }
    last_frame = std::chrono::steady_clock::now();
    try {
      handleFrame(*frame);
    } catch (const std::exception& e) {
      // Bad input or a failure in one frame must never take the node down.
      diagnostics_->failed();
      diagnostics_->warn(
          std::string("failed: ") + e.what(),
          atStamp("frame at t=%.3f failed: ", frame->header().stamp.toSec()) + e.what());
    }
  }
}

void Long3rNodelet::handleFrame(const InputFrame& frame) {
  const std_msgs::Header& header = frame.header();
  DecodedImage decoded;
  try {
    decoded = decodeInput(frame, static_cast<std::uint64_t>(params_.node.max_image_pixels));
  } catch (const InputError& e) {
    diagnostics_->badInput();
    diagnostics_->warn(e.kind(),
                       atStamp("frame at t=%.3f skipped: ", header.stamp.toSec()) + e.what());
    return;
  }
  long3r::LiveFrame f;
  f.image = decoded.image;
  f.encoding = decoded.encoding;
  f.stamp_s = header.stamp.toSec();
  f.clock_s = frame.arrival.toSec();
  if (params_.node.use_camera_info) f.camera = stamped_->camera(header.stamp);
  f.tag = header;
  std::lock_guard<std::mutex> lock(session_mutex_);
  try {
    session_->push(std::move(f));
  } catch (...) {
    copyStatus();
    throw;
  }
  copyStatus();
}

void Long3rNodelet::flushPending() {
  std::lock_guard<std::mutex> lock(session_mutex_);
  try {
    session_->flush();
  } catch (const std::exception& e) {
    diagnostics_->failed();
    NODELET_ERROR("publishing the pending frame failed: %s", e.what());
  }
  copyStatus();
}

void Long3rNodelet::copyStatus() {
  const long3r::LiveStatus status = session_->status();
  std::lock_guard<std::mutex> lock(state_mutex_);
  state_.session = status;
  if (frames_->started()) state_.frames = frames_->describe();
  if (frames_->anchored()) state_.T_map_W = frames_->T_map_W();
}

// ---------------------------------------------------------------- session client

std::optional<Eigen::Isometry3d> Long3rNodelet::place(const long3r::LiveFrame& frame) {
  return placement_->place(headerOf(frame.tag));
}

Eigen::Isometry3d Long3rNodelet::odometry_camera_m(const std::any& tag) {
  return placement_->cameraInOdom(headerOf(tag).stamp);
}

cv::Mat Long3rNodelet::depth(const std::any& tag) { return stamped_->depth(headerOf(tag).stamp); }

void Long3rNodelet::on_event(const long3r::LiveEvent& e) {
  if (e.frame_dropped) diagnostics_->droppedInput();
  if (e.level == long3r::LiveEvent::Level::kInfo) {
    NODELET_INFO("%s", e.message.c_str());
  } else if (e.throttle) {
    diagnostics_->warn(e.kind, e.message);
  } else {
    NODELET_WARN("%s", e.message.c_str());
  }
}

// Where the ending stream's map stays in ~map.
std::optional<Eigen::Isometry3d> Long3rNodelet::T_map_W() {
  if (!frames_->anchored()) return std::nullopt;
  return frames_->T_map_W();
}

void Long3rNodelet::on_new_stream(const std::string&) {
  if (params_.frames.odom_frame.empty() && !session_->ended_maps().empty()) {
    NODELET_INFO(
        "without odom_frame the new stream's map is not registered to the %zu points "
        "kept in ~map from ended streams",
        session_->ended_maps().size());
  }
  frames_->reset();
  tf_pub_->forget();
  frame_pub_->restartTwist();
  path_pub_.publish(pathMessage());
}

long3r::StateDict Long3rNodelet::session_state() { return placement_->sessionState(); }

// After a load: the session's map frame, so that its map and path stay where
// they were; the robot's odometry is tied to it by the first placed frame.
void Long3rNodelet::restore_session_state(const long3r::StateDict& state) {
  placement_->restoreSessionState(state);
  copyStatus();
  if (!outputUnits(session_->status().scale_metric, false).poses_held) {
    path_pub_.publish(pathMessage());
  }
}

nav_msgs::Path Long3rNodelet::pathMessage() {
  nav_msgs::Path path;
  path.header.frame_id = params_.frames.map_frame;
  for (const auto& [stamp, T_W_C] : session_->reconstruction().trajectory()) {
    geometry_msgs::PoseStamped p;
    p.header.stamp = ros::Time(stamp);
    p.header.frame_id = params_.frames.map_frame;
    p.pose = tf2::toMsg(frames_->bodyInMap(T_W_C, p.header.stamp));
    path.poses.push_back(p);
  }
  if (!path.poses.empty()) path.header.stamp = path.poses.back().header.stamp;
  return path;
}

// ---------------------------------------------------------------- services' access

void Long3rNodelet::readSession(const SessionServices::Reader& f) {
  std::lock_guard<std::mutex> lock(session_mutex_);
  f(*session_, *frames_);
}

void Long3rNodelet::changeSession(const SessionServices::Changer& f) {
  std::lock_guard<std::mutex> lock(session_mutex_);
  f(*session_);
  copyStatus();
}

void Long3rNodelet::sessionFileChanged(const std::string& what) {
  std::lock_guard<std::mutex> lock(state_mutex_);
  state_.session_file = what;
}

void Long3rNodelet::clearQueue() { queue_->clear(); }

bool Long3rNodelet::setPaused(bool paused) { return paused_.exchange(paused); }

std::uint64_t Long3rNodelet::pausedDrops() const { return diagnostics_->pausedDrops(); }

long3r::ColoredMesh Long3rNodelet::surfaceMesh() {
  Eigen::Isometry3d T_map_W;
  {
    std::lock_guard<std::mutex> lock(state_mutex_);
    T_map_W = state_.T_map_W;
  }
  return session_->surface_mesh(T_map_W);
}

long3r::MapSnapshot Long3rNodelet::mapSnapshot() {
  Eigen::Isometry3d T_map_W;
  {
    std::lock_guard<std::mutex> lock(state_mutex_);
    T_map_W = state_.T_map_W;
  }
  return session_->map_snapshot(T_map_W);
}

// ---------------------------------------------------------------- outputs

void Long3rNodelet::on_result(long3r::LiveResult& r) {
  // A frame that finishes while the node shuts down has no one to go to, and
  // ROS's publishers may already be torn down.
  if (!running_ || !ros::ok()) return;
  std_msgs::Header header = headerOf(r.tag);
  if (!params_.frames.camera_frame.empty()) header.frame_id = params_.frames.camera_frame;
  diagnostics_->processed(header.stamp);
  if (r.scale_changed) frame_pub_->restartTwist();  // the previous pose was in the old scale
  if (r.frame.pose.ok()) placement_->anchorOdometry(r.frame.pose.T_W_C, header.stamp);
  publishOutputs(r.frame, header);
}

void Long3rNodelet::publishOutputs(const long3r::FrameResult& r, const std_msgs::Header& header) {
  FramePublisher::Context c;
  c.header = header;
  c.map_frame = params_.frames.map_frame;
  c.body_frame = frames_->bodyFrame();
  c.T_map_W = frames_->T_map_W();
  if (r.posed()) c.T_map_body = frames_->bodyInMap(r.pose.T_W_C, header.stamp);
  const long3r::LiveStatus status = session_->status();
  c.scale_metric = status.scale_metric;
  c.scale_stddev = status.scale_estimate.stddev;
  c.units = outputUnits(status.scale_metric, r.pose_given);
  if (c.units.anyHeld()) c.held_why = heldWhy(c.units);
  c.conf_threshold = params_.reconstruction.conf_threshold;
  // A pose the odometry placed has the odometry's covariance.
  if (r.posed() && r.pose_given) {
    c.given_covariance_map =
        stamped_->odometryCovarianceInMap(header.stamp, frames_->T_map_odom().linear());
  }
  const bool pose_out = r.posed() && !c.units.poses_held;
  // TF first, so that the frame's messages resolve in map as they arrive.
  if (pose_out) tf_pub_->publish(*frames_, r.pose.T_W_C, header.stamp);
  frame_pub_->publish(r, c);
  if (pose_out) path_pub_.publish(pathMessage());
}

OutputUnits Long3rNodelet::outputUnits(bool scale_metric, bool pose_given) const {
  return long3r_ros::outputUnits(params_.session.scale.source, scale_metric, pose_given,
                                 params_.node.publish_unscaled);
}

std::string Long3rNodelet::heldWhy(const OutputUnits& units) const {
  const long3r::ScaleSource source = params_.session.scale.source;
  if (source == long3r::ScaleSource::kNone) {
    return units.held() +
           " would be in model units (scale_source none; REP-118 depth is metres); "
           "publish_unscaled: true sends it anyway";
  }
  return units.held() + " wait for the metric scale (scale_source " +
         long3r::config::enum_name(source) +
         "); publish_unscaled: true sends them in model units meanwhile";
}

// ---------------------------------------------------------------- shutdown

void Long3rNodelet::shutdown() {
  if (!running_.exchange(false)) return;
  // Every way into this object from the manager's callback threads is closed
  // (and waited for: roscpp blocks until a running callback returns) before
  // the worker stops and members start to be destroyed; a service or timer
  // callback running into a half-destroyed nodelet is undefined behaviour.
  if (images_) images_->shutdown();
  if (stamped_) stamped_->shutdown();
  if (tf_pub_) tf_pub_->shutdown();
  if (services_) services_->shutdown();
  map_timer_.stop();
  if (queue_) queue_->close();
  if (worker_.joinable()) worker_.join();
  if (diagnostics_) diagnostics_->shutdown();
}

}  // namespace long3r_ros

PLUGINLIB_EXPORT_CLASS(long3r_ros::Long3rNodelet, nodelet::Nodelet)

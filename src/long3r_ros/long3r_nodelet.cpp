#include "long3r_ros/long3r_nodelet.hpp"

#include <geometry_msgs/PoseStamped.h>
#include <geometry_msgs/TransformStamped.h>
#include <ros/package.h>
#include <tf2_eigen/tf2_eigen.h>
#include <pluginlib/class_list_macros.hpp>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <limits>

#include "long3r/dataset/tum_dataset.hpp"
#include "long3r/model/inference.hpp"
#include "long3r/model/safetensors.hpp"
#include "long3r_ros/conversions.hpp"

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

std::string format(const char* fmt, double a, double b = 0.0) {
  char buf[256];
  std::snprintf(buf, sizeof(buf), fmt, a, b);
  return buf;
}

double wallNow() { return ros::WallTime::now().toSec(); }

// roscpp's own queue for the image topic. The callback only enqueues, but its
// thread can be held up (a loaded machine, the manager's other nodelets);
// frames that overflow here are lost without a trace, while the node's own
// queue (queue_size) drops them counted. So this one is generous.
constexpr std::uint32_t kSubscriberQueue = 30;

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
  if (params_.node.pose_source == PoseSource::kOdometry &&
      params_.session.scale.source == long3r::ScaleSource::kNone) {
    NODELET_WARN(
        "pose_source odometry places frames in metres but scale_source is none: frames "
        "are not mapped until a metric scale is set (scale_source odometry, depth or "
        "fixed)");
  }
  NODELET_INFO_STREAM("configuration:\n" << describe(params_));
  tf_listener_ = std::make_unique<tf2_ros::TransformListener>(tf_buffer_, getNodeHandle());
  frames_ = std::make_unique<RobotFrames>(params_.frames, tf_buffer_);
  loadModel();
  advertise();
  loadStartSession();
  queue_ = std::make_unique<long3r::BoundedQueue<InputFrame>>(
      static_cast<std::size_t>(params_.node.queue_size));
  started_ = ros::WallTime::now();
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
  NODELET_INFO("model loaded from %s, running on %s in %s", path.c_str(),
               params_.inference.device.c_str(),
               long3r::config::enum_name(params_.inference.precision));
}

// A session named at start must continue, or the node must not start:
// mapping into a new map frame would mislead whatever navigates on it.
void Long3rNodelet::loadStartSession() {
  if (params_.node.session_path.empty()) return;
  try {
    std::lock_guard<std::mutex> lock(session_mutex_);
    session_->load(params_.node.session_path);
    copyStatus();
    std::lock_guard<std::mutex> state_lock(state_mutex_);
    state_.session_file = "loaded from " + params_.node.session_path;
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
  frame_pub_ = std::make_unique<FramePublisher>(
      pnh, [this](const std::string& kind, const std::string& message) {
        warnThrottled(kind, message);
      });
  map_pub_ = std::make_unique<MapPublisher>(
      pnh,
      MapPublisher::Config{params_.frames.map_frame, params_.node.map_display_voxel_m,
                           params_.node.map_display_outlier_neighbours,
                           params_.node.map_display_outlier_stddev,
                           !params_.frames.base_frame.empty(), params_.grid},
      [this](const std::string& kind, const std::string& message) {
        warnThrottled(kind, message);
      });
  path_pub_ = pnh.advertise<nav_msgs::Path>("path", 1, /*latch=*/true);  // latched, newest only
  reset_srv_ = pnh.advertiseService("reset", &Long3rNodelet::resetService, this);
  pause_srv_ = pnh.advertiseService("pause", &Long3rNodelet::pauseService, this);
  resume_srv_ = pnh.advertiseService("resume", &Long3rNodelet::resumeService, this);
  save_map_srv_ = pnh.advertiseService("save_map", &Long3rNodelet::saveMapService, this);
  save_trajectory_srv_ =
      pnh.advertiseService("save_trajectory", &Long3rNodelet::saveTrajectoryService, this);
  save_session_srv_ =
      pnh.advertiseService("save_session", &Long3rNodelet::saveSessionService, this);
  load_session_srv_ =
      pnh.advertiseService("load_session", &Long3rNodelet::loadSessionService, this);
  map_timer_ = nh.createWallTimer(ros::WallDuration(params_.node.map_publish_period_s),
                                  &Long3rNodelet::mapTimerCallback, this);
  if (params_.node.publish_tf &&
      !(params_.frames.odom_frame.empty() && params_.frames.base_frame.empty())) {
    // The transform we publish: map -> odom, or map -> base without odometry.
    tf_rival_ = std::make_unique<TfRivalWatch>(
        nh, params_.frames.map_frame,
        params_.frames.odom_frame.empty() ? params_.frames.base_frame : params_.frames.odom_frame,
        getName());
  }
  if (params_.node.publish_tf && !params_.frames.odom_frame.empty() &&
      params_.node.tf_publish_rate_hz > 0.0) {
    tf_timer_ = nh.createTimer(ros::Duration(1.0 / params_.node.tf_publish_rate_hz),
                               &Long3rNodelet::tfTimerCallback, this);
  }

  diagnostics_ = std::make_unique<diagnostic_updater::Updater>(nh, pnh, getName());
  diagnostics_->setHardwareID("long3r");
  diagnostics_->add("reconstruction", this, &Long3rNodelet::diagnose);
  min_rate_hz_ = 0.0;
  max_rate_hz_ = std::numeric_limits<double>::infinity();
  output_diagnostic_ = std::make_unique<diagnostic_updater::TopicDiagnostic>(
      "pointmap", *diagnostics_,
      diagnostic_updater::FrequencyStatusParam(&min_rate_hz_, &max_rate_hz_, 0.1, 5),
      diagnostic_updater::TimeStampStatusParam(-1.0, params_.node.max_latency_s));
}

void Long3rNodelet::subscribe() {
  ros::NodeHandle& nh = getNodeHandle();
  ros::NodeHandle& pnh = getPrivateNodeHandle();
  StampedInputs::Config stamped;
  stamped.camera_info = params_.node.use_camera_info;
  stamped.depth = params_.session.scale.source == long3r::ScaleSource::kDepth;
  stamped.odometry = params_.node.pose_source == PoseSource::kOdometry;
  // The worker pairs each queued image with the messages of its stamp, so
  // the caches reach back as far as the image queue does.
  stamped.reach = static_cast<unsigned>(params_.node.queue_size) + StampedInputs::kReachMargin;
  stamped.odom_frame = params_.frames.odom_frame;
  stamped.base_frame = params_.frames.base_frame;
  stamped_ = std::make_unique<StampedInputs>(
      nh, stamped, [this](const std::string& kind, const std::string& message) {
        warnThrottled(kind, message);
      });
  if (stamped.depth) {
    NODELET_INFO("metric scale from the depth images on %s", stamped_->depthTopic().c_str());
  }
  if (stamped.odometry) {
    NODELET_INFO("covariance of the odometry-placed poses from %s (nav_msgs/Odometry)",
                 stamped_->odomTopic().c_str());
  }
  it_ = std::make_unique<image_transport::ImageTransport>(nh);
  const std::vector<std::string> loadable = it_->getLoadableTransports();
  const bool installed =
      std::find(loadable.begin(), loadable.end(),
                "image_transport/" + params_.node.image_transport) != loadable.end();
  if (!installed && params_.node.image_transport == "compressed") {
    // Debian packages no compressed plugin: take the messages it would decode.
    const std::string topic = nh.resolveName("image") + "/compressed";
    compressed_sub_ =
        nh.subscribe(topic, kSubscriberQueue, &Long3rNodelet::compressedCallback, this);
    NODELET_INFO(
        "subscribed to %s (sensor_msgs/CompressedImage, decoded by the node: the "
        "compressed image_transport plugin is not installed)",
        compressed_sub_.getTopic().c_str());
    return;
  }
  if (!installed) {
    std::string names;
    for (const std::string& l : loadable) names += (names.empty() ? "" : ", ") + l;
    const std::string what = "image_transport '" + params_.node.image_transport +
                             "' is not installed (installed: " + names + ")";
    logFatal(getName(), what);
    throw std::runtime_error(what);
  }
  image_sub_ = it_->subscribe(
      "image", kSubscriberQueue, &Long3rNodelet::imageCallback, this,
      image_transport::TransportHints(params_.node.image_transport, ros::TransportHints(), pnh));
  NODELET_INFO("subscribed to %s (transport %s)", image_sub_.getTopic().c_str(),
               params_.node.image_transport.c_str());
}

// ---------------------------------------------------------------- callbacks

void Long3rNodelet::imageCallback(const sensor_msgs::ImageConstPtr& msg) {
  enqueue(InputFrame{msg, nullptr, ros::Time::now()});
}

void Long3rNodelet::compressedCallback(const sensor_msgs::CompressedImageConstPtr& msg) {
  enqueue(InputFrame{nullptr, msg, ros::Time::now()});
}

void Long3rNodelet::enqueue(InputFrame frame) {
  ++frames_received_;
  window_.received();
  last_input_wall_s_ = wallNow();
  if (paused_) {
    ++frames_dropped_paused_;
    window_.dropped();
    return;
  }
  if (queue_->push(std::move(frame))) {
    window_.dropped();
    warnThrottled("queue", "input queue full (queue_size " + std::to_string(queue_->capacity()) +
                               "): the oldest frame was dropped, " +
                               std::to_string(queue_->dropped()) + " so far");
  }
}

bool Long3rNodelet::rivalPublishing() const { return tf_rival_ && tf_rival_->rivalPublishing(); }

void Long3rNodelet::tfTimerCallback(const ros::TimerEvent&) {
  std::optional<geometry_msgs::TransformStamped> t;
  {
    std::lock_guard<std::mutex> lock(state_mutex_);
    t = state_.map_to_odom;
  }
  if (!t || rivalPublishing()) return;
  // map -> odom is a slowly changing correction: kept valid at the current
  // time (and tf_delay_s ahead), so that map -> base resolves at the
  // odometry's latest stamps.
  t->header.stamp = ros::Time::now() + ros::Duration(params_.node.tf_delay_s);
  tf_broadcaster_.sendTransform(*t);
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
      ++frames_failed_;
      window_.failed();
      warnThrottled(std::string("failed: ") + e.what(),
                    format("frame at t=%.3f failed: ", frame->header().stamp.toSec()) + e.what());
    }
  }
}

void Long3rNodelet::handleFrame(const InputFrame& frame) {
  const std_msgs::Header& header = frame.header();
  DecodedImage decoded;
  try {
    decoded = decodeInput(frame, static_cast<std::uint64_t>(params_.node.max_image_pixels));
  } catch (const InputError& e) {
    ++frames_dropped_input_;
    window_.failed();
    warnThrottled(e.kind(), format("frame at t=%.3f skipped: ", header.stamp.toSec()) + e.what());
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
    ++frames_failed_;
    window_.failed();
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
  // For ~grid, whenever it is subscribed (a few microseconds per thousand poses).
  state_.cameras_map.clear();
  for (const auto& entry : session_->reconstruction().trajectory()) {
    state_.cameras_map.push_back(state_.T_map_W * entry.second.translation());
  }
}

// ---------------------------------------------------------------- session client

// Where the stream sits in the robot's TF tree, fixed by its first frame; with
// pose_source odometry, the frame's pose from the odometry.
std::optional<Eigen::Isometry3d> Long3rNodelet::place(const long3r::LiveFrame& frame) {
  const auto& header = std::any_cast<const std_msgs::Header&>(frame.tag);
  try {
    if (!frames_->started()) {
      frames_->startStream(header.frame_id, header.stamp);
      NODELET_INFO("frames: %s", frames_->describe().c_str());
    } else if (frames_->followRoot()) {
      NODELET_WARN("frames: the camera frame gained a parent in TF: %s",
                   frames_->describe().c_str());
    }
  } catch (const TfUnavailable& e) {
    throw Unavailable("tf start", format("frame at t=%.3f skipped: ", header.stamp.toSec()) +
                                      e.what() + "; the stream starts once TF has it");
  }
  try {
    frames_->updateExtrinsics(header.stamp);  // a camera that moves on the base
  } catch (const TfUnavailable& e) {
    warnThrottled("tf extrinsics",
                  format("frame at t=%.3f: the camera's mounting: ", header.stamp.toSec()) +
                      e.what() + "; the last one known is used");
  }
  if (params_.node.pose_source != PoseSource::kOdometry) return std::nullopt;
  if (!frames_->odometryAnchored()) {
    warnThrottled("session odometry",
                  format("frame at t=%.3f placed by the model: in the loaded session, map -> "
                         "odom follows from the first frame the model places (pose_source "
                         "odometry resumes then)",
                         header.stamp.toSec()));
    return std::nullopt;
  }
  try {
    return frames_->cameraFromOdometry(header.stamp);
  } catch (const TfUnavailable& e) {
    throw Unavailable("tf odometry", format("frame at t=%.3f skipped (pose_source odometry): ",
                                            header.stamp.toSec()) +
                                         e.what());
  }
}

Eigen::Vector3d Long3rNodelet::odometry_camera_position_m(const long3r::LiveResult& result) {
  try {
    const auto& header = std::any_cast<const std_msgs::Header&>(result.tag);
    return frames_->cameraInOdom(header.stamp).translation();
  } catch (const TfUnavailable& e) {
    throw Unavailable("tf scale", std::string("odometry scale: ") + e.what());
  }
}

cv::Mat Long3rNodelet::depth(const long3r::LiveResult& result) {
  return stamped_->depth(std::any_cast<const std_msgs::Header&>(result.tag).stamp);
}

void Long3rNodelet::on_event(const long3r::LiveEvent& e) {
  if (e.frame_dropped) {
    ++frames_dropped_input_;
    window_.dropped();
  }
  if (e.level == long3r::LiveEvent::Level::kInfo) {
    NODELET_INFO("%s", e.message.c_str());
  } else if (e.throttle) {
    warnThrottled(e.kind, e.message);
  } else {
    NODELET_WARN("%s", e.message.c_str());
  }
}

// Where the ending stream's map stays in ~map.
std::optional<Eigen::Isometry3d> Long3rNodelet::T_map_W() {
  if (!frames_->anchored()) return std::nullopt;
  return frames_->T_map_W();
}

long3r::MapSnapshot Long3rNodelet::mapSnapshot() {
  Eigen::Isometry3d T_map_W;
  {
    std::lock_guard<std::mutex> lock(state_mutex_);
    T_map_W = state_.T_map_W;
  }
  return session_->map_snapshot(T_map_W);
}

void Long3rNodelet::on_new_stream(const std::string&) {
  if (params_.frames.odom_frame.empty() && !session_->ended_maps().empty()) {
    NODELET_INFO(
        "without odom_frame the new stream's map is not registered to the %zu points "
        "kept in ~map from ended streams",
        session_->ended_maps().size());
  }
  frames_->reset();
  {
    std::lock_guard<std::mutex> state_lock(state_mutex_);
    state_.map_to_odom.reset();
  }
  frame_pub_->restartTwist();
  path_pub_.publish(pathMessage());
}

long3r::StateDict Long3rNodelet::session_state() {
  long3r::StateDict state;
  if (frames_->anchored()) state["T_map_W"] = long3r::pose_to_tensor(frames_->T_map_W());
  if (frames_->started() && frames_->mode() == RobotFrames::Mode::kMapToOdom &&
      frames_->odometryAnchored()) {
    state["T_map_odom"] = long3r::pose_to_tensor(frames_->T_map_odom());
  }
  return state;
}

// After a load: the session's map frame, so that its map and path stay where
// they were; the robot's odometry is tied to it by the first placed frame.
void Long3rNodelet::restore_session_state(const long3r::StateDict& state) {
  auto pose = [&state](const char* key) -> std::optional<Eigen::Isometry3d> {
    const auto it = state.find(key);
    return it == state.end() ? std::nullopt : long3r::pose_from_tensor(it->second);
  };
  if (const std::optional<Eigen::Isometry3d> T_map_W = pose("T_map_W")) {
    frames_->continueSession(*T_map_W, pose("T_map_odom"));
  } else {
    NODELET_WARN(
        "the loaded session has no map frame of its own (saved by long3r_reconstruct?): "
        "%s is fixed by the next frame, as for a new stream",
        params_.frames.map_frame.c_str());
  }
  copyStatus();
  path_pub_.publish(pathMessage());
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

// ---------------------------------------------------------------- outputs

void Long3rNodelet::on_result(long3r::LiveResult& r) {
  // A frame that finishes while the node shuts down has no one to go to, and
  // ROS's publishers may already be torn down.
  if (!running_ || !ros::ok()) return;
  std_msgs::Header header = std::any_cast<const std_msgs::Header&>(r.tag);
  if (!params_.frames.camera_frame.empty()) header.frame_id = params_.frames.camera_frame;
  ++frames_processed_;
  window_.processed((ros::Time::now() - header.stamp).toSec());
  output_diagnostic_->tick(header.stamp);
  if (r.scale_changed) frame_pub_->restartTwist();  // the previous pose was in the old scale
  if (r.frame.pose.ok() && !frames_->odometryAnchored()) {
    try {
      frames_->anchorOdometry(r.frame.pose.T_W_C, header.stamp);
      NODELET_INFO("relocalised in the loaded session at t=%.3f: map -> %s follows from it",
                   header.stamp.toSec(), params_.frames.odom_frame.c_str());
    } catch (const TfUnavailable& e) {
      warnThrottled("tf session", std::string("map -> odom not tied yet: ") + e.what());
    }
  }
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
  const long3r::ScaleSource source = params_.session.scale.source;
  c.depth_held = source != long3r::ScaleSource::kNone && !status.scale_metric &&
                 !params_.node.publish_unscaled_depth;
  if (c.depth_held) {
    c.depth_held_why = std::string("they wait for the metric scale (scale_source ") +
                       long3r::config::enum_name(source) +
                       "); publish_unscaled_depth: true sends them in model units meanwhile";
  }
  c.conf_threshold = params_.reconstruction.conf_threshold;
  // A pose the odometry placed has the odometry's covariance.
  if (r.posed() && r.pose_given) {
    c.given_covariance_map =
        stamped_->odometryCovarianceInMap(header.stamp, frames_->T_map_odom().linear());
  }
  frame_pub_->publish(r, c);
  if (!r.posed()) return;

  path_pub_.publish(pathMessage());

  if (params_.node.publish_tf) {
    try {
      if (const auto t = frames_->transformFor(r.pose.T_W_C, header.stamp)) {
        if (!rivalPublishing()) tf_broadcaster_.sendTransform(*t);
        if (frames_->mode() == RobotFrames::Mode::kMapToOdom) {
          std::lock_guard<std::mutex> lock(state_mutex_);
          state_.map_to_odom = *t;
        }
      } else {
        warnThrottled("tf conflict", "no TF published: " + frames_->conflict());
      }
    } catch (const TfUnavailable& e) {
      warnThrottled("tf publish",
                    format("no TF for the frame at t=%.3f: ", header.stamp.toSec()) + e.what());
    }
  }
}

void Long3rNodelet::mapTimerCallback(const ros::WallTimerEvent&) {
  if (diagnostics_) diagnostics_->update();
  if (!session_) return;
  // The maps lock themselves: no wait for the model step.
  const std::uint64_t revision = session_->map_revision();
  if (map_pub_->wants(revision)) {
    std::vector<Eigen::Vector3d> cameras;
    bool metric = false;
    {
      std::lock_guard<std::mutex> lock(state_mutex_);
      cameras = state_.cameras_map;
      metric = state_.session.scale_metric;
    }
    map_pub_->publish(mapSnapshot(), cameras, metric, revision);
  }
  std::lock_guard<std::mutex> lock(state_mutex_);
  state_.grid = map_pub_->gridStatus();
}

// ---------------------------------------------------------------- services

bool Long3rNodelet::resetService(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
  {
    std::lock_guard<std::mutex> lock(session_mutex_);
    session_->reset("reset requested");
    copyStatus();
  }
  queue_->clear();
  res.success = true;
  res.message = "memory, map and path cleared";
  return true;
}

bool Long3rNodelet::pauseService(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
  const bool was = paused_.exchange(true);
  res.success = true;
  res.message = was ? "already paused"
                    : "paused: incoming frames are dropped and counted until ~resume; memory, "
                      "map and path are kept";
  if (!was) NODELET_INFO("%s", res.message.c_str());
  return true;
}

bool Long3rNodelet::resumeService(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
  const bool was = paused_.exchange(false);
  res.success = true;
  res.message = was ? "resumed; " + std::to_string(frames_dropped_paused_.load()) +
                          " frame(s) dropped while paused so far"
                    : "not paused";
  if (was) NODELET_INFO("%s", res.message.c_str());
  return true;
}

bool Long3rNodelet::saveMapService(SaveMap::Request& req, SaveMap::Response& res) {
  try {
    const long3r::MapSnapshot snap = mapSnapshot();                  // as ~map shows it
    long3r::save_colored_cloud(req.path, snap.points, snap.colors);  // atomic
    res.success = true;
    res.message = "wrote " + std::to_string(snap.points.size()) + " points (" +
                  params_.frames.map_frame + ") to " + req.path;
  } catch (const std::exception& e) {
    res.success = false;
    res.message = e.what();
  }
  return true;
}

bool Long3rNodelet::saveSessionService(SaveSession::Request& req, SaveSession::Response& res) {
  std::lock_guard<std::mutex> lock(session_mutex_);
  try {
    session_->save(req.path);  // atomic; publishes the pending frame first
    res.success = true;
    res.message = "saved " + std::to_string(session_->reconstruction().frames_pushed()) +
                  " frames, " + std::to_string(session_->reconstruction().map().size()) +
                  " map points to " + req.path;
    std::lock_guard<std::mutex> state_lock(state_mutex_);
    state_.session_file = "saved to " + req.path;
  } catch (const std::exception& e) {
    res.success = false;
    res.message = e.what();
    NODELET_ERROR("~save_session: %s", e.what());
  }
  copyStatus();
  return true;
}

bool Long3rNodelet::loadSessionService(LoadSession::Request& req, LoadSession::Response& res) {
  {
    std::lock_guard<std::mutex> lock(session_mutex_);
    try {
      session_->load(req.path);  // all or nothing
      res.success = true;
      res.message = "loaded " + std::to_string(session_->reconstruction().frames_pushed()) +
                    " frames, " + std::to_string(session_->reconstruction().map().size()) +
                    " map points from " + req.path + "; the next frames continue it";
      std::lock_guard<std::mutex> state_lock(state_mutex_);
      state_.session_file = "loaded from " + req.path;
    } catch (const std::exception& e) {
      res.success = false;
      res.message = e.what() + std::string("; the running session is kept");
      NODELET_ERROR("~load_session: %s", res.message.c_str());
    }
    copyStatus();
  }
  if (res.success) queue_->clear();  // frames queued for the old stream
  return true;
}

bool Long3rNodelet::saveTrajectoryService(SaveTrajectory::Request& req,
                                          SaveTrajectory::Response& res) {
  long3r::PoseTrajectory trajectory;
  std::string what;
  {
    std::lock_guard<std::mutex> lock(session_mutex_);
    for (const auto& [stamp, T_W_C] : session_->reconstruction().trajectory()) {
      trajectory.stamps.push_back(stamp);
      trajectory.poses.push_back(frames_->bodyInMap(T_W_C, ros::Time(stamp)));
    }
    what = "poses of " + frames_->bodyFrame() + " in " + params_.frames.map_frame;
  }
  try {
    long3r::write_tum_trajectory(req.path, trajectory, "long3r_ros ~path: " + what);  // atomic
    res.success = true;
    res.message = "wrote " + std::to_string(trajectory.size()) + " " + what + " to " + req.path;
  } catch (const std::exception& e) {
    res.success = false;
    res.message = e.what();
  }
  return true;
}

// ---------------------------------------------------------------- diagnostics

void Long3rNodelet::warnThrottled(const std::string& kind, const std::string& message) {
  std::uint64_t repeats = 0;
  if (!throttle_.ready(kind, wallNow(), &repeats)) return;
  if (repeats > 0) {
    NODELET_WARN("%s (and %lu more like it since the last report)", message.c_str(),
                 static_cast<unsigned long>(repeats));
  } else {
    NODELET_WARN("%s", message.c_str());
  }
}

void Long3rNodelet::diagnose(diagnostic_updater::DiagnosticStatusWrapper& stat) {
  NodeStatus n;
  {
    std::lock_guard<std::mutex> lock(state_mutex_);
    n.session = state_.session;
    n.frames = state_.frames;
    n.session_file = state_.session_file;
    n.grid = state_.grid;
  }
  if (tf_rival_) n.tf_rival = tf_rival_->describe();
  n.window = window_.window();
  window_.rotate();
  const double last_input = last_input_wall_s_;
  n.input_seen = last_input > 0.0;
  n.quiet_s = wallNow() - (n.input_seen ? last_input : started_.toSec());
  n.no_input_warn_s = params_.node.no_input_warn_s;
  n.paused = paused_;
  n.scale_source = params_.session.scale.source;
  n.map_points = session_ ? session_->reconstruction().map().size() : 0;
  n.ended_map_points = session_ ? session_->ended_maps().size() : 0;
  n.received = frames_received_;
  n.processed = frames_processed_;
  n.failed = frames_failed_;
  n.dropped_input = frames_dropped_input_;
  n.dropped_queue = queue_ ? queue_->dropped() : 0;
  n.dropped_paused = frames_dropped_paused_;
  fillDiagnostics(n, stat);
}

void Long3rNodelet::shutdown() {
  if (!running_.exchange(false)) return;
  // Every way into this object from the manager's callback threads is closed
  // (and waited for: roscpp blocks until a running callback returns) before
  // the worker stops and members start to be destroyed; a service or timer
  // callback running into a half-destroyed nodelet is undefined behaviour.
  image_sub_.shutdown();
  compressed_sub_.shutdown();
  if (stamped_) stamped_->shutdown();
  if (tf_rival_) tf_rival_->shutdown();
  tf_timer_.stop();
  reset_srv_.shutdown();
  pause_srv_.shutdown();
  resume_srv_.shutdown();
  save_map_srv_.shutdown();
  save_session_srv_.shutdown();
  load_session_srv_.shutdown();
  save_trajectory_srv_.shutdown();
  map_timer_.stop();
  if (queue_) queue_->close();
  if (worker_.joinable()) worker_.join();
  diagnostics_.reset();
  output_diagnostic_.reset();
}

}  // namespace long3r_ros

PLUGINLIB_EXPORT_CLASS(long3r_ros::Long3rNodelet, nodelet::Nodelet)

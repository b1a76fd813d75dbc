#include "long3r_ros/long3r_nodelet.hpp"

#include <cv_bridge/cv_bridge.h>
#include <geometry_msgs/PoseStamped.h>
#include <geometry_msgs/TransformStamped.h>
#include <ros/package.h>
#include <sensor_msgs/image_encodings.h>
#include <tf2_eigen/tf2_eigen.h>
#include <pluginlib/class_list_macros.hpp>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <limits>

#include "long3r/dataset/tum_dataset.hpp"
#include "long3r/model/inference.hpp"
#include "long3r/model/safetensors.hpp"
#include "long3r_ros/Pointmap.h"
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
    config_ = readNodeletConfig(pnh);
    frames_config_ = readFramesConfig(pnh);
    scale_config_ = readMetricScaleConfig(pnh);
    monitor_config_ = readStreamMonitorConfig(pnh);
    if (config_.pose_source == PoseSource::kOdometry &&
        (frames_config_.odom_frame.empty() || frames_config_.base_frame.empty())) {
      throw ParamError("parameter " + pnh.resolveName("pose_source") +
                       " odometry needs odom_frame and base_frame");
    }
    if (scale_config_.source == long3r::ScaleSource::kOdometry &&
        (frames_config_.odom_frame.empty() || frames_config_.base_frame.empty())) {
      throw ParamError("parameter " + pnh.resolveName("scale_source") +
                       " odometry needs odom_frame and base_frame");
    }
    thread_config_ = readThreadConfig(pnh);
    inference_config_ = readInferenceConfig(pnh);
    recon_config_ = readReconstructionConfig(pnh);
  } catch (const ParamError& e) {
    logFatal(getName(), std::string("invalid configuration: ") + e.what());
    throw;
  }
  if (pnh.hasParam("world_frame")) {
    NODELET_WARN("~world_frame is the old name of ~map_frame; please rename it");
  }
  if (config_.pose_source == PoseSource::kOdometry &&
      scale_config_.source == long3r::ScaleSource::kNone) {
    NODELET_WARN(
        "pose_source odometry places frames in metres but scale_source is none: frames "
        "are not mapped until a metric scale is set (scale_source odometry, depth or "
        "fixed)");
  }
  NODELET_INFO_STREAM("configuration:\n"
                      << describe(config_) << "\n"
                      << describe(frames_config_) << "\n"
                      << describe(scale_config_) << "\n"
                      << describe(monitor_config_) << "\n"
                      << describe(thread_config_) << "\n"
                      << describe(inference_config_) << "\n"
                      << describe(recon_config_));
  loadModel();
  monitor_ = StreamMonitor(monitor_config_);
  tf_listener_ = std::make_unique<tf2_ros::TransformListener>(tf_buffer_, getNodeHandle());
  frames_ = std::make_unique<RobotFrames>(frames_config_, tf_buffer_);
  scale_policy_ = long3r::ScalePolicy(scale_config_);
  scale_sampler_ = std::make_unique<long3r::OdometryScaleSampler>(scale_config_);
  {
    std::lock_guard<std::mutex> lock(recon_mutex_);
    startStreamScale();
  }
  advertise();
  queue_ = std::make_unique<long3r::BoundedQueue<InputFrame>>(
      static_cast<std::size_t>(config_.queue_size));
  started_ = ros::WallTime::now();
  running_ = true;
  worker_ = std::thread(&Long3rNodelet::workerLoop, this);
  subscribe();
}

// A model that cannot be loaded stops the nodelet here (the launch files
// mark it required), with one line that names the file and the reason.
void Long3rNodelet::loadModel() {
  const std::string path = config_.model_path.empty() ? defaultModelPath() : config_.model_path;
  try {
    if (path.empty()) {
      throw std::runtime_error("~model_path is empty and the package's default model is not found");
    }
    if (long3r::has_random_weights(long3r::read_safetensors_metadata(path))) {
      NODELET_WARN("%s holds RANDOM weights (long3r_make_random_model): its maps are meaningless",
                   path.c_str());
    }
    recon_ = std::make_unique<long3r::Reconstruction>(
        long3r::make_streaming_model(path, inference_config_), recon_config_);
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
               inference_config_.device.c_str(),
               long3r::config::enum_name(inference_config_.precision));
}

void Long3rNodelet::advertise() {
  ros::NodeHandle& nh = getNodeHandle();
  ros::NodeHandle& pnh = getPrivateNodeHandle();
  // Per-frame outputs queue a few messages for subscribers that lag a frame
  // or two (a Python node under load); the map is latched, newest only.
  frame_cloud_pub_ = pnh.advertise<sensor_msgs::PointCloud2>("frame_cloud", 5);
  pointmap_pub_ = pnh.advertise<Pointmap>("pointmap", 5);
  map_pub_ = pnh.advertise<sensor_msgs::PointCloud2>("map", 1, /*latch=*/true);
  pose_pub_ = pnh.advertise<geometry_msgs::PoseStamped>("pose", 10);
  path_pub_ = pnh.advertise<nav_msgs::Path>("path", 1, /*latch=*/true);
  camera_info_pub_ = pnh.advertise<sensor_msgs::CameraInfo>("camera_info", 10);
  depth_pub_ = pnh.advertise<sensor_msgs::Image>("depth", 5);
  odometry_pub_ = pnh.advertise<nav_msgs::Odometry>("odometry", 10);
  reset_srv_ = pnh.advertiseService("reset", &Long3rNodelet::resetService, this);
  pause_srv_ = pnh.advertiseService("pause", &Long3rNodelet::pauseService, this);
  resume_srv_ = pnh.advertiseService("resume", &Long3rNodelet::resumeService, this);
  save_map_srv_ = pnh.advertiseService("save_map", &Long3rNodelet::saveMapService, this);
  save_trajectory_srv_ =
      pnh.advertiseService("save_trajectory", &Long3rNodelet::saveTrajectoryService, this);
  map_timer_ = nh.createWallTimer(ros::WallDuration(config_.map_publish_period_s),
                                  &Long3rNodelet::mapTimerCallback, this);
  if (config_.publish_tf && !frames_config_.odom_frame.empty()) {
    tf_timer_ = nh.createTimer(ros::Duration(0.05), &Long3rNodelet::tfTimerCallback, this);
  }

  diagnostics_ = std::make_unique<diagnostic_updater::Updater>(nh, pnh, getName());
  diagnostics_->setHardwareID("long3r");
  diagnostics_->add("reconstruction", this, &Long3rNodelet::diagnose);
  min_rate_hz_ = 0.0;
  max_rate_hz_ = std::numeric_limits<double>::infinity();
  output_diagnostic_ = std::make_unique<diagnostic_updater::TopicDiagnostic>(
      "pointmap", *diagnostics_,
      diagnostic_updater::FrequencyStatusParam(&min_rate_hz_, &max_rate_hz_, 0.1, 5),
      diagnostic_updater::TimeStampStatusParam(-1.0, config_.max_latency_s));
}

void Long3rNodelet::subscribe() {
  ros::NodeHandle& nh = getNodeHandle();
  ros::NodeHandle& pnh = getPrivateNodeHandle();
  // The worker pairs each queued image with the camera_info and depth of its
  // stamp, so the caches reach back as far as the image queue does.
  const auto reach = static_cast<unsigned>(config_.queue_size) + kCacheMargin;
  camera_info_cache_.setCacheSize(reach);
  depth_cache_.setCacheSize(reach);
  if (config_.use_camera_info) {
    camera_info_sub_ = nh.subscribe("camera_info", 10, &Long3rNodelet::cameraInfoCallback, this);
  }
  if (scale_config_.source == long3r::ScaleSource::kDepth) {
    depth_sub_ = nh.subscribe("depth", kSubscriberQueue, &Long3rNodelet::depthCallback, this);
    NODELET_INFO("metric scale from the depth images on %s", depth_sub_.getTopic().c_str());
  }
  it_ = std::make_unique<image_transport::ImageTransport>(nh);
  const std::vector<std::string> loadable = it_->getLoadableTransports();
  const bool installed = std::find(loadable.begin(), loadable.end(),
                                   "image_transport/" + config_.image_transport) != loadable.end();
  if (!installed && config_.image_transport == "compressed") {
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
    const std::string what = "image_transport '" + config_.image_transport +
                             "' is not installed (installed: " + names + ")";
    logFatal(getName(), what);
    throw std::runtime_error(what);
  }
  image_sub_ = it_->subscribe(
      "image", kSubscriberQueue, &Long3rNodelet::imageCallback, this,
      image_transport::TransportHints(config_.image_transport, ros::TransportHints(), pnh));
  NODELET_INFO("subscribed to %s (transport %s)", image_sub_.getTopic().c_str(),
               config_.image_transport.c_str());
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

void Long3rNodelet::cameraInfoCallback(const sensor_msgs::CameraInfoConstPtr& msg) {
  camera_info_cache_.add(msg);  // validated by the worker, with the image it calibrates
}

void Long3rNodelet::depthCallback(const sensor_msgs::ImageConstPtr& msg) {
  depth_cache_.add(msg);  // read by the worker with the result of the image of its stamp
}

void Long3rNodelet::tfTimerCallback(const ros::TimerEvent&) {
  std::optional<geometry_msgs::TransformStamped> t;
  {
    std::lock_guard<std::mutex> lock(state_mutex_);
    t = last_map_odom_;
  }
  if (!t) return;
  // map -> odom is a slowly changing correction: kept valid at the current
  // time, so that map -> base resolves at the odometry's latest stamps.
  t->header.stamp = ros::Time::now();
  tf_broadcaster_.sendTransform(*t);
}

// ---------------------------------------------------------------- worker

void Long3rNodelet::workerLoop() {
  const long3r::ThreadState threads = long3r::apply_thread_config(thread_config_);
  NODELET_INFO("worker thread running with %s", long3r::describe(threads).c_str());
  auto last_frame = std::chrono::steady_clock::now();
  while (running_) {
    std::optional<InputFrame> frame = queue_->pop(std::chrono::milliseconds(50));
    if (!frame) {
      const double idle_s =
          std::chrono::duration<double>(std::chrono::steady_clock::now() - last_frame).count();
      if (idle_s >= config_.flush_after_s) flushPending();
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
  const double stamp_s = frame.header().stamp.toSec();
  DecodedImage decoded;
  try {
    decoded = decodeInput(frame, static_cast<std::uint64_t>(config_.max_image_pixels));
  } catch (const InputError& e) {
    ++frames_dropped_input_;
    window_.failed();
    warnThrottled(e.kind(), format("frame at t=%.3f skipped: ", stamp_s) + e.what());
    return;
  }

  StreamMonitor::Decision d;
  std::optional<std::pair<InputFrame, DecodedImage>> held;
  {
    std::lock_guard<std::mutex> lock(recon_mutex_);
    d = monitor_.check(stamp_s, frame.arrival.toSec(), decoded.image.cols, decoded.image.rows);
    if (d.held != StreamMonitor::Held::kNone) held.swap(held_);
    if (d.action == StreamMonitor::Action::kHold) held_.emplace(frame, decoded);
  }
  if (held && d.held == StreamMonitor::Held::kProcess) {
    processFrame(held->first, held->second);
  } else if (held) {
    ++frames_dropped_input_;
    window_.dropped();
    warnThrottled("outlier stamp", format("frame at t=%.3f dropped: its stamp was far ahead of the "
                                          "frames around it (max_stamp_jump_s)",
                                          held->first.header().stamp.toSec()));
  }

  using A = StreamMonitor::Action;
  switch (d.action) {
    case A::kProcess:
      processFrame(frame, decoded);
      return;
    case A::kNewStreamTimeBackwards:
    case A::kNewStreamSizeChanged:
      flushPending();  // the old stream's last frame is published, not lost
      {
        std::lock_guard<std::mutex> lock(recon_mutex_);
        resetStream(format("frame at t=%.3f: ", stamp_s) + StreamMonitor::describe(d.action));
      }
      processFrame(frame, decoded);
      return;
    case A::kHold:
      warnThrottled("stamp jump",
                    format("frame at t=%.3f: its stamp ran ahead of the clock by more than "
                           "max_stamp_jump_s (%.1f s); held until the next frame shows whether "
                           "time moved on",
                           stamp_s, monitor_config_.max_stamp_jump_s));
      return;
    case A::kDropZeroStamp:
    case A::kDropOutOfOrder:
    case A::kDropStraySize:
      ++frames_dropped_input_;
      window_.dropped();
      warnThrottled(
          StreamMonitor::describe(d.action),
          format("frame at t=%.3f dropped: ", stamp_s) + StreamMonitor::describe(d.action) +
              (d.action == A::kDropStraySize ? " (" + std::to_string(decoded.image.cols) + "x" +
                                                   std::to_string(decoded.image.rows) + ")"
                                             : std::string()));
      return;
  }
}

void Long3rNodelet::processFrame(const InputFrame& frame, const DecodedImage& decoded) {
  std::optional<long3r::FrameResult> result;
  {
    std::lock_guard<std::mutex> lock(recon_mutex_);
    const cv::Mat image = calibrate(frame, decoded.image);
    const std_msgs::Header& header = frame.header();
    // Where the stream sits in the robot's TF tree, fixed by its first frame.
    try {
      if (!frames_->started()) {
        frames_->startStream(header.frame_id, header.stamp);
        NODELET_INFO("frames: %s", frames_->describe().c_str());
      } else if (frames_->followRoot()) {
        NODELET_WARN("frames: the camera frame gained a parent in TF: %s",
                     frames_->describe().c_str());
      }
    } catch (const TfUnavailable& e) {
      ++frames_dropped_input_;
      window_.dropped();
      warnThrottled("tf start", format("frame at t=%.3f skipped: ", header.stamp.toSec()) +
                                    e.what() + "; the stream starts once TF has it");
      return;
    }
    {
      std::lock_guard<std::mutex> state_lock(state_mutex_);
      frames_text_ = frames_->describe();
      T_map_W_ = frames_->T_map_W();
    }
    std::optional<Eigen::Isometry3d> T_W_C;
    if (config_.pose_source == PoseSource::kOdometry) {
      try {
        T_W_C = frames_->cameraFromOdometry(header.stamp);
      } catch (const TfUnavailable& e) {
        ++frames_dropped_input_;
        window_.dropped();
        warnThrottled("tf odometry", format("frame at t=%.3f skipped (pose_source odometry): ",
                                            header.stamp.toSec()) +
                                         e.what());
        return;
      }
      // Odometry places frames in metres: mapping waits for a metric scale.
      recon_->set_mapping(scale_policy_.metric());
    }
    result = recon_->push(image, decoded.encoding, header.stamp.toSec(), T_W_C);
    // Only a frame the model accepted awaits a result.
    pending_.push_back({header, cv::Size(image.cols, image.rows)});
    stream_frames_ = recon_->frames_pushed();
  }
  if (result) publishResult(std::move(*result));
}

// The calibration of this frame: the camera_info with its stamp (else the
// latest before it, else the first after it), validated against the image;
// a valid new one applies from this frame on. Returns the image the model
// sees (rectified when the calibration has distortion).
cv::Mat Long3rNodelet::calibrate(const InputFrame& frame, const cv::Mat& image) {
  if (!config_.use_camera_info) return image;
  if (calibration_.valid() && (calibration_.intrinsics().width != image.cols ||
                               calibration_.intrinsics().height != image.rows)) {
    calibration_ = CameraCalibration();  // of another image size: a new stream began
    recon_->set_calibration(std::nullopt);
  }
  const ros::Time stamp = frame.header().stamp;
  sensor_msgs::CameraInfoConstPtr info;
  const auto exact = camera_info_cache_.getInterval(stamp, stamp);
  if (!exact.empty()) {
    info = exact.back();
  } else if (!(info = camera_info_cache_.getElemBeforeTime(stamp))) {
    info = camera_info_cache_.getElemAfterTime(stamp);
  }
  if (info) {
    const std::string problem = CameraCalibration::problem(*info, image.cols, image.rows);
    if (!problem.empty()) {
      calibration_problem_ = problem;
      warnThrottled(
          "camera_info " + problem,
          "camera_info not used: " + problem +
              (calibration_.valid() ? "; keeping the last valid calibration"
                                    : "; the focal length is estimated from the images instead"));
    } else {
      calibration_problem_.clear();
      const bool first = !calibration_.valid();
      if (calibration_.set(*info, config_.image_is_rectified)) {
        NODELET_INFO("camera calibration %s: %s", first ? "from camera_info" : "changed",
                     calibration_.describe().c_str());
        recon_->set_calibration(calibration_.intrinsics());
      }
    }
  }
  {
    std::lock_guard<std::mutex> lock(state_mutex_);
    calibration_text_ = calibration_problem_.empty()
                            ? calibration_.describe()
                            : "camera_info not used: " + calibration_problem_;
  }
  return calibration_.prepare(image);
}

void Long3rNodelet::flushPending() {
  std::optional<long3r::FrameResult> result;
  {
    std::lock_guard<std::mutex> lock(recon_mutex_);
    if (pending_.empty()) return;
    try {
      result = recon_->flush();
    } catch (const std::exception& e) {
      ++frames_failed_;
      window_.failed();
      NODELET_ERROR("publishing the pending frame failed: %s", e.what());
      return;
    }
  }
  if (result) publishResult(std::move(*result));
}

void Long3rNodelet::resetStream(const std::string& why) {
  NODELET_WARN("%s: starting a new stream (memory, map and path cleared)", why.c_str());
  recon_->reset();
  pending_.clear();
  held_.reset();
  lost_frames_ = 0;
  lost_frames_diag_ = 0;
  lost_for_s_ = 0.0;
  frames_->reset();
  {
    std::lock_guard<std::mutex> state_lock(state_mutex_);
    last_map_odom_.reset();
  }
  last_body_.reset();
  last_body_cov_.reset();
  startStreamScale();
  path_pub_.publish(pathMessage());
}

void Long3rNodelet::startStreamScale() {
  scale_policy_.reset();
  scale_sampler_->reset();
  recon_->set_scale(scale_policy_.applied());  // fixed: the given scale; otherwise 1
  recon_->set_mapping(true);
  std::lock_guard<std::mutex> state_lock(state_mutex_);
  scale_estimate_ = scale_policy_.estimate();
  scale_in_use_ = scale_policy_.applied();
  scale_metric_ = scale_policy_.metric();
}

nav_msgs::Path Long3rNodelet::pathMessage() {
  nav_msgs::Path path;
  path.header.frame_id = frames_config_.map_frame;
  for (const auto& [stamp, T_W_C] : recon_->trajectory()) {
    geometry_msgs::PoseStamped p;
    p.header.stamp = ros::Time(stamp);
    p.header.frame_id = frames_config_.map_frame;
    p.pose = tf2::toMsg(frames_->bodyInMap(T_W_C));
    path.poses.push_back(p);
  }
  if (!path.poses.empty()) path.header.stamp = path.poses.back().header.stamp;
  return path;
}

// ---------------------------------------------------------------- outputs

void Long3rNodelet::trackLoss(const long3r::FrameResult& r) {
  std::lock_guard<std::mutex> lock(recon_mutex_);
  if (r.pose.ok()) {
    if (lost_frames_ > 0) {
      NODELET_INFO("tracking recovered at frame %ld after %d unposed frame(s)",
                   static_cast<long>(r.frame_index), lost_frames_);
    }
    lost_frames_ = 0;
  } else {
    if (lost_frames_++ == 0) lost_since_stamp_ = r.stamp;
    warnThrottled("pose", "frame " + std::to_string(r.frame_index) + ": pose estimation failed (" +
                              r.pose.message + "); not added to the map (tracking lost for " +
                              std::to_string(lost_frames_) + " frame(s))");
    if (config_.lost_reset_frames > 0 && lost_frames_ >= config_.lost_reset_frames) {
      resetStream("tracking lost for " + std::to_string(lost_frames_) +
                  " consecutive frames (lost_reset_frames)");
    }
  }
  lost_frames_diag_ = lost_frames_;
  lost_for_s_ = lost_frames_ > 0 ? r.stamp - lost_since_stamp_ : 0.0;
  std::lock_guard<std::mutex> text_lock(state_mutex_);
  tracking_text_ = lost_frames_ > 0 ? "lost" : "ok";
}

void Long3rNodelet::publishResult(long3r::FrameResult r) {
  // A frame that finishes while the node shuts down has no one to go to, and
  // ROS's publishers may already be torn down.
  if (!running_ || !ros::ok()) return;
  std_msgs::Header header;
  cv::Size pushed_size;
  {
    std::lock_guard<std::mutex> lock(recon_mutex_);
    // Results come back in push order: the oldest pending frame is this one.
    if (pending_.empty()) return;
    header = pending_.front().header;
    pushed_size = pending_.front().size;
    pending_.pop_front();
  }
  if (!frames_config_.camera_frame.empty()) header.frame_id = frames_config_.camera_frame;
  ++frames_processed_;
  window_.processed((ros::Time::now() - header.stamp).toSec());
  output_diagnostic_->tick(header.stamp);
  mem_short_ = r.model.mem_short_tokens;
  mem_long_ = r.model.mem_long_tokens;
  mem_relevant_ = r.model.relevant_tokens;

  if (r.intrinsics.fx > 0.0) {
    const std::string line =
        r.intrinsics_source == long3r::IntrinsicsSource::kCalibration
            ? format("from camera_info: fx %.2f, fy %.2f px", r.intrinsics.fx, r.intrinsics.fy) +
                  format(", cx %.2f, cy %.2f at model resolution", r.intrinsics.cx, r.intrinsics.cy)
            : format(
                  "estimated from the first frame (no usable camera_info): focal %.2f px at "
                  "model resolution",
                  r.intrinsics.fx);
    if (line != intrinsics_logged_) {
      NODELET_INFO("intrinsics in use %s", line.c_str());
      intrinsics_logged_ = line;
    }
  }
  trackLoss(r);
  if (r.pose.ok()) updateScale(r, header, pushed_size);
  publishOutputs(r, header);
}

// This frame's sample of the metric scale, and the scale itself when the
// policy applies one: the stream is rescaled, and so is this result.
void Long3rNodelet::updateScale(long3r::FrameResult& r, const std_msgs::Header& header,
                                const cv::Size& image_size) {
  std::optional<double> sample;
  if (scale_config_.source == long3r::ScaleSource::kDepth) {
    sample = depthScaleSample(r, header, image_size);
  } else if (scale_config_.source == long3r::ScaleSource::kOdometry) {
    try {
      const Eigen::Vector3d odom = frames_->cameraInOdom(header.stamp).translation();
      const Eigen::Vector3d model = r.model_T_W_C.translation() / r.scale;
      sample = scale_sampler_->add(odom, model);
    } catch (const TfUnavailable& e) {
      warnThrottled("tf scale", std::string("odometry scale: ") + e.what());
    }
  }
  std::optional<double> scale;
  long3r::ScaleEstimate e;
  {
    std::lock_guard<std::mutex> lock(recon_mutex_);
    if (sample) scale_policy_.add_sample(*sample);
    scale = scale_policy_.scale_to_apply();
    e = scale_policy_.estimate();
    if (scale) {
      recon_->set_scale(*scale);
      recon_->set_mapping(true);
    }
    std::lock_guard<std::mutex> state_lock(state_mutex_);
    scale_estimate_ = e;
    scale_in_use_ = scale_policy_.applied();
    scale_metric_ = scale_policy_.metric();
  }
  if (!scale) return;
  NODELET_INFO(
      "metric scale %.4f +- %.4f m per model unit from %d samples (%s, %d rejected): "
      "map and path rescaled",
      e.scale, e.stddev, e.samples, long3r::config::enum_name(scale_config_.source), e.rejected);
  long3r::Reconstruction::rescale(r, *scale);
  last_body_.reset();  // the previous pose was in the old scale
}

// measured / predicted depth for this frame (metric_scale.hpp), with the
// depth image of its stamp (exact, else within 20 ms).
std::optional<double> Long3rNodelet::depthScaleSample(const long3r::FrameResult& r,
                                                      const std_msgs::Header& header,
                                                      const cv::Size& image_size) {
  sensor_msgs::ImageConstPtr depth;
  for (const auto& d : depth_cache_.getSurroundingInterval(header.stamp, header.stamp)) {
    if (std::abs((d->header.stamp - header.stamp).toSec()) <= 0.02 &&
        (!depth || std::abs((d->header.stamp - header.stamp).toSec()) <
                       std::abs((depth->header.stamp - header.stamp).toSec()))) {
      depth = d;
    }
  }
  if (!depth) {
    warnThrottled("depth missing", format("no depth image within 20 ms of the frame at t=%.3f "
                                          "(scale_source depth)",
                                          header.stamp.toSec()));
    return std::nullopt;
  }
  cv::Mat metres;
  try {
    const cv_bridge::CvImageConstPtr d = cv_bridge::toCvShare(depth);
    if (depth->encoding == sensor_msgs::image_encodings::TYPE_16UC1) {
      d->image.convertTo(metres, CV_32FC1, 0.001);  // millimetres, as RGB-D drivers publish
      metres.setTo(std::numeric_limits<float>::quiet_NaN(), d->image == 0);
    } else if (depth->encoding == sensor_msgs::image_encodings::TYPE_32FC1) {
      metres = d->image;
    } else {
      throw std::invalid_argument("encoding '" + depth->encoding + "' (16UC1 mm or 32FC1 m)");
    }
  } catch (const std::exception& e) {
    warnThrottled("depth encoding", std::string("depth image not used: ") + e.what());
    return std::nullopt;
  }
  if (metres.size() == image_size) {
    std::lock_guard<std::mutex> lock(recon_mutex_);
    // Registered to the raw image: rectified as the image was, without blending depths.
    if (calibration_.rectifies()) metres = calibration_.prepare(metres, cv::INTER_NEAREST);
  }
  if (metres.size() != image_size) {
    warnThrottled("depth size", "depth image of " + std::to_string(metres.cols) + "x" +
                                    std::to_string(metres.rows) +
                                    " is not registered to the images (" +
                                    std::to_string(image_size.width) + "x" +
                                    std::to_string(image_size.height) + ")");
    return std::nullopt;
  }
  const long3r::ResizeCropPlan plan =
      long3r::plan_resize_crop(metres.cols, metres.rows, recon_config_.preprocess);
  const cv::Mat measured =
      long3r::depth_at_model_pixels(metres, plan.model_to_source, r.conf.cols, r.conf.rows);
  std::vector<cv::Mat> xyz;
  cv::split(r.points_C, xyz);
  const cv::Mat predicted = xyz[2] / r.scale;  // model units
  return long3r::depth_scale_sample(predicted, measured, r.conf, recon_config_.conf_threshold);
}

void Long3rNodelet::publishOutputs(const long3r::FrameResult& r, const std_msgs::Header& header) {
  const int h = r.conf.rows, w = r.conf.cols;
  const sensor_msgs::CameraInfo info = toCameraInfo(r.intrinsics.fx, r.intrinsics.fy,
                                                    r.intrinsics.cx, r.intrinsics.cy, w, h, header);
  // ~camera_info goes with every result, posed or not (depth_image_proc pairs it with ~depth).
  camera_info_pub_.publish(info);
  if (!r.pose.ok() || r.points_C.empty()) return;

  const Eigen::Isometry3d& T_map_W = frames_->T_map_W();
  const Eigen::Isometry3d T_map_cam = T_map_W * r.pose.T_W_C;
  const Eigen::Isometry3d T_map_body = frames_->bodyInMap(r.pose.T_W_C);
  const bool metric = scale_policy_.metric();
  if (depth_pub_.getNumSubscribers() > 0 || frame_cloud_pub_.getNumSubscribers() > 0) {
    const sensor_msgs::ImagePtr depth =
        toDepthImage(r.points_C, r.conf, recon_config_.conf_threshold, header);
    if (depth_pub_.getNumSubscribers() > 0) depth_pub_.publish(depth);
    if (frame_cloud_pub_.getNumSubscribers() > 0) {
      frame_cloud_pub_.publish(toFrameCloud(depth, info, r.conf, r.rgb));
    }
  }
  if (pointmap_pub_.getNumSubscribers() > 0) {
    Pointmap pm;
    pm.header = header;
    pm.height = static_cast<std::uint32_t>(h);
    pm.width = static_cast<std::uint32_t>(w);
    pm.frame_index = static_cast<std::uint32_t>(r.frame_index);
    const cv::Mat pts = r.points_C.isContinuous() ? r.points_C : r.points_C.clone();
    const cv::Mat conf = r.conf.isContinuous() ? r.conf : r.conf.clone();
    pm.points.assign(pts.ptr<float>(), pts.ptr<float>() + static_cast<std::size_t>(h) * w * 3);
    pm.confidence.assign(conf.ptr<float>(), conf.ptr<float>() + static_cast<std::size_t>(h) * w);
    pm.map_frame_id = frames_config_.map_frame;
    pm.T_W_C = tf2::toMsg(T_map_cam);
    pm.fx = r.intrinsics.fx;
    pm.fy = r.intrinsics.fy;
    pm.cx = r.intrinsics.cx;
    pm.cy = r.intrinsics.cy;
    pm.scale = r.scale;
    pm.scale_stddev = metric ? scale_policy_.estimate().stddev : 0.0;
    pm.metric = metric;
    pointmap_pub_.publish(pm);
  }

  geometry_msgs::PoseStamped pose;
  pose.header.stamp = header.stamp;
  pose.header.frame_id = frames_config_.map_frame;
  pose.pose = tf2::toMsg(T_map_body);
  pose_pub_.publish(pose);

  nav_msgs::Odometry odom;
  odom.header = pose.header;
  odom.child_frame_id = frames_->bodyFrame();
  odom.pose.pose = pose.pose;
  std::optional<Eigen::Matrix<double, 6, 6>> cov_map;
  if (r.pose.covariance) {
    const std::array<double, 36> c = poseCovarianceInMap(
        *r.pose.covariance, T_map_W.linear(), T_map_body.translation() - T_map_cam.translation());
    std::copy(c.begin(), c.end(), odom.pose.covariance.begin());
    cov_map =
        Eigen::Map<const Eigen::Matrix<double, 6, 6, Eigen::RowMajor>>(odom.pose.covariance.data());
  }
  if (last_body_ && last_body_cov_ && cov_map && header.stamp.toSec() > last_body_->second) {
    // Twist in the body frame by finite difference; its covariance from the
    // two poses' (taken as independent), rotated into the body frame.
    const double dt = header.stamp.toSec() - last_body_->second;
    const Eigen::Isometry3d delta = last_body_->first.inverse() * T_map_body;
    const Eigen::AngleAxisd aa(delta.rotation());
    const Eigen::Vector3d v = delta.translation() / dt, wv = aa.angle() * aa.axis() / dt;
    tf2::toMsg(v, odom.twist.twist.linear);
    odom.twist.twist.angular.x = wv.x();
    odom.twist.twist.angular.y = wv.y();
    odom.twist.twist.angular.z = wv.z();
    Eigen::Matrix<double, 6, 6> R = Eigen::Matrix<double, 6, 6>::Zero();
    R.topLeftCorner<3, 3>() = T_map_body.linear().transpose();
    R.bottomRightCorner<3, 3>() = T_map_body.linear().transpose();
    const Eigen::Matrix<double, 6, 6> tc =
        R * (*cov_map + *last_body_cov_) * R.transpose() / (dt * dt);
    Eigen::Map<Eigen::Matrix<double, 6, 6, Eigen::RowMajor>>(odom.twist.covariance.data()) =
        0.5 * (tc + tc.transpose());
  }
  if (cov_map) odometry_pub_.publish(odom);
  last_body_ = std::make_pair(T_map_body, header.stamp.toSec());
  last_body_cov_ = cov_map;

  nav_msgs::Path path;
  {
    std::lock_guard<std::mutex> lock(recon_mutex_);
    path = pathMessage();
  }
  path_pub_.publish(path);

  if (config_.publish_tf) {
    try {
      if (const auto t = frames_->transformFor(r.pose.T_W_C, header.stamp)) {
        tf_broadcaster_.sendTransform(*t);
        if (frames_->mode() == RobotFrames::Mode::kMapToOdom) {
          std::lock_guard<std::mutex> lock(state_mutex_);
          last_map_odom_ = *t;
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
  if (!recon_) return;
  const std::uint64_t revision = recon_->map().revision();
  if (revision == last_map_revision_) return;  // republish only when the map changed
  last_map_revision_ = revision;
  long3r::MapSnapshot snap = recon_->map().snapshot();
  Eigen::Isometry3f T_map_W;
  {
    std::lock_guard<std::mutex> lock(state_mutex_);
    T_map_W = T_map_W_.cast<float>();
  }
  for (Eigen::Vector3f& p : snap.points) p = T_map_W * p;
  std_msgs::Header header;
  header.stamp = ros::Time::now();
  header.frame_id = frames_config_.map_frame;
  map_pub_.publish(toColoredCloud(snap.points, snap.colors, header));
}

// ---------------------------------------------------------------- services

bool Long3rNodelet::resetService(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
  {
    std::lock_guard<std::mutex> lock(recon_mutex_);
    monitor_.reset();
    resetStream("reset requested");
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
    long3r::MapSnapshot snap = recon_->map().snapshot();  // the map locks itself
    Eigen::Isometry3f T_map_W;
    {
      std::lock_guard<std::mutex> lock(state_mutex_);
      T_map_W = T_map_W_.cast<float>();
    }
    for (Eigen::Vector3f& p : snap.points) p = T_map_W * p;          // as ~map shows it
    long3r::save_colored_cloud(req.path, snap.points, snap.colors);  // atomic
    res.success = true;
    res.message = "wrote " + std::to_string(snap.points.size()) + " points (" +
                  frames_config_.map_frame + ") to " + req.path;
  } catch (const std::exception& e) {
    res.success = false;
    res.message = e.what();
  }
  return true;
}

bool Long3rNodelet::saveTrajectoryService(SaveTrajectory::Request& req,
                                          SaveTrajectory::Response& res) {
  long3r::PoseTrajectory trajectory;
  std::string what;
  {
    std::lock_guard<std::mutex> lock(recon_mutex_);
    for (const auto& [stamp, T_W_C] : recon_->trajectory()) {
      trajectory.stamps.push_back(stamp);
      trajectory.poses.push_back(frames_->bodyInMap(T_W_C));
    }
    what = "poses of " + frames_->bodyFrame() + " in " + frames_config_.map_frame;
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
  using S = diagnostic_msgs::DiagnosticStatus;
  const WindowStats::Counts w = window_.window();
  window_.rotate();
  const double last_input = last_input_wall_s_;
  const double quiet_s = wallNow() - (last_input > 0.0 ? last_input : started_.toSec());
  std::string tracking, calibration;
  {
    std::lock_guard<std::mutex> lock(state_mutex_);
    tracking = tracking_text_;
    calibration = calibration_text_;
  }
  const int lost = lost_frames_diag_;

  if (paused_) {
    stat.summary(S::OK, "paused (~resume to continue)");
  } else if (quiet_s > config_.no_input_warn_s) {
    stat.summaryf(S::WARN, last_input > 0.0 ? "no input for %.0f s" : "no image received in %.0f s",
                  quiet_s);
  } else if (lost > 0) {
    stat.summaryf(S::WARN, "tracking lost for %d frame(s) (%.1f s)", lost, lost_for_s_.load());
  } else if (calibration.rfind("camera_info not used", 0) == 0) {
    stat.summary(S::WARN, calibration);
  } else if (w.dropped + w.failed > 0) {
    stat.summaryf(S::WARN, "dropped %lu and failed %lu frame(s) in the window",
                  static_cast<unsigned long>(w.dropped), static_cast<unsigned long>(w.failed));
  } else {
    stat.summary(S::OK, "running");
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
  stat.addf("seconds since the last image", "%.1f", quiet_s);
  stat.add("paused", static_cast<bool>(paused_));
  stat.add("tracking", tracking);
  stat.add("tracking lost (frames)", lost);
  stat.addf("tracking lost (s)", "%.1f", lost_for_s_.load());
  stat.add("calibration", calibration);
  {
    std::lock_guard<std::mutex> lock(state_mutex_);
    stat.add("frames", frames_text_);
  }
  {
    std::lock_guard<std::mutex> lock(state_mutex_);
    const long3r::ScaleEstimate& e = scale_estimate_;
    stat.add("scale source", long3r::config::enum_name(scale_config_.source));
    stat.addf("scale in use (m per model unit)", "%.6g", scale_in_use_);
    stat.add("scale metric", scale_metric_);
    stat.addf("scale estimate", "%.6g +- %.3g (%d samples, %d rejected)", e.scale, e.stddev,
              e.samples, e.rejected);
  }
  stat.add("stream frames", stream_frames_.load());
  stat.add("memory tokens short", mem_short_.load());
  stat.add("memory tokens long", mem_long_.load());
  stat.add("relevant tokens", mem_relevant_.load());
  stat.add("map points", recon_ ? recon_->map().size() : 0);
  stat.add("frames received (total)", frames_received_.load());
  stat.add("frames processed (total)", frames_processed_.load());
  stat.add("frames failed (total)", frames_failed_.load());
  stat.add("frames dropped: bad input (total)", frames_dropped_input_.load());
  stat.add("frames dropped: queue full (total)", queue_ ? queue_->dropped() : 0);
  stat.add("frames dropped: paused (total)", frames_dropped_paused_.load());
}

void Long3rNodelet::shutdown() {
  if (!running_.exchange(false)) return;
  // Every way into this object from the manager's callback threads is closed
  // (and waited for: roscpp blocks until a running callback returns) before
  // the worker stops and members start to be destroyed; a service or timer
  // callback running into a half-destroyed nodelet is undefined behaviour.
  image_sub_.shutdown();
  compressed_sub_.shutdown();
  camera_info_sub_.shutdown();
  depth_sub_.shutdown();
  tf_timer_.stop();
  reset_srv_.shutdown();
  pause_srv_.shutdown();
  resume_srv_.shutdown();
  save_map_srv_.shutdown();
  save_trajectory_srv_.shutdown();
  map_timer_.stop();
  if (queue_) queue_->close();
  if (worker_.joinable()) worker_.join();
  diagnostics_.reset();
  output_diagnostic_.reset();
}

}  // namespace long3r_ros

PLUGINLIB_EXPORT_CLASS(long3r_ros::Long3rNodelet, nodelet::Nodelet)

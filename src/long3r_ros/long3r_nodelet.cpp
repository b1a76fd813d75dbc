#include "long3r_ros/long3r_nodelet.hpp"

#include <cv_bridge/cv_bridge.h>
#include <geometry_msgs/PoseStamped.h>
#include <geometry_msgs/TransformStamped.h>
#include <ros/package.h>
#include <sensor_msgs/image_encodings.h>
#include <pluginlib/class_list_macros.hpp>

#include <chrono>
#include <fstream>

#include "long3r/model/inference.hpp"
#include "long3r_ros/Pointmap.h"
#include "long3r_ros/conversions.hpp"

namespace long3r_ros {

namespace {

bool supportedEncoding(const std::string& enc) {
  namespace e = sensor_msgs::image_encodings;
  return enc == e::RGB8 || enc == e::BGR8 || enc == e::RGBA8 || enc == e::BGRA8 ||
         enc == e::MONO8 || enc == e::MONO16;
}

std::string defaultModelPath() {
  const std::string pkg = ros::package::getPath("long3r_ros");
  return pkg.empty() ? std::string() : pkg + "/models/default.safetensors";
}

}  // namespace

Long3rNodelet::~Long3rNodelet() { shutdown(); }

void Long3rNodelet::onInit() {
  ros::NodeHandle& nh = getNodeHandle();
  ros::NodeHandle& pnh = getPrivateNodeHandle();
  try {
    config_ = readNodeletConfig(pnh);
    thread_config_ = readThreadConfig(pnh);
    inference_config_ = readInferenceConfig(pnh);
    recon_config_ = readReconstructionConfig(pnh);
  } catch (const ParamError& e) {
    NODELET_FATAL("invalid configuration: %s", e.what());
    throw;
  }
  NODELET_INFO_STREAM("configuration:\n"
                      << describe(config_) << "\n"
                      << describe(thread_config_) << "\n"
                      << describe(inference_config_) << "\n"
                      << describe(recon_config_));

  // A missing or bad model must stop the nodelet here, with the reason.
  const std::string model_path =
      config_.model_path.empty() ? defaultModelPath() : config_.model_path;
  try {
    if (model_path.empty() || !std::ifstream(model_path).good()) {
      throw std::runtime_error("model file '" + model_path +
                               "' does not exist or is not readable (set ~model_path)");
    }
    recon_ = std::make_unique<long3r::Reconstruction>(
        long3r::make_streaming_model(model_path, inference_config_), recon_config_);
  } catch (const long3r::InferenceUnsupportedError& e) {
    NODELET_FATAL("cannot run the model as configured (~device, ~precision): %s", e.what());
    throw;
  } catch (const std::exception& e) {
    NODELET_FATAL("cannot load the model: %s", e.what());
    throw;
  }
  NODELET_INFO("model loaded from %s, running on %s in %s", model_path.c_str(),
               inference_config_.device.c_str(),
               long3r::config::enum_name(inference_config_.precision));

  frame_cloud_pub_ = pnh.advertise<sensor_msgs::PointCloud2>("frame_cloud", 2);
  pointmap_pub_ = pnh.advertise<Pointmap>("pointmap", 2);
  map_pub_ = pnh.advertise<sensor_msgs::PointCloud2>("map", 1, /*latch=*/true);
  pose_pub_ = pnh.advertise<geometry_msgs::PoseStamped>("pose", 10);
  path_pub_ = pnh.advertise<nav_msgs::Path>("path", 1, /*latch=*/true);
  camera_info_pub_ = pnh.advertise<sensor_msgs::CameraInfo>("camera_info", 2);
  reset_srv_ = pnh.advertiseService("reset", &Long3rNodelet::resetService, this);
  save_map_srv_ = pnh.advertiseService("save_map", &Long3rNodelet::saveMapService, this);
  map_timer_ = nh.createWallTimer(ros::WallDuration(config_.map_publish_period_s),
                                  &Long3rNodelet::mapTimerCallback, this);

  diagnostics_ = std::make_unique<diagnostic_updater::Updater>(nh, pnh, getName());
  diagnostics_->setHardwareID("long3r");
  diagnostics_->add("reconstruction", this, &Long3rNodelet::diagnose);
  stats_since_ = ros::WallTime::now();

  path_.header.frame_id = config_.world_frame;
  queue_ = std::make_unique<long3r::BoundedQueue<sensor_msgs::ImageConstPtr>>(
      static_cast<std::size_t>(config_.queue_size));
  running_ = true;
  worker_ = std::thread(&Long3rNodelet::workerLoop, this);

  if (config_.use_camera_info) {
    camera_info_sub_ = nh.subscribe("camera_info", 2, &Long3rNodelet::cameraInfoCallback, this);
  }
  it_ = std::make_unique<image_transport::ImageTransport>(nh);
  image_sub_ = it_->subscribe(
      "image", 5, &Long3rNodelet::imageCallback, this,
      image_transport::TransportHints(config_.image_transport, ros::TransportHints(), pnh));
  NODELET_INFO("subscribed to %s (transport %s)", image_sub_.getTopic().c_str(),
               config_.image_transport.c_str());
}

void Long3rNodelet::imageCallback(const sensor_msgs::ImageConstPtr& msg) {
  // Only enqueue: the worker does all conversion and model work.
  ++frames_received_;
  if (queue_->push(msg)) {
    NODELET_WARN_THROTTLE(5.0, "input queue full (size %zu): dropped %lu frame(s) so far",
                          queue_->capacity(), static_cast<unsigned long>(queue_->dropped()));
  }
}

void Long3rNodelet::cameraInfoCallback(const sensor_msgs::CameraInfoConstPtr& msg) {
  if (msg->K[0] <= 0.0 || msg->K[4] <= 0.0 || msg->width == 0 || msg->height == 0) {
    NODELET_WARN_THROTTLE(10.0, "ignoring camera_info without valid intrinsics");
    return;
  }
  long3r::PinholeIntrinsics k;
  k.fx = msg->K[0];
  k.fy = msg->K[4];
  k.cx = msg->K[2];
  k.cy = msg->K[5];
  k.width = static_cast<int>(msg->width);
  k.height = static_cast<int>(msg->height);
  std::lock_guard<std::mutex> lock(camera_info_mutex_);
  calibration_ = k;
}

void Long3rNodelet::workerLoop() {
  const int threads = long3r::apply_thread_config(thread_config_);
  NODELET_INFO("worker thread running with %d torch thread(s)", threads);
  auto last_frame = std::chrono::steady_clock::now();
  while (running_) {
    auto msg = queue_->pop(std::chrono::milliseconds(50));
    if (!msg) {
      const double idle_s =
          std::chrono::duration<double>(std::chrono::steady_clock::now() - last_frame).count();
      if (idle_s >= config_.flush_after_s) flushPending();
      continue;
    }
    last_frame = std::chrono::steady_clock::now();
    try {
      processFrame(*msg);
    } catch (const std::exception& e) {
      // Bad input or a failure in one frame must never take the node down.
      ++frames_failed_;
      NODELET_ERROR_THROTTLE(5.0, "frame at t=%.3f skipped: %s", (*msg)->header.stamp.toSec(),
                             e.what());
    }
  }
}

void Long3rNodelet::processFrame(const sensor_msgs::ImageConstPtr& msg) {
  if (!supportedEncoding(msg->encoding)) {
    NODELET_ERROR_THROTTLE(5.0,
                           "unsupported image encoding '%s' (supported: rgb8, bgr8, rgba8, "
                           "bgra8, mono8, mono16); frame skipped",
                           msg->encoding.c_str());
    ++frames_failed_;
    return;
  }
  cv_bridge::CvImageConstPtr image = cv_bridge::toCvShare(msg);
  if (image->image.empty()) throw std::runtime_error("empty image");

  const double stamp_s = msg->header.stamp.toSec();
  const int width = static_cast<int>(msg->width), height = static_cast<int>(msg->height);
  StreamMonitor::Decision decision;
  {
    std::lock_guard<std::mutex> lock(recon_mutex_);
    decision = monitor_.check(stamp_s, width, height);
  }
  if (decision == StreamMonitor::Decision::kResetSizeChanged ||
      decision == StreamMonitor::Decision::kResetTimeBackwards) {
    flushPending();  // the old stream's last frame is published, not lost
    std::lock_guard<std::mutex> lock(recon_mutex_);
    resetStream(StreamMonitor::describe(decision));
    monitor_.check(stamp_s, width, height);
  }

  std::optional<long3r::FrameResult> result;
  {
    std::lock_guard<std::mutex> lock(recon_mutex_);
    if (recon_->frames_pushed() == 0) {
      std::lock_guard<std::mutex> info_lock(camera_info_mutex_);
      std::optional<long3r::PinholeIntrinsics> calib;
      if (calibration_ && calibration_->width == static_cast<int>(msg->width) &&
          calibration_->height == static_cast<int>(msg->height)) {
        calib = calibration_;
      } else if (calibration_) {
        NODELET_WARN_THROTTLE(10.0,
                              "camera_info is %dx%d but images are %ux%u: estimating the focal "
                              "length instead",
                              calibration_->width, calibration_->height, msg->width, msg->height);
      }
      recon_->set_calibration(calib);
    }
    std_msgs::Header header = msg->header;
    if (!config_.camera_frame.empty()) header.frame_id = config_.camera_frame;
    result = recon_->push(image->image, msg->encoding, stamp_s);
    // Only a frame the model accepted awaits a result.
    pending_headers_.push_back(header);
  }
  if (result) publishResult(*result);
}

void Long3rNodelet::flushPending() {
  std::optional<long3r::FrameResult> result;
  {
    std::lock_guard<std::mutex> lock(recon_mutex_);
    if (pending_headers_.empty()) return;
    try {
      result = recon_->flush();
    } catch (const std::exception& e) {
      ++frames_failed_;
      NODELET_ERROR("flushing the last frame failed: %s", e.what());
      pending_headers_.clear();
      return;
    }
  }
  if (result) publishResult(*result);
}

void Long3rNodelet::resetStream(const std::string& why) {
  NODELET_WARN("%s: starting a new stream (memory, map and path cleared)", why.c_str());
  recon_->reset();
  pending_headers_.clear();
  path_.poses.clear();
  monitor_.reset();
}

void Long3rNodelet::publishResult(const long3r::FrameResult& r) {
  // A frame that finishes while the node shuts down has no one to go to, and
  // ROS's publishers may already be torn down.
  if (!running_ || !ros::ok()) return;
  std_msgs::Header header;
  nav_msgs::Path path_copy;
  {
    std::lock_guard<std::mutex> lock(recon_mutex_);
    // Results come back in push order, one frame late: the oldest header is this frame's.
    if (pending_headers_.empty()) return;
    header = pending_headers_.front();
    pending_headers_.pop_front();
  }
  ++frames_processed_;
  last_latency_s_ = (ros::Time::now() - header.stamp).toSec();
  mem_short_ = r.model.mem_short_tokens;
  mem_long_ = r.model.mem_long_tokens;
  mem_relevant_ = r.model.relevant_tokens;

  if (!r.pose.ok()) {
    NODELET_WARN_THROTTLE(5.0, "frame %ld: pose estimation failed (%s); not added to the map",
                          static_cast<long>(r.frame_index), r.pose.message.c_str());
  }
  const Eigen::Isometry3d& T_W_C = r.pose.T_W_C;
  const int h = r.conf.rows, w = r.conf.cols;

  if (camera_info_pub_.getNumSubscribers() > 0) {
    camera_info_pub_.publish(toCameraInfo(r.intrinsics.fx, r.intrinsics.fy, r.intrinsics.cx,
                                          r.intrinsics.cy, w, h, header));
  }
  if (r.pose.ok() && !r.points_C.empty()) {
    if (frame_cloud_pub_.getNumSubscribers() > 0) {
      frame_cloud_pub_.publish(toOrganizedCloud(r.points_C, r.conf, r.rgb, header));
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
      pm.T_W_C = toPoseMsg(T_W_C);
      pm.fx = r.intrinsics.fx;
      pm.fy = r.intrinsics.fy;
      pm.cx = r.intrinsics.cx;
      pm.cy = r.intrinsics.cy;
      pointmap_pub_.publish(pm);
    }
  }
  if (!r.pose.ok()) return;

  geometry_msgs::PoseStamped pose;
  pose.header = header;
  pose.header.frame_id = config_.world_frame;
  pose.pose = toPoseMsg(T_W_C);
  pose_pub_.publish(pose);
  {
    std::lock_guard<std::mutex> lock(recon_mutex_);
    path_.header.stamp = header.stamp;
    path_.poses.push_back(pose);
    path_copy = path_;
  }
  path_pub_.publish(path_copy);

  if (config_.publish_tf) {
    if (header.frame_id.empty()) {
      NODELET_WARN_THROTTLE(10.0, "image has no frame_id and ~camera_frame is empty: no TF");
    } else {
      geometry_msgs::TransformStamped tf;
      tf.header.stamp = header.stamp;
      tf.header.frame_id = config_.world_frame;
      tf.child_frame_id = header.frame_id;
      tf.transform.translation.x = pose.pose.position.x;
      tf.transform.translation.y = pose.pose.position.y;
      tf.transform.translation.z = pose.pose.position.z;
      tf.transform.rotation = pose.pose.orientation;
      tf_broadcaster_.sendTransform(tf);
    }
  }
}

void Long3rNodelet::mapTimerCallback(const ros::WallTimerEvent&) {
  if (diagnostics_) diagnostics_->update();
  if (!recon_) return;
  const std::uint64_t revision = recon_->map().revision();
  if (revision == last_map_revision_) return;  // republish only when the map changed
  last_map_revision_ = revision;
  const long3r::MapSnapshot snap = recon_->map().snapshot();
  std_msgs::Header header;
  header.stamp = ros::Time::now();
  header.frame_id = config_.world_frame;
  map_pub_.publish(toColoredCloud(snap.points, snap.colors, header));
}

bool Long3rNodelet::resetService(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
  {
    std::lock_guard<std::mutex> lock(recon_mutex_);
    resetStream("reset requested");
  }
  queue_->clear();
  path_pub_.publish(path_);
  res.success = true;
  res.message = "memory, map and path cleared";
  return true;
}

bool Long3rNodelet::saveMapService(SaveMap::Request& req, SaveMap::Response& res) {
  try {
    recon_->map().save(req.path);  // the map locks itself; the write is atomic
    res.success = true;
    res.message = "wrote " + std::to_string(recon_->map().size()) + " points to " + req.path;
  } catch (const std::exception& e) {
    res.success = false;
    res.message = e.what();
  }
  return true;
}

void Long3rNodelet::diagnose(diagnostic_updater::DiagnosticStatusWrapper& stat) {
  const ros::WallTime now = ros::WallTime::now();
  const double dt = std::max(1e-3, (now - stats_since_).toSec());
  stat.summary(diagnostic_msgs::DiagnosticStatus::OK, "running");
  if (queue_ && queue_->dropped() > 0) {
    stat.summary(diagnostic_msgs::DiagnosticStatus::WARN, "dropping input frames");
  }
  stat.add("input rate (Hz)", frames_received_.load() / dt);
  stat.add("processing rate (Hz)", frames_processed_.load() / dt);
  stat.add("latency (s)", last_latency_s_.load());
  stat.add("dropped frames", queue_ ? queue_->dropped() : 0);
  stat.add("failed frames", frames_failed_.load());
  stat.add("memory tokens short", mem_short_.load());
  stat.add("memory tokens long", mem_long_.load());
  stat.add("relevant tokens", mem_relevant_.load());
}

void Long3rNodelet::shutdown() {
  if (!running_.exchange(false)) return;
  // Every way into this object from the manager's callback threads is closed
  // (and waited for: roscpp blocks until a running callback returns) before
  // the worker stops and members start to be destroyed; a service or timer
  // callback running into a half-destroyed nodelet is undefined behaviour.
  image_sub_.shutdown();
  camera_info_sub_.shutdown();
  reset_srv_.shutdown();
  save_map_srv_.shutdown();
  map_timer_.stop();
  if (queue_) queue_->close();
  if (worker_.joinable()) worker_.join();
  diagnostics_.reset();
}

}  // namespace long3r_ros

PLUGINLIB_EXPORT_CLASS(long3r_ros::Long3rNodelet, nodelet::Nodelet)

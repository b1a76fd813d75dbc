#include "long3r_ros/stamped_inputs.hpp"

#include <cv_bridge/cv_bridge.h>
#include <sensor_msgs/image_encodings.h>

#include <cmath>
#include <cstdio>

#include "long3r/pipeline/live_session.hpp"
#include "long3r_ros/conversions.hpp"
#include "long3r_ros/log_throttle.hpp"

namespace long3r_ros {

namespace {

using Unavailable = long3r::LiveSessionClient::Unavailable;

// roscpp's own queue for depth images, as generous as the image topic's.
constexpr std::uint32_t kDepthQueue = 30;
// Base drivers publish odometry at 10 Hz or more: 20 s at 100 Hz.
constexpr unsigned kOdomCacheSize = 2000;
// How far from a frame's stamp its depth image and its odometry may be.
constexpr double kDepthMaxDtS = 0.02;
constexpr double kOdomCovarianceMaxDtS = 0.1;

// The message of `cache` whose stamp is nearest to `stamp`, at most max_dt_s
// away (null when there is none).
template <class M>
boost::shared_ptr<const M> nearestInCache(const message_filters::Cache<M>& cache,
                                          const ros::Time& stamp, double max_dt_s) {
  const ros::Duration window(max_dt_s);
  const ros::Time from = stamp.toSec() > max_dt_s ? stamp - window : ros::Time(0);
  boost::shared_ptr<const M> nearest;
  for (const auto& m : cache.getInterval(from, stamp + window)) {
    if (!nearest || std::abs((m->header.stamp - stamp).toSec()) <
                        std::abs((nearest->header.stamp - stamp).toSec())) {
      nearest = m;
    }
  }
  return nearest;
}

}  // namespace

StampedInputs::StampedInputs(ros::NodeHandle& nh, const Config& config, Warn warn)
    : config_(config),
      warn_(std::move(warn)),
      camera_info_cache_(config.reach),
      depth_cache_(config.reach),
      odom_cache_(kOdomCacheSize) {
  // Validated by the worker, with the image each one calibrates.
  if (config_.camera_info) {
    camera_info_sub_ = nh.subscribe<sensor_msgs::CameraInfo>(
        "camera_info", 10,
        [this](const sensor_msgs::CameraInfoConstPtr& msg) { camera_info_cache_.add(msg); });
  }
  if (config_.depth) {
    depth_sub_ = nh.subscribe<sensor_msgs::Image>(
        "depth", kDepthQueue,
        [this](const sensor_msgs::ImageConstPtr& msg) { depth_cache_.add(msg); });
  }
  if (config_.odometry) {
    odom_sub_ = nh.subscribe<nav_msgs::Odometry>(
        "odom", 100, [this](const nav_msgs::OdometryConstPtr& msg) { odom_cache_.add(msg); });
  }
}

void StampedInputs::shutdown() {
  camera_info_sub_.shutdown();
  depth_sub_.shutdown();
  odom_sub_.shutdown();
}

sensor_msgs::CameraInfoConstPtr cameraInfoFor(
    const message_filters::Cache<sensor_msgs::CameraInfo>& cache, const ros::Time& stamp,
    double max_dt_s) {
  const auto exact = cache.getInterval(stamp, stamp);
  if (!exact.empty()) return exact.back();
  return nearestInCache(cache, stamp, max_dt_s);
}

std::optional<long3r::CameraModel> StampedInputs::camera(const ros::Time& stamp) {
  const sensor_msgs::CameraInfoConstPtr info =
      cameraInfoFor(camera_info_cache_, stamp, config_.camera_info_max_dt_s);
  if (info) return toCameraModel(*info);
  if (camera_info_cache_.getLatestTime().isZero()) return std::nullopt;  // none published yet
  char bound[32];
  std::snprintf(bound, sizeof(bound), "%.3f", config_.camera_info_max_dt_s);
  warn_("camera_info stamp",
        std::string("no camera_info within ") + bound +
            atStamp(" s of the frame at t=%.3f (camera_info_max_dt_s): ", stamp.toSec()) +
            "the last calibration stands");
  return std::nullopt;
}

cv::Mat StampedInputs::depth(const ros::Time& stamp) {
  const sensor_msgs::ImageConstPtr depth = nearestInCache(depth_cache_, stamp, kDepthMaxDtS);
  if (!depth) {
    throw Unavailable("depth missing", atStamp("no depth image within 20 ms of the frame at t=%.3f "
                                               "(scale_source depth)",
                                               stamp.toSec()));
  }
  namespace enc = sensor_msgs::image_encodings;
  if (depth->encoding != enc::TYPE_16UC1 && depth->encoding != enc::TYPE_32FC1) {
    throw Unavailable("depth encoding", "depth image not used: encoding '" + depth->encoding +
                                            "' (16UC1 mm or 32FC1 m)");
  }
  try {
    return cv_bridge::toCvShare(depth)->image;
  } catch (const std::exception& e) {
    throw Unavailable("depth encoding", std::string("depth image not used: ") + e.what());
  }
}

std::optional<Eigen::Matrix<double, 6, 6>> StampedInputs::odometryCovarianceInMap(
    const ros::Time& stamp, const Eigen::Matrix3d& R_map_odom) {
  const std::string topic = odom_sub_.getTopic();
  std::string why = "no odometry message on " + topic + " within " +
                    std::to_string(static_cast<int>(std::lround(1e3 * kOdomCovarianceMaxDtS))) +
                    " ms";
  if (const nav_msgs::OdometryConstPtr nearest =
          nearestInCache(odom_cache_, stamp, kOdomCovarianceMaxDtS)) {
    if (auto cov = poseCovarianceOfOdometry(*nearest, config_.odom_frame, config_.base_frame,
                                            R_map_odom, &why)) {
      return cov;
    }
    why = "the odometry on " + topic + ": " + why;
  }
  warn_("odometry covariance",
        atStamp("frame at t=%.3f placed by odometry: ", stamp.toSec()) + why +
            "; ~odometry and ~pose_with_covariance carry the model's PnP covariance "
            "instead (none when PnP failed)");
  return std::nullopt;
}

}  // namespace long3r_ros

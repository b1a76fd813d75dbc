// StampedInputs: the messages that go with an image by its stamp. The
// camera_info, depth image (scale_source depth) and base odometry
// (pose_source odometry) topics are cached as they arrive
// (message_filters::Cache, callbacks only store) and looked up by the worker
// for the image it runs: its calibration, its registered depth image and the
// covariance of the odometry that placed it. Frames: depth images in the
// camera optical frame; the odometry's covariance turned into map.
#pragma once

#include <message_filters/cache.h>
#include <nav_msgs/Odometry.h>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>

#include <Eigen/Core>
#include <functional>
#include <optional>
#include <string>

#include <opencv2/core/mat.hpp>

#include "long3r/pipeline/camera_rectifier.hpp"
#include "long3r_ros/log_throttle.hpp"

namespace long3r_ros {

// The camera_info of an image: the one of its stamp, else the nearest within
// max_dt_s (the earlier one on a tie); null when there is none.
sensor_msgs::CameraInfoConstPtr cameraInfoFor(
    const message_filters::Cache<sensor_msgs::CameraInfo>& cache, const ros::Time& stamp,
    double max_dt_s);

class StampedInputs {
 public:
  // What arrives while the worker runs one frame.
  static constexpr unsigned kReachMargin = 30;
  struct Config {
    bool camera_info = true;            // use_camera_info
    double camera_info_max_dt_s = 0.1;  // pairing bound (camera_info_max_dt_s)
    bool depth = false;                 // scale_source depth
    bool odometry = false;              // pose_source odometry
    // How many messages of each image-rate topic to keep: as many as the
    // image queue reaches back over, plus kReachMargin.
    unsigned reach = kReachMargin;
    std::string odom_frame, base_frame;  // the odometry's frames, as the robot has them
  };

  // Subscribes (on nh) to camera_info, depth and odom as `config` asks.
  StampedInputs(ros::NodeHandle& nh, const Config& config, Warn warn);
  void shutdown();  // no callback runs after it returns

  std::string depthTopic() const { return depth_sub_.getTopic(); }
  std::string odomTopic() const { return odom_sub_.getTopic(); }

  // The camera_info of this stamp, else the nearest within
  // camera_info_max_dt_s (the earlier one on a tie); unvalidated (the session
  // validates it against the image). None within the bound: nullopt (the
  // session keeps the last calibration), with a throttled warning once any
  // camera_info has arrived.
  std::optional<long3r::CameraModel> camera(const ros::Time& stamp);
  // The depth image of this stamp (the nearest within 20 ms), 16UC1 mm or
  // 32FC1 m. Throws long3r::LiveSessionClient::Unavailable naming what is
  // missing or wrong.
  cv::Mat depth(const ros::Time& stamp);
  // The pose covariance of the odometry message nearest `stamp` (within
  // 100 ms), turned into map by R_map_odom; nullopt, with a throttled
  // warning saying why, when there is none to use.
  std::optional<Eigen::Matrix<double, 6, 6>> odometryCovarianceInMap(
      const ros::Time& stamp, const Eigen::Matrix3d& R_map_odom);

 private:
  Config config_;
  Warn warn_;
  ros::Subscriber camera_info_sub_, depth_sub_, odom_sub_;
  message_filters::Cache<sensor_msgs::CameraInfo> camera_info_cache_;
  message_filters::Cache<sensor_msgs::Image> depth_cache_;
  message_filters::Cache<nav_msgs::Odometry> odom_cache_;
};

}  // namespace long3r_ros

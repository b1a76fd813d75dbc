// The node's per-frame outputs: ~camera_info, ~depth, ~frame_cloud,
// ~pointmap, ~pose, ~odometry and ~pose_with_covariance, built from one
// result of the core.
//
// Frames: ~camera_info, ~depth, ~frame_cloud and ~pointmap's points are in
// the camera optical frame (the result's header); ~pose, ~odometry and
// ~pose_with_covariance describe the body (base_frame, else the camera) in
// map_frame. ~odometry carries a pose covariance (the odometry's own for a
// pose it placed, else PnP's moved to the body) and a twist from the
// finite difference of two consecutive poses; without a covariance it is
// not published. Lengths in metres once the scale is metric; until then
// what carries metres is held (Context::units).
#pragma once

#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <std_msgs/Header.h>

#include <Eigen/Geometry>
#include <functional>
#include <optional>
#include <string>
#include <utility>

#include "long3r/pipeline/frame_result.hpp"
#include "long3r_ros/log_throttle.hpp"
#include "long3r_ros/output_units.hpp"

namespace long3r_ros {

class FramePublisher {
 public:
  // What the node adds to a result.
  struct Context {
    std_msgs::Header header;  // the image's stamp, the camera optical frame
    std::string map_frame, body_frame;
    Eigen::Isometry3d T_map_W = Eigen::Isometry3d::Identity();
    Eigen::Isometry3d T_map_body = Eigen::Isometry3d::Identity();
    bool scale_metric = false;
    double scale_stddev = 0.0;
    // Outputs held, not in metres (output_units.hpp); ~pointmap says it itself.
    OutputUnits units;
    std::string held_why;  // the rest of the warning that says so
    float conf_threshold = 1.0f;
    // The odometry's covariance (row-major, map) of a pose it placed.
    std::optional<Eigen::Matrix<double, 6, 6>> given_covariance_map;
  };

  // Named warnings go through `warn(kind, message)` (the node throttles them).
  FramePublisher(ros::NodeHandle& pnh, Warn warn);

  void publish(const long3r::FrameResult& r, const Context& c);
  // The next pose starts a new finite difference (the scale changed).
  void restartTwist() { last_body_.reset(); }

 private:
  void publishDepth(const long3r::FrameResult& r, const Context& c,
                    const sensor_msgs::CameraInfo& info);
  void publishOdometry(const long3r::FrameResult& r, const Context& c,
                       const Eigen::Isometry3d& T_map_cam);

  Warn warn_;
  ros::Publisher camera_info_pub_, depth_pub_, frame_cloud_pub_, pointmap_pub_, pose_pub_,
      odometry_pub_, pose_cov_pub_;
  struct BodyPose {
    Eigen::Isometry3d T_map_body;
    double stamp_s = 0.0;
    std::optional<Eigen::Matrix<double, 6, 6>> covariance_map;
  };
  std::optional<BodyPose> last_body_;
};

}  // namespace long3r_ros

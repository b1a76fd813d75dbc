#include "long3r_ros/frame_publisher.hpp"

#include <geometry_msgs/PoseStamped.h>
#include <geometry_msgs/PoseWithCovarianceStamped.h>
#include <nav_msgs/Odometry.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/PointCloud2.h>
#include <tf2_eigen/tf2_eigen.h>

#include <algorithm>
#include <array>

#include "long3r/pipeline/pose.hpp"
#include "long3r_ros/Pointmap.h"
#include "long3r_ros/conversions.hpp"
#include "long3r_ros/log_throttle.hpp"

namespace long3r_ros {

using RowMajor6 = Eigen::Matrix<double, 6, 6, Eigen::RowMajor>;

FramePublisher::FramePublisher(ros::NodeHandle& pnh, Warn warn) : warn_(std::move(warn)) {
  // Queues of a few messages for subscribers that lag a frame or two (a
  // Python node under load).
  camera_info_pub_ = pnh.advertise<sensor_msgs::CameraInfo>("camera_info", 10);
  depth_pub_ = pnh.advertise<sensor_msgs::Image>("depth", 5);
  frame_cloud_pub_ = pnh.advertise<sensor_msgs::PointCloud2>("frame_cloud", 5);
  pointmap_pub_ = pnh.advertise<Pointmap>("pointmap", 5);
  pose_pub_ = pnh.advertise<geometry_msgs::PoseStamped>("pose", 10);
  odometry_pub_ = pnh.advertise<nav_msgs::Odometry>("odometry", 10);
  pose_cov_pub_ =
      pnh.advertise<geometry_msgs::PoseWithCovarianceStamped>("pose_with_covariance", 10);
}

void FramePublisher::publish(const long3r::FrameResult& r, const Context& c) {
  const sensor_msgs::CameraInfo info =
      toCameraInfo(r.intrinsics.fx, r.intrinsics.fy, r.intrinsics.cx, r.intrinsics.cy, r.conf.cols,
                   r.conf.rows, c.header);
  // ~camera_info goes with every result, posed or not (depth_image_proc pairs it with ~depth).
  camera_info_pub_.publish(info);
  if (!r.posed()) return;
  // A frame placed by odometry whose PnP failed has a pose but no points_C.
  const bool has_points = r.pose.ok() && !r.points_C.empty();
  const Eigen::Isometry3d T_map_cam = c.T_map_W * r.pose.T_W_C;
  if (has_points) publishDepth(r, c, info);
  if (has_points && pointmap_pub_.getNumSubscribers() > 0) {
    pointmap_pub_.publish(
        toPointmap(r, c.header, c.map_frame, T_map_cam, c.scale_metric, c.scale_stddev));
  }
  geometry_msgs::PoseStamped pose;
  pose.header.stamp = c.header.stamp;
  pose.header.frame_id = c.map_frame;
  pose.pose = tf2::toMsg(c.T_map_body);
  if (c.units.poses_held) return;
  pose_pub_.publish(pose);
  publishOdometry(r, c, T_map_cam);
}

void FramePublisher::publishDepth(const long3r::FrameResult& r, const Context& c,
                                  const sensor_msgs::CameraInfo& info) {
  const bool depth_wanted = depth_pub_.getNumSubscribers() > 0;
  const bool cloud_wanted = frame_cloud_pub_.getNumSubscribers() > 0;
  const bool depth = depth_wanted && !c.units.depth_held;
  const bool cloud = cloud_wanted && !c.units.frame_cloud_held;
  if ((depth_wanted && !depth) || (cloud_wanted && !cloud)) {
    warn_("units held",
          atStamp("outputs of the frame at t=%.3f held: ", c.header.stamp.toSec()) + c.held_why);
  }
  if (!depth && !cloud) return;
  const sensor_msgs::ImagePtr image = toDepthImage(r.points_C, r.conf, c.conf_threshold, c.header);
  if (depth) depth_pub_.publish(image);
  if (cloud) frame_cloud_pub_.publish(toFrameCloud(image, info, r.conf, r.rgb));
}

void FramePublisher::publishOdometry(const long3r::FrameResult& r, const Context& c,
                                     const Eigen::Isometry3d& T_map_cam) {
  nav_msgs::Odometry odom;
  odom.header.stamp = c.header.stamp;
  odom.header.frame_id = c.map_frame;
  odom.child_frame_id = c.body_frame;
  odom.pose.pose = tf2::toMsg(c.T_map_body);
  std::optional<Eigen::Matrix<double, 6, 6>> cov_map = c.given_covariance_map;
  if (!cov_map && r.pose.covariance) {
    const std::array<double, 36> cov =
        poseCovarianceInMap(*r.pose.covariance, c.T_map_W.linear(),
                            c.T_map_body.translation() - T_map_cam.translation());
    cov_map = Eigen::Map<const RowMajor6>(cov.data());
  }
  if (cov_map) Eigen::Map<RowMajor6>(odom.pose.covariance.data()) = *cov_map;
  const double stamp_s = c.header.stamp.toSec();
  if (last_body_ && last_body_->covariance_map && cov_map) {
    if (const auto twist =
            long3r::finite_difference_twist(last_body_->T_map_body, *last_body_->covariance_map,
                                            last_body_->stamp_s, c.T_map_body, *cov_map, stamp_s)) {
      tf2::toMsg(twist->linear, odom.twist.twist.linear);
      tf2::toMsg(twist->angular, odom.twist.twist.angular);
      Eigen::Map<RowMajor6>(odom.twist.covariance.data()) = twist->covariance;
    }
  }
  last_body_ = BodyPose{c.T_map_body, stamp_s, cov_map};
  if (!cov_map) return;
  odometry_pub_.publish(odom);
  // robot_localization's pose input: the same pose and covariance.
  geometry_msgs::PoseWithCovarianceStamped pose_cov;
  pose_cov.header = odom.header;
  pose_cov.pose = odom.pose;
  pose_cov_pub_.publish(pose_cov);
}

}  // namespace long3r_ros

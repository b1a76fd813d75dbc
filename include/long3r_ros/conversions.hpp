// Message conversion between the core's types and ROS messages.
//
// Frames: `points_C` are in the camera optical frame (x right, y down, z
// forward); `points_W` and `T_W_C` in the world frame (`world_frame`).
#pragma once

#include <geometry_msgs/Pose.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/PointCloud2.h>
#include <std_msgs/Header.h>

#include <Eigen/Geometry>
#include <array>
#include <cstdint>
#include <opencv2/core/mat.hpp>
#include <vector>

namespace long3r_ros {

// Organised cloud (height x width) with fields x, y, z, rgb, confidence.
// points_C: CV_32FC3, conf: CV_32FC1, rgb: CV_8UC3 in RGB order, all the same size.
// Pixels whose point is not finite get NaN coordinates (a standard organised
// cloud hole).
sensor_msgs::PointCloud2 toOrganizedCloud(const cv::Mat& points_C, const cv::Mat& conf,
                                          const cv::Mat& rgb, const std_msgs::Header& header);

// Unorganised cloud with fields x, y, z, rgb. colors are RGB.
sensor_msgs::PointCloud2 toColoredCloud(const std::vector<Eigen::Vector3f>& points,
                                        const std::vector<std::array<std::uint8_t, 3>>& colors,
                                        const std_msgs::Header& header);

geometry_msgs::Pose toPoseMsg(const Eigen::Isometry3d& T);

// Pinhole camera_info without distortion (the model works on undistorted
// pixels at model resolution).
sensor_msgs::CameraInfo toCameraInfo(double fx, double fy, double cx, double cy, int width,
                                     int height, const std_msgs::Header& header);

// Packs RGB into the float the PCL/rviz "rgb" field expects.
float packRgb(std::uint8_t r, std::uint8_t g, std::uint8_t b);

}  // namespace long3r_ros

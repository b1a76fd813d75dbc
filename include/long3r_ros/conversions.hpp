// Message conversion between the core's types and ROS messages.
//
// Frames: `points_C` are in the camera optical frame (x right, y down, z
// forward); map points and poses in map_frame.
#pragma once

#include <geometry_msgs/Pose.h>
#include <nav_msgs/OccupancyGrid.h>
#include <nav_msgs/Odometry.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/PointCloud2.h>
#include <std_msgs/Header.h>
#include <visualization_msgs/Marker.h>

#include <Eigen/Geometry>
#include <array>
#include <cstdint>
#include <opencv2/core/mat.hpp>
#include <optional>
#include <string>
#include <vector>

#include "long3r/geometry/cv/pcl_cloud.hpp"
#include "long3r/mapping/occupancy_grid.hpp"
#include "long3r/mapping/tsdf_volume.hpp"
#include "long3r/mapping/voxel_map.hpp"
#include "long3r/pipeline/camera_rectifier.hpp"
#include "long3r/pipeline/frame_result.hpp"
#include "long3r_ros/Pointmap.h"

namespace long3r_ros {

// camera_info as the core reads a calibration (the same fields, unvalidated:
// long3r::CameraRectifier::problem() names what is wrong).
long3r::CameraModel toCameraModel(const sensor_msgs::CameraInfo& info);

// The depth an RGB-D camera would give: 32FC1, z of points_C (camera frame),
// NaN where the point is not finite or conf < conf_threshold.
sensor_msgs::ImagePtr toDepthImage(const cv::Mat& points_C, const cv::Mat& conf,
                                   float conf_threshold, const std_msgs::Header& header);

// Organised cloud (height x width) with fields x, y, z, rgb, confidence: the
// depth image back-projected through the camera_info exactly as
// depth_image_proc's point_cloud_xyz does (its own conversion fills x, y, z),
// so consumers of ~depth and of ~frame_cloud see the same points. NaN depth
// gives NaN coordinates (a standard organised cloud hole). conf: CV_32FC1,
// rgb: CV_8UC3 in RGB order, both the depth's size.
sensor_msgs::PointCloud2 toFrameCloud(const sensor_msgs::ImageConstPtr& depth,
                                      const sensor_msgs::CameraInfo& info, const cv::Mat& conf,
                                      const cv::Mat& rgb);

// The grid as nav_msgs/OccupancyGrid (the same cell layout: rows along y from
// the origin corner, -1 unknown, 0 free, 100 occupied) in header.frame_id.
nav_msgs::OccupancyGrid toOccupancyGrid(const long3r::OccupancyGrid& grid,
                                        const std_msgs::Header& header);

// The map as PCL's unorganised coloured cloud (~map, in map; published
// through pcl_conversions: fields x, y, z, rgb). Throws std::invalid_argument
// when points and colours differ in number.
using MapCloud = long3r::ColoredCloud;
MapCloud toPclCloud(const long3r::MapSnapshot& map);

// The map thinned for display (~map with map_display_voxel_m): one point per
// cube of voxel_m, the centroid of its points' positions and colours (PCL's
// VoxelGrid). Unchanged for voxel_m <= 0.
void downsampleForDisplay(MapCloud& cloud, double voxel_m);
// Isolated points left out for display (map_display_outlier_neighbours): a
// point whose mean distance to its `neighbours` nearest points exceeds the
// mean over all points by `stddev` standard deviations (PCL's
// StatisticalOutlierRemoval). Unchanged for neighbours <= 0.
void removeIsolatedPoints(MapCloud& cloud, int neighbours, double stddev);

// A pose covariance (position, then rotation about the fixed axes: ROS's
// order) of a camera pose in W, as the covariance of the body pose in map:
// rotated by R_map_W, and moved to the body through the lever arm a = body
// position - camera position (in map): dp_body = dp - [a]x dth. Row-major,
// as geometry_msgs/PoseWithCovariance holds it.
std::array<double, 36> poseCovarianceInMap(const Eigen::Matrix<double, 6, 6>& cov_W,
                                           const Eigen::Matrix3d& R_map_W,
                                           const Eigen::Vector3d& lever_arm_map);

// The pose covariance of an odometry message of base_frame in odom_frame,
// turned into map by R_map_odom (the body pose in map is T_map_odom *
// T_odom_base: the same point, axes turned). nullopt, with *why saying what
// is wrong, for another pair of frames, negative or non-finite entries, or a
// covariance left unset (zeros).
std::optional<Eigen::Matrix<double, 6, 6>> poseCovarianceOfOdometry(
    const nav_msgs::Odometry& odom, const std::string& odom_frame, const std::string& base_frame,
    const Eigen::Matrix3d& R_map_odom, std::string* why);

// ~mesh: the surface's triangles as rviz draws them, a TRIANGLE_LIST marker
// (three points per triangle, a colour per point, scale 1, opaque), namespace
// "long3r_surface", id 0, in header's frame.
visualization_msgs::Marker toMeshMarker(const long3r::ColoredMesh& mesh,
                                        const std_msgs::Header& header);

// Pinhole camera_info without distortion (the model works on undistorted
// pixels at model resolution).
sensor_msgs::CameraInfo toCameraInfo(double fx, double fy, double cx, double cy, int width,
                                     int height, const std_msgs::Header& header);

// ~pointmap: the result's points_C and confidence, its pose in map_frame
// (T_map_cam), intrinsics and scale (the estimate's standard error once metric).
Pointmap toPointmap(const long3r::FrameResult& r, const std_msgs::Header& header,
                    const std::string& map_frame, const Eigen::Isometry3d& T_map_cam, bool metric,
                    double scale_stddev);

// Packs RGB into the float the PCL/rviz "rgb" field expects.
float packRgb(std::uint8_t r, std::uint8_t g, std::uint8_t b);

}  // namespace long3r_ros

#include "long3r_ros/conversions.hpp"

#include <depth_image_proc/depth_conversions.h>
#include <image_geometry/pinhole_camera_model.h>
#include <pcl/filters/statistical_outlier_removal.h>
#include <pcl/filters/voxel_grid.h>
#include <pcl/point_types.h>
#include <sensor_msgs/image_encodings.h>
#include <sensor_msgs/point_cloud2_iterator.h>
#include <tf2_eigen/tf2_eigen.h>
#include <boost/make_shared.hpp>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <stdexcept>

namespace long3r_ros {

float packRgb(std::uint8_t r, std::uint8_t g, std::uint8_t b) {
  const std::uint32_t packed = (static_cast<std::uint32_t>(r) << 16) |
                               (static_cast<std::uint32_t>(g) << 8) | static_cast<std::uint32_t>(b);
  float out;
  std::memcpy(&out, &packed, sizeof(out));
  return out;
}

sensor_msgs::ImagePtr toDepthImage(const cv::Mat& points_C, const cv::Mat& conf,
                                   float conf_threshold, const std_msgs::Header& header) {
  if (points_C.type() != CV_32FC3 || conf.type() != CV_32FC1 || conf.size() != points_C.size()) {
    throw std::invalid_argument(
        "toDepthImage: expected CV_32FC3 points and CV_32FC1 conf of one size");
  }
  auto msg = boost::make_shared<sensor_msgs::Image>();
  msg->header = header;
  msg->height = static_cast<std::uint32_t>(points_C.rows);
  msg->width = static_cast<std::uint32_t>(points_C.cols);
  msg->encoding = sensor_msgs::image_encodings::TYPE_32FC1;
  msg->is_bigendian = false;
  msg->step = msg->width * sizeof(float);
  msg->data.resize(static_cast<std::size_t>(msg->step) * msg->height);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (int v = 0; v < points_C.rows; ++v) {
    const auto* p = points_C.ptr<cv::Vec3f>(v);
    const float* c = conf.ptr<float>(v);
    auto* d = reinterpret_cast<float*>(&msg->data[static_cast<std::size_t>(v) * msg->step]);
    for (int u = 0; u < points_C.cols; ++u) {
      const bool ok = c[u] >= conf_threshold && std::isfinite(p[u][0]) && std::isfinite(p[u][1]) &&
                      std::isfinite(p[u][2]) && p[u][2] > 0.0f;
      d[u] = ok ? p[u][2] : nan;
    }
  }
  return msg;
}

sensor_msgs::PointCloud2 toFrameCloud(const sensor_msgs::ImageConstPtr& depth,
                                      const sensor_msgs::CameraInfo& info, const cv::Mat& conf,
                                      const cv::Mat& rgb) {
  const cv::Size size(static_cast<int>(depth->width), static_cast<int>(depth->height));
  if (depth->encoding != sensor_msgs::image_encodings::TYPE_32FC1 || conf.type() != CV_32FC1 ||
      rgb.type() != CV_8UC3 || conf.size() != size || rgb.size() != size) {
    throw std::invalid_argument(
        "toFrameCloud: expected a 32FC1 depth image and CV_32FC1 conf, CV_8UC3 rgb of its size");
  }
  auto cloud = boost::make_shared<sensor_msgs::PointCloud2>();
  cloud->header = depth->header;
  sensor_msgs::PointCloud2Modifier modifier(*cloud);
  modifier.setPointCloud2Fields(
      5, "x", 1, sensor_msgs::PointField::FLOAT32, "y", 1, sensor_msgs::PointField::FLOAT32, "z", 1,
      sensor_msgs::PointField::FLOAT32, "rgb", 1, sensor_msgs::PointField::FLOAT32, "confidence", 1,
      sensor_msgs::PointField::FLOAT32);
  modifier.resize(static_cast<std::size_t>(size.area()));
  cloud->height = depth->height;
  cloud->width = depth->width;
  cloud->row_step = cloud->width * cloud->point_step;
  image_geometry::PinholeCameraModel model;
  model.fromCameraInfo(info);
  depth_image_proc::convert<float>(depth, cloud, model);
  cloud->is_dense = true;
  sensor_msgs::PointCloud2Iterator<float> it_z(*cloud, "z");
  sensor_msgs::PointCloud2Iterator<float> it_rgb(*cloud, "rgb");
  sensor_msgs::PointCloud2Iterator<float> it_conf(*cloud, "confidence");
  for (int v = 0; v < size.height; ++v) {
    const float* c = conf.ptr<float>(v);
    const auto* col = rgb.ptr<cv::Vec3b>(v);
    for (int u = 0; u < size.width; ++u, ++it_z, ++it_rgb, ++it_conf) {
      if (!std::isfinite(*it_z)) cloud->is_dense = false;
      *it_rgb = packRgb(col[u][0], col[u][1], col[u][2]);
      *it_conf = c[u];
    }
  }
  return *cloud;
}

visualization_msgs::Marker toMeshMarker(const long3r::ColoredMesh& mesh,
                                        const std_msgs::Header& header) {
  visualization_msgs::Marker m;
  m.header = header;
  m.ns = "long3r_surface";
  m.id = 0;
  m.type = visualization_msgs::Marker::TRIANGLE_LIST;
  m.action = visualization_msgs::Marker::ADD;
  m.pose.orientation.w = 1.0;
  m.scale.x = m.scale.y = m.scale.z = 1.0;
  m.color.a = 1.0f;
  m.points.reserve(3 * mesh.triangles.size());
  m.colors.reserve(3 * mesh.triangles.size());
  for (const long3r::Triangle& t : mesh.triangles) {
    for (const std::int32_t i : t) {
      const Eigen::Vector3f& v = mesh.vertices[static_cast<std::size_t>(i)];
      geometry_msgs::Point p;
      p.x = v.x();
      p.y = v.y();
      p.z = v.z();
      m.points.push_back(p);
      const long3r::Rgb8& c = mesh.colors[static_cast<std::size_t>(i)];
      std_msgs::ColorRGBA rgba;
      rgba.r = c[0] / 255.0f;
      rgba.g = c[1] / 255.0f;
      rgba.b = c[2] / 255.0f;
      rgba.a = 1.0f;
      m.colors.push_back(rgba);
    }
  }
  return m;
}

MapCloud toPclCloud(const long3r::MapSnapshot& map) {
  return long3r::to_pcl_cloud(map.points, map.colors);
}

void downsampleForDisplay(MapCloud& cloud, double voxel_m) {
  if (!(voxel_m > 0.0) || cloud.empty()) return;
  pcl::VoxelGrid<pcl::PointXYZRGB> grid;
  grid.setInputCloud(MapCloud::ConstPtr(&cloud, [](const MapCloud*) {}));  // not owned
  const float leaf = static_cast<float>(voxel_m);
  grid.setLeafSize(leaf, leaf, leaf);
  MapCloud out;
  grid.filter(out);
  cloud.swap(out);
}

void removeIsolatedPoints(MapCloud& cloud, int neighbours, double stddev) {
  if (neighbours <= 0 || cloud.size() <= static_cast<std::size_t>(neighbours)) return;
  pcl::StatisticalOutlierRemoval<pcl::PointXYZRGB> sor;
  sor.setInputCloud(MapCloud::ConstPtr(&cloud, [](const MapCloud*) {}));  // not owned
  sor.setMeanK(neighbours);
  sor.setStddevMulThresh(stddev);
  MapCloud out;
  sor.filter(out);
  cloud.swap(out);
}

std::array<double, 36> poseCovarianceInMap(const Eigen::Matrix<double, 6, 6>& cov_W,
                                           const Eigen::Matrix3d& R_map_W,
                                           const Eigen::Vector3d& lever_arm_map) {
  Eigen::Matrix3d a_cross;
  a_cross << 0.0, -lever_arm_map.z(), lever_arm_map.y(), lever_arm_map.z(), 0.0, -lever_arm_map.x(),
      -lever_arm_map.y(), lever_arm_map.x(), 0.0;
  Eigen::Matrix<double, 6, 6> rotate = Eigen::Matrix<double, 6, 6>::Zero();
  rotate.topLeftCorner<3, 3>() = R_map_W;
  rotate.bottomRightCorner<3, 3>() = R_map_W;
  Eigen::Matrix<double, 6, 6> lever = Eigen::Matrix<double, 6, 6>::Identity();
  lever.topRightCorner<3, 3>() = -a_cross;
  const Eigen::Matrix<double, 6, 6> J = lever * rotate;
  Eigen::Matrix<double, 6, 6> cov = J * cov_W * J.transpose();
  cov = 0.5 * (cov + cov.transpose());
  std::array<double, 36> out;
  Eigen::Map<Eigen::Matrix<double, 6, 6, Eigen::RowMajor>>(out.data()) = cov;
  return out;
}

std::optional<Eigen::Matrix<double, 6, 6>> poseCovarianceOfOdometry(
    const nav_msgs::Odometry& odom, const std::string& odom_frame, const std::string& base_frame,
    const Eigen::Matrix3d& R_map_odom, std::string* why) {
  const auto bare = [](const std::string& f) { return f.empty() || f[0] != '/' ? f : f.substr(1); };
  if (bare(odom.header.frame_id) != odom_frame || bare(odom.child_frame_id) != base_frame) {
    *why = "it is of " + odom.child_frame_id + " in " + odom.header.frame_id + ", not of " +
           base_frame + " in " + odom_frame + " (the frames that place it)";
    return std::nullopt;
  }
  const Eigen::Matrix<double, 6, 6> cov_odom =
      Eigen::Map<const Eigen::Matrix<double, 6, 6, Eigen::RowMajor>>(odom.pose.covariance.data());
  if (!cov_odom.allFinite() || (cov_odom.diagonal().array() < 0.0).any()) {
    *why = "its pose covariance has a negative or non-finite entry";
    return std::nullopt;
  }
  if (cov_odom.isZero(0.0)) {
    *why = "it leaves the pose covariance unset (zeros)";
    return std::nullopt;
  }
  const std::array<double, 36> c =
      poseCovarianceInMap(cov_odom, R_map_odom, Eigen::Vector3d::Zero());
  return Eigen::Map<const Eigen::Matrix<double, 6, 6, Eigen::RowMajor>>(c.data());
}

sensor_msgs::CameraInfo toCameraInfo(double fx, double fy, double cx, double cy, int width,
                                     int height, const std_msgs::Header& header) {
  sensor_msgs::CameraInfo info;
  info.header = header;
  info.width = static_cast<std::uint32_t>(width);
  info.height = static_cast<std::uint32_t>(height);
  info.distortion_model = "plumb_bob";
  info.D = {0.0, 0.0, 0.0, 0.0, 0.0};
  info.K = {fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0};
  info.R = {1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0};
  info.P = {fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0};
  return info;
}

long3r::CameraModel toCameraModel(const sensor_msgs::CameraInfo& info) {
  long3r::CameraModel c;
  c.width = info.width;
  c.height = info.height;
  c.distortion_model = info.distortion_model;
  c.D = info.D;
  std::copy(info.K.begin(), info.K.end(), c.K.begin());
  std::copy(info.R.begin(), info.R.end(), c.R.begin());
  std::copy(info.P.begin(), info.P.end(), c.P.begin());
  c.binning_x = info.binning_x;
  c.binning_y = info.binning_y;
  c.roi.x_offset = info.roi.x_offset;
  c.roi.y_offset = info.roi.y_offset;
  c.roi.width = info.roi.width;
  c.roi.height = info.roi.height;
  return c;
}

Pointmap toPointmap(const long3r::FrameResult& r, const std_msgs::Header& header,
                    const std::string& map_frame, const Eigen::Isometry3d& T_map_cam, bool metric,
                    double scale_stddev) {
  const int h = r.conf.rows, w = r.conf.cols;
  Pointmap pm;
  pm.header = header;
  pm.height = static_cast<std::uint32_t>(h);
  pm.width = static_cast<std::uint32_t>(w);
  pm.frame_index = static_cast<std::uint32_t>(r.frame_index);
  const cv::Mat pts = r.points_C.isContinuous() ? r.points_C : r.points_C.clone();
  const cv::Mat conf = r.conf.isContinuous() ? r.conf : r.conf.clone();
  pm.points.assign(pts.ptr<float>(), pts.ptr<float>() + static_cast<std::size_t>(h) * w * 3);
  pm.confidence.assign(conf.ptr<float>(), conf.ptr<float>() + static_cast<std::size_t>(h) * w);
  pm.map_frame_id = map_frame;
  pm.T_W_C = tf2::toMsg(T_map_cam);
  pm.fx = r.intrinsics.fx;
  pm.fy = r.intrinsics.fy;
  pm.cx = r.intrinsics.cx;
  pm.cy = r.intrinsics.cy;
  pm.scale = r.scale;
  pm.scale_stddev = metric ? scale_stddev : 0.0;
  pm.metric = metric;
  return pm;
}

nav_msgs::OccupancyGrid toOccupancyGrid(const long3r::OccupancyGrid& grid,
                                        const std_msgs::Header& header) {
  nav_msgs::OccupancyGrid msg;
  msg.header = header;
  msg.info.map_load_time = header.stamp;
  msg.info.resolution = static_cast<float>(grid.resolution_m);
  msg.info.width = static_cast<std::uint32_t>(grid.width);
  msg.info.height = static_cast<std::uint32_t>(grid.height);
  msg.info.origin.position.x = grid.origin_x_m;
  msg.info.origin.position.y = grid.origin_y_m;
  msg.info.origin.orientation.w = 1.0;
  msg.data = grid.cells;
  return msg;
}

}  // namespace long3r_ros

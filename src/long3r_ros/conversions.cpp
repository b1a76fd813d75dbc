#include "long3r_ros/conversions.hpp"

#include <sensor_msgs/point_cloud2_iterator.h>

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

sensor_msgs::PointCloud2 toOrganizedCloud(const cv::Mat& points_C, const cv::Mat& conf,
                                          const cv::Mat& rgb, const std_msgs::Header& header) {
  if (points_C.type() != CV_32FC3 || conf.type() != CV_32FC1 || rgb.type() != CV_8UC3) {
    throw std::invalid_argument(
        "toOrganizedCloud: expected CV_32FC3 points, CV_32FC1 conf, CV_8UC3 rgb");
  }
  if (conf.size() != points_C.size() || rgb.size() != points_C.size()) {
    throw std::invalid_argument("toOrganizedCloud: points, conf and rgb differ in size");
  }
  sensor_msgs::PointCloud2 cloud;
  cloud.header = header;
  sensor_msgs::PointCloud2Modifier modifier(cloud);
  modifier.setPointCloud2Fields(
      5, "x", 1, sensor_msgs::PointField::FLOAT32, "y", 1, sensor_msgs::PointField::FLOAT32, "z", 1,
      sensor_msgs::PointField::FLOAT32, "rgb", 1, sensor_msgs::PointField::FLOAT32, "confidence", 1,
      sensor_msgs::PointField::FLOAT32);
  modifier.resize(static_cast<std::size_t>(points_C.rows) * points_C.cols);
  cloud.height = static_cast<std::uint32_t>(points_C.rows);
  cloud.width = static_cast<std::uint32_t>(points_C.cols);
  cloud.row_step = cloud.width * cloud.point_step;
  cloud.is_dense = true;

  sensor_msgs::PointCloud2Iterator<float> it_x(cloud, "x");
  sensor_msgs::PointCloud2Iterator<float> it_rgb(cloud, "rgb");
  sensor_msgs::PointCloud2Iterator<float> it_conf(cloud, "confidence");
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (int v = 0; v < points_C.rows; ++v) {
    const auto* p = points_C.ptr<cv::Vec3f>(v);
    const auto* c = conf.ptr<float>(v);
    const auto* col = rgb.ptr<cv::Vec3b>(v);
    for (int u = 0; u < points_C.cols; ++u, ++it_x, ++it_rgb, ++it_conf) {
      const bool finite =
          std::isfinite(p[u][0]) && std::isfinite(p[u][1]) && std::isfinite(p[u][2]);
      if (!finite) cloud.is_dense = false;
      it_x[0] = finite ? p[u][0] : nan;
      it_x[1] = finite ? p[u][1] : nan;
      it_x[2] = finite ? p[u][2] : nan;
      *it_rgb = packRgb(col[u][0], col[u][1], col[u][2]);
      *it_conf = c[u];
    }
  }
  return cloud;
}

sensor_msgs::PointCloud2 toColoredCloud(const std::vector<Eigen::Vector3f>& points,
                                        const std::vector<std::array<std::uint8_t, 3>>& colors,
                                        const std_msgs::Header& header) {
  if (points.size() != colors.size()) {
    throw std::invalid_argument("toColoredCloud: points and colors differ in size");
  }
  sensor_msgs::PointCloud2 cloud;
  cloud.header = header;
  sensor_msgs::PointCloud2Modifier modifier(cloud);
  modifier.setPointCloud2FieldsByString(2, "xyz", "rgb");
  modifier.resize(points.size());
  cloud.height = 1;
  cloud.width = static_cast<std::uint32_t>(points.size());
  cloud.is_dense = true;
  sensor_msgs::PointCloud2Iterator<float> it_x(cloud, "x");
  sensor_msgs::PointCloud2Iterator<float> it_rgb(cloud, "rgb");
  for (std::size_t i = 0; i < points.size(); ++i, ++it_x, ++it_rgb) {
    it_x[0] = points[i].x();
    it_x[1] = points[i].y();
    it_x[2] = points[i].z();
    *it_rgb = packRgb(colors[i][0], colors[i][1], colors[i][2]);
  }
  return cloud;
}

geometry_msgs::Pose toPoseMsg(const Eigen::Isometry3d& T) {
  geometry_msgs::Pose pose;
  const Eigen::Vector3d t = T.translation();
  const Eigen::Quaterniond q(T.rotation());
  pose.position.x = t.x();
  pose.position.y = t.y();
  pose.position.z = t.z();
  pose.orientation.x = q.x();
  pose.orientation.y = q.y();
  pose.orientation.z = q.z();
  pose.orientation.w = q.w();
  return pose;
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

}  // namespace long3r_ros

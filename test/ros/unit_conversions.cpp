// Message conversions: field layout, values, holes, and size checks.
#include <gtest/gtest.h>
#include <sensor_msgs/point_cloud2_iterator.h>

#include <cmath>
#include <cstring>
#include <opencv2/core.hpp>

#include "long3r_ros/conversions.hpp"

using namespace long3r_ros;

namespace {
std::uint32_t unpack(float f) {
  std::uint32_t u;
  std::memcpy(&u, &f, sizeof(u));
  return u;
}
}  // namespace

TEST(Conversions, OrganizedCloudLayoutAndValues) {
  cv::Mat pts(2, 3, CV_32FC3), conf(2, 3, CV_32FC1), rgb(2, 3, CV_8UC3);
  for (int v = 0; v < 2; ++v)
    for (int u = 0; u < 3; ++u) {
      pts.at<cv::Vec3f>(v, u) = cv::Vec3f(u, v, 1.0f + u + 10 * v);
      conf.at<float>(v, u) = 1.5f + u;
      rgb.at<cv::Vec3b>(v, u) = cv::Vec3b(10 * u, 20 * v, 7);
    }
  pts.at<cv::Vec3f>(1, 2)[2] = std::nanf("");
  std_msgs::Header h;
  h.frame_id = "camera";
  auto cloud = toOrganizedCloud(pts, conf, rgb, h);
  EXPECT_EQ(cloud.height, 2u);
  EXPECT_EQ(cloud.width, 3u);
  EXPECT_EQ(cloud.header.frame_id, "camera");
  EXPECT_FALSE(cloud.is_dense);
  ASSERT_EQ(cloud.fields.size(), 5u);
  EXPECT_EQ(cloud.fields[4].name, "confidence");
  sensor_msgs::PointCloud2ConstIterator<float> x(cloud, "x"), c(cloud, "confidence"),
      col(cloud, "rgb");
  for (int v = 0; v < 2; ++v)
    for (int u = 0; u < 3; ++u, ++x, ++c, ++col) {
      if (v == 1 && u == 2) {
        EXPECT_TRUE(std::isnan(x[0]) && std::isnan(x[1]) && std::isnan(x[2]));
        continue;
      }
      EXPECT_FLOAT_EQ(x[0], u);
      EXPECT_FLOAT_EQ(x[1], v);
      EXPECT_FLOAT_EQ(x[2], 1.0f + u + 10 * v);
      EXPECT_FLOAT_EQ(*c, 1.5f + u);
      EXPECT_EQ(unpack(*col), (static_cast<std::uint32_t>(10 * u) << 16) | ((20u * v) << 8) | 7u);
    }
}

TEST(Conversions, OrganizedCloudRejectsMismatchedSizes) {
  cv::Mat pts(2, 3, CV_32FC3), conf(2, 2, CV_32FC1), rgb(2, 3, CV_8UC3);
  EXPECT_THROW(toOrganizedCloud(pts, conf, rgb, {}), std::invalid_argument);
  cv::Mat wrong(2, 3, CV_64FC3);
  EXPECT_THROW(toOrganizedCloud(wrong, cv::Mat(2, 3, CV_32FC1), rgb, {}), std::invalid_argument);
}

TEST(Conversions, ColoredCloud) {
  std::vector<Eigen::Vector3f> p{{1, 2, 3}, {4, 5, 6}};
  std::vector<std::array<std::uint8_t, 3>> c{{{255, 0, 0}}, {{0, 0, 255}}};
  auto cloud = toColoredCloud(p, c, {});
  EXPECT_EQ(cloud.width, 2u);
  EXPECT_EQ(cloud.height, 1u);
  sensor_msgs::PointCloud2ConstIterator<float> x(cloud, "x"), col(cloud, "rgb");
  EXPECT_FLOAT_EQ(x[2], 3.0f);
  EXPECT_EQ(unpack(*col), 0xFF0000u);
  ++x;
  ++col;
  EXPECT_FLOAT_EQ(x[0], 4.0f);
  EXPECT_EQ(unpack(*col), 0x0000FFu);
  c.pop_back();
  EXPECT_THROW(toColoredCloud(p, c, {}), std::invalid_argument);
}

TEST(Conversions, PoseAndCameraInfo) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.rotate(Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitZ()));
  T.pretranslate(Eigen::Vector3d(1, 2, 3));
  auto pose = toPoseMsg(T);
  EXPECT_DOUBLE_EQ(pose.position.z, 3.0);
  EXPECT_NEAR(pose.orientation.z, std::sqrt(0.5), 1e-12);
  EXPECT_NEAR(pose.orientation.w, std::sqrt(0.5), 1e-12);
  auto info = toCameraInfo(200, 210, 111.5, 100.5, 224, 224, {});
  EXPECT_DOUBLE_EQ(info.K[0], 200);
  EXPECT_DOUBLE_EQ(info.K[4], 210);
  EXPECT_DOUBLE_EQ(info.P[2], 111.5);
  EXPECT_EQ(info.width, 224u);
}

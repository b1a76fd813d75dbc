// Message conversions: field layout, values, holes, and size checks.
#include <gtest/gtest.h>
#include <pcl_conversions/pcl_conversions.h>
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

// ~depth: z of the camera-frame points, NaN where not confident or not finite.
TEST(Conversions, DepthImage) {
  cv::Mat pts(2, 3, CV_32FC3), conf(2, 3, CV_32FC1, cv::Scalar(2.0f));
  for (int v = 0; v < 2; ++v)
    for (int u = 0; u < 3; ++u) pts.at<cv::Vec3f>(v, u) = cv::Vec3f(u, v, 1.0f + u + 10 * v);
  pts.at<cv::Vec3f>(1, 2)[2] = std::nanf("");
  conf.at<float>(0, 1) = 1.0f;
  std_msgs::Header h;
  h.frame_id = "camera";
  const sensor_msgs::ImagePtr d = toDepthImage(pts, conf, 1.5f, h);
  EXPECT_EQ(d->encoding, "32FC1");
  EXPECT_EQ(d->header.frame_id, "camera");
  EXPECT_EQ(d->step, 3u * 4u);
  const auto* z = reinterpret_cast<const float*>(d->data.data());
  EXPECT_FLOAT_EQ(z[0], 1.0f);
  EXPECT_TRUE(std::isnan(z[1]));  // not confident
  EXPECT_FLOAT_EQ(z[3], 11.0f);
  EXPECT_TRUE(std::isnan(z[5]));  // not finite
  EXPECT_THROW(toDepthImage(pts, cv::Mat(2, 2, CV_32FC1), 1.0f, h), std::invalid_argument);
}

// ~frame_cloud: the depth through camera_info, exactly as depth_image_proc's
// point_cloud_xyz computes it, with colour and confidence.
TEST(Conversions, FrameCloudBackProjectsTheDepth) {
  cv::Mat pts(4, 5, CV_32FC3), conf(4, 5, CV_32FC1), rgb(4, 5, CV_8UC3);
  for (int v = 0; v < 4; ++v)
    for (int u = 0; u < 5; ++u) {
      pts.at<cv::Vec3f>(v, u) = cv::Vec3f(0.0f, 0.0f, 1.0f + 0.1f * (u + v));
      conf.at<float>(v, u) = 1.5f + u;
      rgb.at<cv::Vec3b>(v, u) = cv::Vec3b(10 * u, 20 * v, 7);
    }
  pts.at<cv::Vec3f>(3, 4)[2] = std::nanf("");
  std_msgs::Header h;
  h.frame_id = "camera";
  const sensor_msgs::ImagePtr depth = toDepthImage(pts, conf, 1.0f, h);
  const sensor_msgs::CameraInfo info = toCameraInfo(4.0, 5.0, 2.0, 1.5, 5, 4, h);
  const sensor_msgs::PointCloud2 cloud = toFrameCloud(depth, info, conf, rgb);
  EXPECT_EQ(cloud.height, 4u);
  EXPECT_EQ(cloud.width, 5u);
  EXPECT_EQ(cloud.header.frame_id, "camera");
  EXPECT_FALSE(cloud.is_dense);
  ASSERT_EQ(cloud.fields.size(), 5u);
  EXPECT_EQ(cloud.fields[4].name, "confidence");
  sensor_msgs::PointCloud2ConstIterator<float> x(cloud, "x"), c(cloud, "confidence"),
      col(cloud, "rgb");
  for (int v = 0; v < 4; ++v)
    for (int u = 0; u < 5; ++u, ++x, ++c, ++col) {
      EXPECT_FLOAT_EQ(*c, 1.5f + u);
      EXPECT_EQ(unpack(*col), (static_cast<std::uint32_t>(10 * u) << 16) | ((20u * v) << 8) | 7u);
      if (v == 3 && u == 4) {
        EXPECT_TRUE(std::isnan(x[0]) && std::isnan(x[1]) && std::isnan(x[2]));
        continue;
      }
      const float z = 1.0f + 0.1f * (u + v);
      EXPECT_FLOAT_EQ(x[2], z);
      EXPECT_FLOAT_EQ(x[0], (u - 2.0f) * z / 4.0f);
      EXPECT_FLOAT_EQ(x[1], (v - 1.5f) * z / 5.0f);
    }
  EXPECT_THROW(toFrameCloud(depth, info, conf, cv::Mat(2, 2, CV_8UC3)), std::invalid_argument);
}

// The pose covariance moves from camera to body and from W to map.
TEST(Conversions, PoseCovarianceInMap) {
  Eigen::Matrix<double, 6, 6> cov = Eigen::Matrix<double, 6, 6>::Zero();
  cov.diagonal() << 1e-4, 2e-4, 3e-4, 1e-6, 2e-6, 3e-6;
  const Eigen::Matrix3d R = Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitZ()).matrix();
  // No lever arm: a rotation of the blocks.
  auto c = poseCovarianceInMap(cov, R, Eigen::Vector3d::Zero());
  EXPECT_NEAR(c[0 * 6 + 0], 2e-4, 1e-15);  // map x is W's y turned
  EXPECT_NEAR(c[1 * 6 + 1], 1e-4, 1e-15);
  EXPECT_NEAR(c[5 * 6 + 5], 3e-6, 1e-18);
  // A body 1 m from the camera along map x: a rotation error about z moves it along y.
  c = poseCovarianceInMap(cov, Eigen::Matrix3d::Identity(), Eigen::Vector3d(1.0, 0.0, 0.0));
  EXPECT_NEAR(c[1 * 6 + 1], 2e-4 + 3e-6, 1e-15);
  EXPECT_NEAR(c[0 * 6 + 0], 1e-4, 1e-15);
  EXPECT_NEAR(c[1 * 6 + 5], 3e-6, 1e-18);  // correlated with the yaw
  EXPECT_DOUBLE_EQ(c[1 * 6 + 5], c[5 * 6 + 1]);
}

TEST(Conversions, PoseCovarianceOfOdometry) {
  nav_msgs::Odometry odom;
  odom.header.frame_id = "/odom";  // a leading slash is the same frame
  odom.child_frame_id = "base_link";
  const Eigen::Matrix3d R = Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitZ()).matrix();
  std::string why;
  EXPECT_FALSE(poseCovarianceOfOdometry(odom, "odom", "base_link", R, &why));
  EXPECT_EQ(why, "it leaves the pose covariance unset (zeros)");
  odom.pose.covariance[0] = 1e-4;   // x
  odom.pose.covariance[7] = 2e-4;   // y
  odom.pose.covariance[35] = 3e-6;  // yaw
  const auto cov = poseCovarianceOfOdometry(odom, "odom", "base_link", R, &why);
  ASSERT_TRUE(cov);
  EXPECT_NEAR((*cov)(0, 0), 2e-4, 1e-15);  // map x is odom's y turned
  EXPECT_NEAR((*cov)(1, 1), 1e-4, 1e-15);
  EXPECT_NEAR((*cov)(5, 5), 3e-6, 1e-18);
  EXPECT_FALSE(poseCovarianceOfOdometry(odom, "odom", "base_footprint", R, &why));
  EXPECT_EQ(why,
            "it is of base_link in /odom, not of base_footprint in odom (the frames that "
            "place it)");
  odom.pose.covariance[7] = -1.0;
  EXPECT_FALSE(poseCovarianceOfOdometry(odom, "odom", "base_link", R, &why));
  EXPECT_EQ(why, "its pose covariance has a negative or non-finite entry");
  odom.pose.covariance[7] = std::nan("");
  EXPECT_FALSE(poseCovarianceOfOdometry(odom, "odom", "base_link", R, &why));
}

// ~map's cloud: PCL's coloured points, as a PointCloud2 through pcl_conversions.
TEST(Conversions, MapCloudThroughPcl) {
  long3r::MapSnapshot map;
  map.points = {{1, 2, 3}, {4, 5, 6}};
  map.colors = {{{255, 0, 0}}, {{0, 0, 255}}};
  const MapCloud pcl_cloud = toPclCloud(map);
  sensor_msgs::PointCloud2 cloud;
  pcl::toROSMsg(pcl_cloud, cloud);
  EXPECT_EQ(cloud.width, 2u);
  EXPECT_EQ(cloud.height, 1u);
  EXPECT_TRUE(cloud.is_dense);
  sensor_msgs::PointCloud2ConstIterator<float> x(cloud, "x"), col(cloud, "rgb");
  EXPECT_FLOAT_EQ(x[2], 3.0f);
  EXPECT_EQ(unpack(*col) & 0xFFFFFFu, 0xFF0000u);
  ++x;
  ++col;
  EXPECT_FLOAT_EQ(x[0], 4.0f);
  EXPECT_EQ(unpack(*col) & 0xFFFFFFu, 0x0000FFu);
  map.colors.pop_back();
  EXPECT_THROW(toPclCloud(map), std::invalid_argument);
}

TEST(Conversions, DisplayDownsamplingKeepsOneCentroidPerVoxel) {
  // Two points in one 0.1 m voxel, one in another: two points, the first the
  // centroid of the pair (position and colour).
  long3r::MapSnapshot map;
  map.points = {{0.01f, 0.01f, 0.01f}, {0.03f, 0.05f, 0.07f}, {0.55f, 0.0f, 0.0f}};
  map.colors = {{{100, 0, 0}}, {{200, 0, 50}}, {{0, 0, 255}}};
  MapCloud q = toPclCloud(map);
  downsampleForDisplay(q, 0.0);  // off
  EXPECT_EQ(q.size(), 3u);
  downsampleForDisplay(q, 0.1);
  ASSERT_EQ(q.size(), 2u);
  const std::size_t pair = q[0].x < 0.3f ? 0 : 1;
  EXPECT_NEAR(q[pair].x, 0.02f, 1e-6);
  EXPECT_NEAR(q[pair].y, 0.03f, 1e-6);
  EXPECT_NEAR(q[pair].z, 0.04f, 1e-6);
  EXPECT_EQ(q[pair].r, 150);
  EXPECT_EQ(q[pair].b, 25);
  EXPECT_NEAR(q[1 - pair].x, 0.55f, 1e-6);
  EXPECT_EQ(q[1 - pair].b, 255);
}

TEST(Conversions, IsolatedPointsLeftOutForDisplay) {
  // A 10 x 10 grid of points 1 cm apart and two strays a metre away: the
  // strays go, the grid stays whole.
  long3r::MapSnapshot map;
  for (int i = 0; i < 10; ++i) {
    for (int j = 0; j < 10; ++j) {
      map.points.emplace_back(0.01f * static_cast<float>(i), 0.01f * static_cast<float>(j), 1.0f);
      map.colors.push_back({{1, 2, 3}});
    }
  }
  map.points.emplace_back(1.0f, 1.0f, 2.0f);
  map.points.emplace_back(-1.0f, 0.5f, 0.0f);
  map.colors.push_back({{9, 9, 9}});
  map.colors.push_back({{9, 9, 9}});
  MapCloud cloud = toPclCloud(map);
  removeIsolatedPoints(cloud, 0, 1.0);  // off
  EXPECT_EQ(cloud.size(), 102u);
  removeIsolatedPoints(cloud, 8, 1.0);
  ASSERT_EQ(cloud.size(), 100u);
  for (const pcl::PointXYZRGB& p : cloud) {
    EXPECT_FLOAT_EQ(p.z, 1.0f);
    EXPECT_EQ(p.r, 1);
  }
  // Fewer points than neighbours: nothing to compare, the cloud is kept.
  MapCloud few =
      toPclCloud(long3r::MapSnapshot{{{0, 0, 0}, {5, 5, 5}}, {{{1, 1, 1}}, {{2, 2, 2}}}});
  removeIsolatedPoints(few, 8, 1.0);
  EXPECT_EQ(few.size(), 2u);
}

TEST(Conversions, OccupancyGridLayout) {
  long3r::OccupancyGrid g;
  g.resolution_m = 0.05;
  g.origin_x_m = -1.0;
  g.origin_y_m = 2.0;
  g.width = 3;
  g.height = 2;
  g.cells = {-1, 0, 100, 0, 0, -1};
  std_msgs::Header h;
  h.frame_id = "map";
  const nav_msgs::OccupancyGrid m = long3r_ros::toOccupancyGrid(g, h);
  EXPECT_EQ(m.header.frame_id, "map");
  EXPECT_FLOAT_EQ(m.info.resolution, 0.05f);
  EXPECT_EQ(m.info.width, 3u);
  EXPECT_EQ(m.info.height, 2u);
  EXPECT_DOUBLE_EQ(m.info.origin.position.x, -1.0);
  EXPECT_DOUBLE_EQ(m.info.origin.position.y, 2.0);
  EXPECT_DOUBLE_EQ(m.info.origin.orientation.w, 1.0);
  EXPECT_EQ(m.data, g.cells);  // rows along y from the origin, as nav_msgs
}

TEST(Conversions, CameraInfo) {
  auto info = toCameraInfo(200, 210, 111.5, 100.5, 224, 224, {});
  EXPECT_DOUBLE_EQ(info.K[0], 200);
  EXPECT_DOUBLE_EQ(info.K[4], 210);
  EXPECT_DOUBLE_EQ(info.P[2], 111.5);
  EXPECT_EQ(info.width, 224u);
}

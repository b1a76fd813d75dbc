// RobotFrames against hand-made TF trees (a tf2 buffer filled here, no
// master): which transform is published for each configuration, that it
// composes to LONG3R's pose, that map is z-up, and that a frame that already
// has a parent never gets a second one.
#include <gtest/gtest.h>
#include <ros/time.h>
#include <tf2_eigen/tf2_eigen.h>
#include <tf2_ros/buffer.h>

#include <chrono>
#include <cmath>
#include <future>
#include <thread>

#include "long3r_ros/robot_frames.hpp"

using namespace long3r_ros;

namespace {

Eigen::Isometry3d pose(double x, double y, double z, double roll, double pitch, double yaw) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.translation() = Eigen::Vector3d(x, y, z);
  T.linear() = (Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()) *
                Eigen::AngleAxisd(pitch, Eigen::Vector3d::UnitY()) *
                Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitX()))
                   .matrix();
  return T;
}

class FramesTest : public ::testing::Test {
 protected:
  void SetUp() override {
    ros::Time::init();
    buffer_.setUsingDedicatedThread(true);  // lookups here never wait for data
  }
  void add(const std::string& parent, const std::string& child, const Eigen::Isometry3d& T,
           double stamp, bool is_static) {
    geometry_msgs::TransformStamped t = tf2::eigenToTransform(T);
    t.header.frame_id = parent;
    t.child_frame_id = child;
    t.header.stamp = ros::Time(stamp);
    buffer_.setTransform(t, "test", is_static);
  }
  // A robot: base_link -> camera_link (1.3 m up, pitched 12 degrees down) ->
  // optical (REP-103), odometry odom -> base_link at t = 10 and 11.
  void robot(bool with_odometry) {
    add("base_link", "camera_link", pose(0.2, 0.0, 1.3, 0.0, 12.0 * M_PI / 180.0, 0.0), 0.0, true);
    add("camera_link", "optical", pose(0, 0, 0, -M_PI / 2, 0, -M_PI / 2), 0.0, true);
    if (with_odometry) {
      add("odom", "base_link", pose(1.0, 2.0, 0.0, 0.0, 0.0, 0.3), 10.0, false);
      add("odom", "base_link", pose(1.5, 2.1, 0.0, 0.0, 0.0, 0.35), 11.0, false);
    }
  }
  Eigen::Isometry3d lookup(const std::string& target, const std::string& source, double t) {
    return tf2::transformToEigen(buffer_.lookupTransform(target, source, ros::Time(t)));
  }
  tf2_ros::Buffer buffer_;
};

FramesConfig config(const std::string& odom, const std::string& base) {
  FramesConfig c;
  c.map_frame = "map";
  c.odom_frame = odom;
  c.base_frame = base;
  c.tf_timeout_s = 0.0;
  return c;
}

}  // namespace

TEST(RobotFrames, OpticalToBodyAxes) {
  const Eigen::Matrix3d R = bodyFromOptical();
  EXPECT_TRUE((R * Eigen::Vector3d::UnitZ()).isApprox(Eigen::Vector3d::UnitX()));   // forward
  EXPECT_TRUE((R * Eigen::Vector3d::UnitX()).isApprox(-Eigen::Vector3d::UnitY()));  // right
  EXPECT_TRUE((R * Eigen::Vector3d::UnitY()).isApprox(-Eigen::Vector3d::UnitZ()));  // down
  EXPECT_NEAR(R.determinant(), 1.0, 1e-12);
}

TEST_F(FramesTest, CameraWithoutParentGetsMapToCamera) {
  RobotFrames f(config("", ""), buffer_);
  f.startStream("optical", ros::Time(10));
  EXPECT_EQ(f.mode(), RobotFrames::Mode::kMapToCamera);
  EXPECT_EQ(f.bodyFrame(), "optical");
  const Eigen::Isometry3d T_W_C = pose(0.1, 0.0, 0.5, 0.0, 0.2, 0.0);
  const auto t = f.transformFor(T_W_C, ros::Time(10));
  ASSERT_TRUE(t.has_value());
  EXPECT_EQ(t->header.frame_id, "map");
  EXPECT_EQ(t->child_frame_id, "optical");
  // Camera 0 looks along map's x, its image's down is map's -z.
  EXPECT_TRUE(tf2::transformToEigen(*t).isApprox(f.T_map_W() * T_W_C));
  EXPECT_TRUE(f.T_map_W().linear().isApprox(bodyFromOptical()));
}

TEST_F(FramesTest, CameraWithParentsGetsMapToTheRootOfItsTree) {
  robot(false);
  RobotFrames f(config("", ""), buffer_);
  f.startStream("optical", ros::Time(10));
  EXPECT_EQ(f.mode(), RobotFrames::Mode::kMapToRoot);
  EXPECT_EQ(f.publishedChild(), "base_link");
  const Eigen::Isometry3d T_W_C = pose(0.3, -0.1, 0.2, 0.05, 0.1, -0.2);
  const auto t = f.transformFor(T_W_C, ros::Time(10));
  ASSERT_TRUE(t.has_value());
  EXPECT_EQ(t->child_frame_id, "base_link");
  // map -> base_link -> ... -> optical composes to LONG3R's camera pose.
  const Eigen::Isometry3d composed = tf2::transformToEigen(*t) * lookup("base_link", "optical", 10);
  EXPECT_TRUE(composed.isApprox(f.T_map_W() * T_W_C, 1e-9));
  EXPECT_NE(f.describe().find("root of its tree"), std::string::npos);
}

TEST_F(FramesTest, ALateParentIsFollowed) {
  RobotFrames f(config("", ""), buffer_);
  f.startStream("optical", ros::Time(10));
  EXPECT_FALSE(f.followRoot());
  robot(false);  // the static transforms arrive after the first frame
  EXPECT_TRUE(f.followRoot());
  EXPECT_EQ(f.publishedChild(), "base_link");
  EXPECT_FALSE(f.followRoot());
}

TEST_F(FramesTest, BaseOnlyGetsMapToBaseAndAZUpMap) {
  robot(false);
  RobotFrames f(config("", "base_link"), buffer_);
  f.startStream("optical", ros::Time(10));
  EXPECT_EQ(f.mode(), RobotFrames::Mode::kMapToBase);
  EXPECT_EQ(f.bodyFrame(), "base_link");
  EXPECT_TRUE(f.conflict().empty());
  // At frame 0 the base is map's origin, level: map's z is the base's up.
  EXPECT_TRUE(f.bodyInMap(Eigen::Isometry3d::Identity(), ros::Time(10))
                  .isApprox(Eigen::Isometry3d::Identity(), 1e-9));
  // The floor 1.3 m below the camera, seen by camera 0, lies at z = 0 in map.
  const Eigen::Isometry3d T_base_cam = lookup("base_link", "optical", 10);
  const Eigen::Vector3d floor_point_base(2.0, 0.5, 0.0);
  const Eigen::Vector3d in_cam0 = T_base_cam.inverse() * floor_point_base;
  EXPECT_NEAR((f.T_map_W() * in_cam0).z(), 0.0, 1e-9);
  const auto t = f.transformFor(pose(0.0, 0.0, 0.4, 0, 0, 0), ros::Time(10));
  ASSERT_TRUE(t.has_value());
  EXPECT_EQ(t->child_frame_id, "base_link");
}

TEST_F(FramesTest, BaseWithOdometryGetsMapToOdom) {
  robot(true);
  RobotFrames f(config("odom", "base_link"), buffer_);
  f.startStream("optical", ros::Time(10));
  EXPECT_EQ(f.mode(), RobotFrames::Mode::kMapToOdom);
  // map starts as odom; the odometry's camera at t0 is camera 0.
  EXPECT_TRUE(f.cameraFromOdometry(ros::Time(10)).isApprox(Eigen::Isometry3d::Identity(), 1e-9));
  const Eigen::Isometry3d cam1 = f.cameraFromOdometry(ros::Time(11));
  EXPECT_GT(cam1.translation().norm(), 0.4);
  // LONG3R places the camera slightly elsewhere than odometry does: map -> odom
  // absorbs the difference, and map -> odom -> base is LONG3R's pose.
  const Eigen::Isometry3d T_W_C = pose(0.02, 0.0, 0.01, 0.0, 0.01, 0.0) * cam1;
  const auto t = f.transformFor(T_W_C, ros::Time(11));
  ASSERT_TRUE(t.has_value());
  EXPECT_EQ(t->child_frame_id, "odom");
  const Eigen::Isometry3d map_base = tf2::transformToEigen(*t) * lookup("odom", "base_link", 11);
  EXPECT_TRUE(map_base.isApprox(f.bodyInMap(T_W_C, ros::Time(11)), 1e-9));
  // With LONG3R agreeing with the odometry, map -> odom stays the identity.
  const auto same = f.transformFor(cam1, ros::Time(11));
  EXPECT_TRUE(tf2::transformToEigen(*same).isApprox(Eigen::Isometry3d::Identity(), 1e-9));
  EXPECT_TRUE(f.cameraInOdom(ros::Time(11)).isApprox(lookup("odom", "optical", 11), 1e-9));
}

// A pan-tilt camera: its mounting is looked up per frame and each frame's
// result uses its own, also when it comes a frame late.
TEST_F(FramesTest, AMovingCameraMountIsFollowedFrameByFrame) {
  add("odom", "base_link", pose(1.0, 2.0, 0.0, 0.0, 0.0, 0.3), 10.0, false);
  add("odom", "base_link", pose(1.0, 2.0, 0.0, 0.0, 0.0, 0.3), 12.0, false);
  add("base_link", "camera_link", pose(0.2, 0.0, 1.3, 0.0, 0.0, 0.0), 10.0, false);
  add("base_link", "camera_link", pose(0.2, 0.0, 1.3, 0.0, 0.0, 0.4), 11.0, false);
  add("base_link", "camera_link", pose(0.2, 0.0, 1.3, 0.0, 0.0, 0.4), 12.0, false);
  add("camera_link", "optical", pose(0, 0, 0, -M_PI / 2, 0, -M_PI / 2), 0.0, true);
  RobotFrames f(config("odom", "base_link"), buffer_);
  f.startStream("optical", ros::Time(10));
  f.updateExtrinsics(ros::Time(11));  // panned 0.4 rad
  const Eigen::Isometry3d at10 = lookup("base_link", "optical", 10);
  const Eigen::Isometry3d at11 = lookup("base_link", "optical", 11);
  ASSERT_FALSE(at10.isApprox(at11, 1e-3));
  EXPECT_TRUE(f.T_body_cam(ros::Time(10)).isApprox(at10, 1e-9));
  EXPECT_TRUE(f.T_body_cam(ros::Time(10.5)).isApprox(at10, 1e-9));  // the one before
  EXPECT_TRUE(f.T_body_cam(ros::Time(11)).isApprox(at11, 1e-9));
  EXPECT_TRUE(f.T_body_cam(ros::Time(12)).isApprox(at11, 1e-9));
  // The base stood still while the camera panned: the camera's pose from the
  // odometry turns, the base's pose in map does not.
  const Eigen::Isometry3d cam11 = f.cameraFromOdometry(ros::Time(11));
  EXPECT_NEAR(Eigen::AngleAxisd(cam11.rotation()).angle(), 0.4, 1e-9);
  EXPECT_TRUE(f.bodyInMap(cam11, ros::Time(11))
                  .isApprox(f.bodyInMap(Eigen::Isometry3d::Identity(), ros::Time(10)), 1e-9));
}

TEST_F(FramesTest, NeverGivesAFrameASecondParent) {
  robot(true);  // odom -> base_link exists
  RobotFrames f(config("", "base_link"), buffer_);
  f.startStream("optical", ros::Time(10));
  EXPECT_NE(f.conflict().find("base_link already has the parent odom"), std::string::npos);
  EXPECT_FALSE(f.transformFor(Eigen::Isometry3d::Identity(), ros::Time(10)).has_value());
  // odom already under another map-like frame: no map -> odom either.
  add("world", "odom", Eigen::Isometry3d::Identity(), 0.0, true);
  RobotFrames g(config("odom", "base_link"), buffer_);
  g.startStream("optical", ros::Time(10));
  EXPECT_NE(g.conflict().find("odom already has the parent world"), std::string::npos);
  EXPECT_FALSE(g.transformFor(Eigen::Isometry3d::Identity(), ros::Time(10)).has_value());
}

TEST_F(FramesTest, MissingTransformsAreNamed) {
  RobotFrames f(config("", "base_link"), buffer_);
  try {
    f.startStream("optical", ros::Time(10));
    FAIL() << "no throw";
  } catch (const TfUnavailable& e) {
    EXPECT_NE(std::string(e.what()).find("base_link <- optical"), std::string::npos) << e.what();
  }
  EXPECT_FALSE(f.started());
  RobotFrames g(config("", ""), buffer_);
  EXPECT_THROW(g.startStream("", ros::Time(10)), TfUnavailable);  // no frame_id at all
}

// A replayed bag paused or over: simulated time stands still. A transform
// that is not there is given up after tf_timeout_s of wall time, not waited
// for until the clock moves again (the node's worker would wait for ever).
TEST_F(FramesTest, AMissingTransformIsGivenUpWhileTheSimulatedClockStandsStill) {
  robot(true);  // odometry at t = 10 and 11 only
  FramesConfig c = config("odom", "base_link");
  c.tf_timeout_s = 0.2;
  RobotFrames f(c, buffer_);
  f.startStream("optical", ros::Time(10));
  ros::Time::setNow(ros::Time(11.5));  // simulated time, and it does not move
  std::promise<std::string> result;
  std::future<std::string> done = result.get_future();
  const auto start = std::chrono::steady_clock::now();
  std::thread lookup([&] {
    try {
      f.cameraFromOdometry(ros::Time(12));
      result.set_value("found");
    } catch (const TfUnavailable& e) {
      result.set_value(e.what());
    }
  });
  const bool in_time = done.wait_for(std::chrono::seconds(5)) == std::future_status::ready;
  if (!in_time) ros::Time::setNow(ros::Time(100));  // lets a lookup that waits on ROS time go
  lookup.join();
  const std::chrono::duration<double> waited = std::chrono::steady_clock::now() - start;
  ros::Time::init();  // the system clock again, for the tests after
  ASSERT_TRUE(in_time) << "the lookup waited for the simulated clock";
  EXPECT_GE(waited.count(), 0.2);
  const std::string what = done.get();
  EXPECT_NE(what.find("odom <- "), std::string::npos) << what;
}

// ... and one that arrives within tf_timeout_s is waited for, on the same
// standing clock.
TEST_F(FramesTest, ATransformArrivingWithinTheTimeoutIsWaitedFor) {
  robot(true);
  FramesConfig c = config("odom", "base_link");
  c.tf_timeout_s = 2.0;
  RobotFrames f(c, buffer_);
  f.startStream("optical", ros::Time(10));
  ros::Time::setNow(ros::Time(11.5));
  std::thread late([&] {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    add("odom", "base_link", pose(2.0, 2.2, 0.0, 0.0, 0.0, 0.4), 12.0, false);
  });
  Eigen::Isometry3d cam12 = Eigen::Isometry3d::Identity();
  EXPECT_NO_THROW(cam12 = f.cameraFromOdometry(ros::Time(12)));
  late.join();
  ros::Time::init();
  EXPECT_TRUE(f.cameraInOdom(ros::Time(12)).isApprox(lookup("odom", "optical", 12), 1e-9));
  EXPECT_GT(cam12.translation().norm(), 0.4);
}

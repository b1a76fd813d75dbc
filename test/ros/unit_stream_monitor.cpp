#include <gtest/gtest.h>

#include "long3r_ros/stream_monitor.hpp"

using long3r_ros::StreamMonitor;
using D = StreamMonitor::Decision;

TEST(StreamMonitor, ContinuesOnSteadyStream) {
  StreamMonitor m;
  EXPECT_EQ(m.check(10.0, 640, 480), D::kFirstFrame);
  EXPECT_EQ(m.check(10.1, 640, 480), D::kContinue);
  EXPECT_EQ(m.check(10.1, 640, 480), D::kContinue);  // equal stamps are not backwards
}

TEST(StreamMonitor, ResetsOnSizeChange) {
  StreamMonitor m;
  m.check(1.0, 640, 480);
  EXPECT_EQ(m.check(1.1, 320, 240), D::kResetSizeChanged);
  EXPECT_EQ(m.check(1.2, 320, 240), D::kContinue);
}

TEST(StreamMonitor, ResetsWhenALoopedBagGoesBack) {
  StreamMonitor m(0.05);
  m.check(5.0, 64, 64);
  EXPECT_EQ(m.check(4.97, 64, 64), D::kContinue);  // within tolerance
  EXPECT_EQ(m.check(1.0, 64, 64), D::kResetTimeBackwards);
  EXPECT_EQ(m.check(1.1, 64, 64), D::kContinue);
}

TEST(StreamMonitor, ResetForgetsTheStream) {
  StreamMonitor m;
  m.check(5.0, 64, 64);
  m.reset();
  EXPECT_EQ(m.check(1.0, 32, 32), D::kFirstFrame);
}

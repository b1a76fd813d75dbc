#include <gtest/gtest.h>

#include <limits>

#include "long3r/pipeline/stream_monitor.hpp"

namespace {

using long3r::StreamMonitor;
using long3r::StreamMonitorConfig;
using A = StreamMonitor::Action;
using H = StreamMonitor::Held;

// A camera at 10 Hz whose stamps follow the clock (clock = stamp + offset).
struct Camera {
  StreamMonitor monitor;
  double offset_s = 3.0;
  StreamMonitor::Decision at(double stamp_s, int w = 64, int h = 48) {
    return monitor.check(stamp_s, stamp_s + offset_s, w, h);
  }
  A action(double stamp_s, int w = 64, int h = 48) { return at(stamp_s, w, h).action; }
};

TEST(StreamMonitor, ASteadyStreamContinues) {
  Camera c;
  for (int k = 0; k < 20; ++k) {
    const auto d = c.at(10.0 + 0.1 * k);
    EXPECT_EQ(d.action, A::kProcess) << k;
    EXPECT_EQ(d.held, H::kNone);
  }
}

TEST(StreamMonitor, APauseOfAnyLengthContinues) {
  Camera c;
  EXPECT_EQ(c.action(10.0), A::kProcess);
  EXPECT_EQ(c.action(10.1), A::kProcess);
  EXPECT_EQ(c.action(10.1 + 3600.0), A::kProcess);  // the clock moved on as much
  EXPECT_EQ(c.action(10.2 + 3600.0), A::kProcess);
  // A slow camera: one frame every 2 s.
  for (int k = 1; k < 5; ++k) EXPECT_EQ(c.action(3610.2 + 2.0 * k), A::kProcess);
}

TEST(StreamMonitor, DropsZeroStampsDuplicatesAndSmallReorderings) {
  Camera c;
  EXPECT_EQ(c.action(10.0), A::kProcess);
  EXPECT_EQ(c.action(10.1), A::kProcess);
  EXPECT_EQ(c.action(10.1), A::kDropOutOfOrder);   // duplicate
  EXPECT_EQ(c.action(10.05), A::kDropOutOfOrder);  // 50 ms back
  EXPECT_EQ(c.monitor.check(0.0, 20.0, 64, 48).action, A::kDropZeroStamp);
  EXPECT_EQ(c.monitor.check(-1.0, 20.0, 64, 48).action, A::kDropZeroStamp);
  EXPECT_EQ(c.action(10.2), A::kProcess);  // the stream goes on from 10.1
}

// Recorded data whose clock starts at 0: a zero stamp is a time like any other.
TEST(StreamMonitor, ZeroStampsCanBeTimes) {
  StreamMonitorConfig config;
  config.drop_zero_stamps = false;
  StreamMonitor m(config);
  EXPECT_EQ(m.check(0.0, 0.0, 64, 48).action, A::kProcess);
  EXPECT_EQ(m.check(0.1, 0.1, 64, 48).action, A::kProcess);
  EXPECT_EQ(m.check(0.1, 0.2, 64, 48).action, A::kDropOutOfOrder);
  const double nan = std::numeric_limits<double>::quiet_NaN();
  EXPECT_EQ(m.check(nan, 0.3, 64, 48).action, A::kDropZeroStamp);  // still no time
  EXPECT_EQ(m.check(-5.0, 0.4, 64, 48).action, A::kNewStreamTimeBackwards);
}

TEST(StreamMonitor, ALoopedBagStartsANewStream) {
  Camera c;
  c.action(50.0);
  c.action(50.1);
  EXPECT_EQ(c.monitor.check(1.0, 1.0, 64, 48).action, A::kNewStreamTimeBackwards);
  EXPECT_EQ(c.monitor.check(1.1, 1.1, 64, 48).action, A::kProcess);
}

TEST(StreamMonitor, TheBackwardToleranceIsAParameter) {
  StreamMonitorConfig config;
  config.max_backward_jump_s = 0.01;
  StreamMonitor m(config);
  m.check(5.0, 5.0, 64, 48);
  EXPECT_EQ(m.check(4.995, 5.1, 64, 48).action, A::kDropOutOfOrder);
  EXPECT_EQ(m.check(4.9, 5.2, 64, 48).action, A::kNewStreamTimeBackwards);
}

TEST(StreamMonitor, AnOutlierStampAheadIsDroppedNotAdopted) {
  Camera c;
  c.action(10.0);
  c.action(10.1);
  EXPECT_EQ(c.monitor.check(10.2 + 3600.0, 13.2, 64, 48).action, A::kHold);
  EXPECT_TRUE(c.monitor.holding());
  const auto next = c.at(10.3);  // back on the old time line
  EXPECT_EQ(next.held, H::kDrop);
  EXPECT_EQ(next.action, A::kProcess);
  EXPECT_FALSE(c.monitor.holding());
  EXPECT_EQ(c.action(10.4), A::kProcess);
}

TEST(StreamMonitor, AGenuineJumpAheadIsConfirmedByTheNextFrame) {
  Camera c;
  c.action(10.0);
  c.action(10.1);
  // The camera's clock was corrected forward by 100 s: the stamps stay there.
  EXPECT_EQ(c.monitor.check(110.2, 13.2, 64, 48).action, A::kHold);
  const auto next = c.monitor.check(110.3, 13.3, 64, 48);
  EXPECT_EQ(next.held, H::kProcess);
  EXPECT_EQ(next.action, A::kProcess);
  EXPECT_EQ(c.monitor.check(110.4, 13.4, 64, 48).action, A::kProcess);
}

TEST(StreamMonitor, AStrayFrameOfAnotherSizeIsDropped) {
  Camera c;
  c.action(1.0);
  EXPECT_EQ(c.action(1.1, 6000, 6000), A::kDropStraySize);
  EXPECT_EQ(c.action(1.2), A::kProcess);
  EXPECT_EQ(c.action(1.3, 6000, 6000), A::kDropStraySize);  // not consecutive: counts again
  EXPECT_EQ(c.action(1.4, 6000, 6000), A::kDropStraySize);
  EXPECT_EQ(c.action(1.5), A::kProcess);
}

TEST(StreamMonitor, ASustainedSizeChangeStartsANewStream) {
  StreamMonitorConfig config;
  config.size_change_frames = 3;
  StreamMonitor m(config);
  EXPECT_EQ(m.check(1.0, 1.0, 640, 480).action, A::kProcess);
  EXPECT_EQ(m.check(1.1, 1.1, 320, 240).action, A::kDropStraySize);
  EXPECT_EQ(m.check(1.2, 1.2, 320, 240).action, A::kDropStraySize);
  EXPECT_EQ(m.check(1.3, 1.3, 320, 240).action, A::kNewStreamSizeChanged);
  EXPECT_EQ(m.check(1.4, 1.4, 320, 240).action, A::kProcess);
  EXPECT_EQ(m.check(1.5, 1.5, 640, 480).action, A::kDropStraySize);
}

TEST(StreamMonitor, ResetForgetsTheStream) {
  Camera c;
  c.action(5.0);
  c.monitor.reset();
  EXPECT_EQ(c.action(1.0, 32, 32), A::kProcess);  // a first frame, whatever its size or time
  EXPECT_EQ(c.action(1.1, 32, 32), A::kProcess);
}

}  // namespace

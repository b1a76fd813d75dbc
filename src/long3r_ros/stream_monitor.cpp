#include "long3r_ros/stream_monitor.hpp"

namespace long3r_ros {

StreamMonitor::Decision StreamMonitor::check(double stamp_s, int width, int height) {
  Decision d = Decision::kContinue;
  if (!has_last_) {
    d = Decision::kFirstFrame;
  } else if (width != last_width_ || height != last_height_) {
    d = Decision::kResetSizeChanged;
  } else if (stamp_s < last_stamp_s_ - backwards_tolerance_s_) {
    d = Decision::kResetTimeBackwards;
  }
  has_last_ = true;
  last_stamp_s_ = stamp_s;
  last_width_ = width;
  last_height_ = height;
  return d;
}

std::string StreamMonitor::describe(Decision d) {
  switch (d) {
    case Decision::kFirstFrame:
      return "first frame";
    case Decision::kContinue:
      return "continue";
    case Decision::kResetSizeChanged:
      return "image size changed";
    case Decision::kResetTimeBackwards:
      return "time went backwards";
  }
  return "?";
}

}  // namespace long3r_ros

#include "long3r/pipeline/stream_monitor.hpp"

#include <cmath>

namespace long3r {

void StreamMonitorConfig::validate(const config::FieldCheck& check) const {
  check.require(max_backward_jump_s >= 0.0, "max_backward_jump_s", "must be >= 0");
  check.require(max_stamp_jump_s > 0.0, "max_stamp_jump_s", "must be > 0");
  check.require(size_change_frames >= 1, "size_change_frames", "must be >= 1");
}

void StreamMonitor::reset() {
  has_stream_ = false;
  held_ = false;
  width_ = height_ = 0;
  new_size_frames_ = 0;
}

void StreamMonitor::adopt(double stamp_s, double clock_s) {
  last_stamp_s_ = stamp_s;
  last_clock_s_ = clock_s;
}

StreamMonitor::Decision StreamMonitor::check(double stamp_s, double clock_s, int width,
                                             int height) {
  Decision d;
  if (!std::isfinite(stamp_s) || (config_.drop_zero_stamps && !(stamp_s > 0.0))) {
    d.action = Action::kDropZeroStamp;  // TF and every consumer read 0 as "no time"
    return d;
  }

  if (has_stream_ && (width != width_ || height != height_)) {
    if (width == new_width_ && height == new_height_) {
      ++new_size_frames_;
    } else {
      new_width_ = width;
      new_height_ = height;
      new_size_frames_ = 1;
    }
    if (new_size_frames_ < config_.size_change_frames) {
      d.action = Action::kDropStraySize;
      return d;
    }
    if (held_) d.held = Held::kDrop;  // a frame of the old stream
    reset();
    d.action = Action::kNewStreamSizeChanged;
  }
  new_size_frames_ = 0;

  if (!has_stream_) {
    has_stream_ = true;
    width_ = width;
    height_ = height;
    adopt(stamp_s, clock_s);
    return d;  // kProcess for the first frame
  }

  if (held_) {
    held_ = false;
    if (stamp_s > held_stamp_s_ - config_.max_backward_jump_s) {
      d.held = Held::kProcess;  // time did move on: the held frame was genuine
      adopt(held_stamp_s_, held_clock_s_);
    } else {
      d.held = Held::kDrop;  // back on the old time line: the held stamp was an outlier
    }
  }

  const double dt = stamp_s - last_stamp_s_;
  if (dt <= 0.0) {
    if (-dt <= config_.max_backward_jump_s) {
      d.action = Action::kDropOutOfOrder;
      return d;
    }
    adopt(stamp_s, clock_s);
    d.action = Action::kNewStreamTimeBackwards;
    return d;
  }
  if (dt - (clock_s - last_clock_s_) > config_.max_stamp_jump_s) {
    held_ = true;
    held_stamp_s_ = stamp_s;
    held_clock_s_ = clock_s;
    d.action = Action::kHold;
    return d;
  }
  adopt(stamp_s, clock_s);
  d.action = Action::kProcess;
  return d;
}

const char* StreamMonitor::describe(Action action) {
  switch (action) {
    case Action::kProcess:
      return "continue";
    case Action::kNewStreamTimeBackwards:
      return "time jumped back beyond max_backward_jump_s (a looped bag?)";
    case Action::kNewStreamSizeChanged:
      return "the image size changed for size_change_frames consecutive frames";
    case Action::kDropZeroStamp:
      return "the frame has no time stamp (0)";
    case Action::kDropOutOfOrder:
      return "the frame is a duplicate or out of order";
    case Action::kDropStraySize:
      return "the frame's size differs from the stream's";
    case Action::kHold:
      return "the stamp jumped ahead of the clock; waiting for the next frame";
  }
  return "?";
}

}  // namespace long3r

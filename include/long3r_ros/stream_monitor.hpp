// Decides when an input stream must start over.
//
// A replayed bag that loops sends time backwards; a camera that changes
// resolution changes the image size. LONG3R's memory and the map only make
// sense within one continuous stream, so both reset the stream (with a
// warning) instead of corrupting it. Pure C++ so it is unit-testable.
#pragma once

#include <string>

namespace long3r_ros {

class StreamMonitor {
 public:
  enum class Decision { kFirstFrame, kContinue, kResetSizeChanged, kResetTimeBackwards };

  // backwards_tolerance_s: stamps may go back by this much (reordered
  // messages) before it counts as a jump back in time.
  explicit StreamMonitor(double backwards_tolerance_s = 0.0)
      : backwards_tolerance_s_(backwards_tolerance_s) {}

  // Call once per incoming frame, in arrival order.
  Decision check(double stamp_s, int width, int height);

  // Forget the stream (after an external reset).
  void reset() { has_last_ = false; }

  static std::string describe(Decision d);

 private:
  double backwards_tolerance_s_;
  bool has_last_ = false;
  double last_stamp_s_ = 0.0;
  int last_width_ = 0;
  int last_height_ = 0;
};

}  // namespace long3r_ros

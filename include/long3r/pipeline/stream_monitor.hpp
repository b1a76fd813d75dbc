// Decides, frame by frame, whether an input frame continues the stream, is
// dropped, or starts a new stream, from its stamp, the clock at its arrival
// and its size.
//
// LONG3R's memory and the map only make sense within one continuous stream,
// and losing them is the worst thing that can happen to a user, so only two
// sustained conditions start a new stream: time jumping far back (a looped
// bag) and a lasting change of the image size. Everything that a single odd
// message can cause is dropped instead: a zero stamp ("no time"), a duplicate
// or a small reordering, one frame of another size, one stamp far ahead of
// its neighbours. A pause of any length continues the stream.
//
// "Far ahead" is judged against the clock (the clock at arrival; ROS: simulated
// time during a bag replay): a stamp that advanced by more than the clock did,
// plus `max_stamp_jump_s`, is held until the next frame tells whether time
// really moved on (the next frame continues from it: both are processed) or
// it was an outlier (the next frame continues from before it: it is dropped).
// Pure C++, unit-tested without ROS.
#pragma once

#include <string>

#include "long3r/config/config_fields.hpp"

namespace long3r {

struct StreamMonitorConfig {
  // Stamps at most this far behind the newest frame are reorderings or
  // duplicates (dropped); further back time jumped (new stream).
  double max_backward_jump_s = 1.0;
  // A stamp that advanced this much more than the clock is suspect (held).
  double max_stamp_jump_s = 5.0;
  // Consecutive frames of a new size before it is a new stream; fewer are
  // stray frames (dropped).
  int size_change_frames = 3;
  // A stamp of 0 (or less) means "no time", as in ROS, where TF and every
  // consumer read it so: such frames are dropped. Recorded data whose clock
  // starts at 0 turns this off.
  bool drop_zero_stamps = true;

  // Throws ConfigError naming the field.
  void validate(const config::FieldCheck& check) const;
};

template <class S, class V>
config::FieldsOf<S, StreamMonitorConfig> visit_fields(S& s, V& v) {
  v("max_backward_jump_s", s.max_backward_jump_s);
  v("max_stamp_jump_s", s.max_stamp_jump_s);
  v("size_change_frames", s.size_change_frames);
  v("drop_zero_stamps", s.drop_zero_stamps);
}

class StreamMonitor {
 public:
  enum class Action {
    kProcess,                 // continue the stream (or start the first one)
    kNewStreamTimeBackwards,  // start a new stream with this frame
    kNewStreamSizeChanged,    // start a new stream with this frame
    kDropZeroStamp,
    kDropOutOfOrder,  // a duplicate or a small reordering
    kDropStraySize,   // another size, not (yet) sustained
    kHold,            // far ahead of the clock: decided by the next frame
  };
  // What happens to the frame held by an earlier kHold, decided by this one
  // (before this frame's own action).
  enum class Held { kNone, kProcess, kDrop };
  struct Decision {
    Action action = Action::kProcess;
    Held held = Held::kNone;
  };

  explicit StreamMonitor(const StreamMonitorConfig& config = {}) : config_(config) {}

  // Once per incoming frame, in arrival order. clock_s: the time it arrived
  // (same clock for every call).
  Decision check(double stamp_s, double clock_s, int width, int height);

  // Whether a frame is held (its fate still open).
  bool holding() const { return held_; }

  // Forget the stream (after an external reset): the next frame starts one.
  void reset();

  static const char* describe(Action action);

 private:
  void adopt(double stamp_s, double clock_s);

  StreamMonitorConfig config_;
  bool has_stream_ = false;
  double last_stamp_s_ = 0.0, last_clock_s_ = 0.0;
  int width_ = 0, height_ = 0;
  // A new size being watched: how many consecutive frames had it.
  int new_width_ = 0, new_height_ = 0, new_size_frames_ = 0;
  bool held_ = false;
  double held_stamp_s_ = 0.0, held_clock_s_ = 0.0;
};

}  // namespace long3r

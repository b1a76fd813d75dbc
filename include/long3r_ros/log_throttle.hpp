// Throttling of log messages per kind of problem.
//
// ROS's *_THROTTLE macros throttle per call site: one call site reporting
// every bad encoding would report "yuv444" and then hide "32FC1" arriving
// within the period. Keys here are the kind of problem ("encoding 'yuv444'",
// "camera_info K[2] (cx) is nan"), so each kind is reported at once, and
// again at most once per period with the count of repeats in between.
//
// atStamp() writes the stamp into such a message, the one way the node's
// texts name a frame ("frame at t=%.3f skipped: ...").
#pragma once

#include <cstdint>
#include <cstdio>
#include <functional>
#include <map>
#include <mutex>
#include <string>

namespace long3r_ros {

// How the node's parts report a problem: a warning of a kind, throttled per
// kind by the node (NodeDiagnostics::warn, through a LogThrottle).
using Warn = std::function<void(const std::string& kind, const std::string& message)>;

class LogThrottle {
 public:
  explicit LogThrottle(double period_s) : period_s_(period_s) {}

  // True when `key` should be reported now (first seen, or last reported at
  // least a period ago); *repeats then holds how many were suppressed since.
  bool ready(const std::string& key, double now_s, std::uint64_t* repeats = nullptr) {
    std::lock_guard<std::mutex> lock(mutex_);
    // Keys come from messages (an encoding name): a hostile stream of
    // distinct ones must not grow the map without bound.
    if (entries_.size() >= kMaxKeys && entries_.count(key) == 0) entries_.clear();
    Entry& e = entries_[key];
    if (e.reported && now_s - e.last_s < period_s_) {
      ++e.suppressed;
      return false;
    }
    if (repeats) *repeats = e.suppressed;
    e = Entry{true, now_s, 0};
    return true;
  }

 private:
  struct Entry {
    bool reported = false;
    double last_s = 0.0;
    std::uint64_t suppressed = 0;
  };
  static constexpr std::size_t kMaxKeys = 256;
  const double period_s_;
  std::mutex mutex_;
  std::map<std::string, Entry> entries_;
};

// `fmt` (a printf format with one %f-like conversion) with `stamp_s`, e.g.
// atStamp("frame at t=%.3f skipped: ", 12.5) == "frame at t=12.500 skipped: ".
inline std::string atStamp(const char* fmt, double stamp_s) {
  const int n = std::snprintf(nullptr, 0, fmt, stamp_s);
  if (n <= 0) return fmt;
  std::string text(static_cast<std::size_t>(n), '\0');
  std::snprintf(text.data(), text.size() + 1, fmt, stamp_s);
  return text;
}

}  // namespace long3r_ros

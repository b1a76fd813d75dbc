// Counts over a sliding window of the last few diagnostics periods: frames
// received, processed, dropped and failed, and the latency (result published
// minus image stamp) of the processed frames.
//
// The node's diagnostics report these instead of averages since start-up, so
// a rate reads what the node does now and a warning clears once its cause is
// gone. The window has `periods` buckets; rotate() starts a new one (once per
// diagnostics update, as diagnostic_updater's FrequencyStatus counts its
// window). Thread-safe; pure C++.
#pragma once

#include <algorithm>
#include <cstdint>
#include <deque>
#include <limits>
#include <mutex>

namespace long3r_ros {

class WindowStats {
 public:
  struct Counts {
    std::uint64_t received = 0, processed = 0, dropped = 0, failed = 0;
    double latency_sum_s = 0.0;
    double latency_min_s = std::numeric_limits<double>::infinity();
    double latency_max_s = -std::numeric_limits<double>::infinity();
    double latencyMean() const { return processed > 0 ? latency_sum_s / processed : 0.0; }
  };

  explicit WindowStats(int periods = 5) : periods_(std::max(1, periods)) {
    buckets_.emplace_back();
  }

  void received() {
    add([](Counts& c) { ++c.received; });
  }
  void dropped(std::uint64_t n = 1) {
    add([n](Counts& c) { c.dropped += n; });
  }
  void failed() {
    add([](Counts& c) { ++c.failed; });
  }
  void processed(double latency_s) {
    add([latency_s](Counts& c) {
      ++c.processed;
      c.latency_sum_s += latency_s;
      c.latency_min_s = std::min(c.latency_min_s, latency_s);
      c.latency_max_s = std::max(c.latency_max_s, latency_s);
    });
  }

  // The sum over the window.
  Counts window() const {
    std::lock_guard<std::mutex> lock(mutex_);
    Counts sum;
    for (const Counts& b : buckets_) {
      sum.received += b.received;
      sum.processed += b.processed;
      sum.dropped += b.dropped;
      sum.failed += b.failed;
      sum.latency_sum_s += b.latency_sum_s;
      sum.latency_min_s = std::min(sum.latency_min_s, b.latency_min_s);
      sum.latency_max_s = std::max(sum.latency_max_s, b.latency_max_s);
    }
    return sum;
  }

  // Starts a new period; the oldest one leaves the window.
  void rotate() {
    std::lock_guard<std::mutex> lock(mutex_);
    buckets_.emplace_back();
    while (static_cast<int>(buckets_.size()) > periods_) buckets_.pop_front();
  }

 private:
  template <class F>
  void add(F f) {
    std::lock_guard<std::mutex> lock(mutex_);
    f(buckets_.back());
  }

  const int periods_;
  mutable std::mutex mutex_;
  std::deque<Counts> buckets_;
};

}  // namespace long3r_ros

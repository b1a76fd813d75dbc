// One background thread that runs posted jobs in order, one at a time.
//
// The pipeline hands it the map updates that need nothing back (the 3-D
// occupancy's ray casting, the fused surface's integration), so that the
// thread running the model goes on to the next frame while they run. It
// holds at most `max_pending` jobs: post() waits while that many are queued,
// so a map slower than the model slows the stream down instead of dropping
// views or growing without bound. Whoever reads or replaces what the jobs
// write calls wait_idle() first.
#pragma once

#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <exception>
#include <functional>
#include <mutex>
#include <thread>

namespace long3r {

class SerialWorker {
 public:
  // Throws std::invalid_argument for max_pending 0.
  explicit SerialWorker(std::size_t max_pending);
  // Runs the jobs still queued, then joins.
  ~SerialWorker();
  SerialWorker(const SerialWorker&) = delete;
  SerialWorker& operator=(const SerialWorker&) = delete;

  // Queues a job, waiting while max_pending jobs are queued. A job that
  // threw since the last post() has its exception rethrown here (once),
  // and this job is not queued.
  void post(std::function<void()> job);
  // Returns when every job posted before the call has run.
  void wait_idle() const;
  // Jobs queued or running.
  std::size_t pending() const;

 private:
  void run();

  const std::size_t max_pending_;
  mutable std::mutex mutex_;
  mutable std::condition_variable changed_;
  std::deque<std::function<void()>> jobs_;
  std::uint64_t posted_ = 0, done_ = 0;  // jobs queued and finished, ever
  bool stopping_ = false;
  std::exception_ptr failure_;
  std::thread thread_;  // last: started once the members above exist
};

}  // namespace long3r

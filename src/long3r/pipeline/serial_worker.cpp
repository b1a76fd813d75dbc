#include "long3r/pipeline/serial_worker.hpp"

#include <stdexcept>
#include <utility>

namespace long3r {

SerialWorker::SerialWorker(std::size_t max_pending) : max_pending_(max_pending) {
  if (max_pending == 0) throw std::invalid_argument("SerialWorker: max_pending must be >= 1");
  thread_ = std::thread([this] { run(); });
}

SerialWorker::~SerialWorker() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stopping_ = true;
  }
  changed_.notify_all();
  thread_.join();
}

void SerialWorker::post(std::function<void()> job) {
  std::unique_lock<std::mutex> lock(mutex_);
  if (failure_) {
    std::exception_ptr failure = std::exchange(failure_, nullptr);
    std::rethrow_exception(failure);
  }
  changed_.wait(lock, [this] { return jobs_.size() < max_pending_; });
  jobs_.push_back(std::move(job));
  ++posted_;
  lock.unlock();
  changed_.notify_all();
}

void SerialWorker::wait_idle() const {
  std::unique_lock<std::mutex> lock(mutex_);
  // Only the jobs posted so far: a stream of new ones does not hold it up.
  const std::uint64_t posted = posted_;
  changed_.wait(lock, [this, posted] { return done_ >= posted; });
}

std::size_t SerialWorker::pending() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return static_cast<std::size_t>(posted_ - done_);
}

void SerialWorker::run() {
  std::unique_lock<std::mutex> lock(mutex_);
  for (;;) {
    changed_.wait(lock, [this] { return stopping_ || !jobs_.empty(); });
    if (jobs_.empty()) return;  // stopping, nothing left
    std::function<void()> job = std::move(jobs_.front());
    jobs_.pop_front();
    lock.unlock();
    changed_.notify_all();  // a slot is free for post()
    std::exception_ptr failure;
    try {
      job();
    } catch (...) {
      failure = std::current_exception();
    }
    lock.lock();
    ++done_;
    if (failure && !failure_) failure_ = failure;
    changed_.notify_all();  // wait_idle() may return
  }
}

}  // namespace long3r

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <future>
#include <mutex>
#include <stdexcept>
#include <thread>
#include <vector>

#include "long3r/pipeline/serial_worker.hpp"

using long3r::SerialWorker;
using namespace std::chrono_literals;

TEST(SerialWorker, RejectsNoPendingJobs) { EXPECT_THROW(SerialWorker(0), std::invalid_argument); }

TEST(SerialWorker, RunsJobsInOrderOffTheCallersThread) {
  std::vector<int> order;
  std::vector<std::thread::id> threads;
  {
    SerialWorker worker(2);
    for (int i = 0; i < 50; ++i) {
      worker.post([&, i] {  // one job at a time, so no lock is needed
        order.push_back(i);
        threads.push_back(std::this_thread::get_id());
      });
    }
    worker.wait_idle();
    EXPECT_EQ(worker.pending(), 0u);
    ASSERT_EQ(order.size(), 50u);
    for (int i = 0; i < 50; ++i) EXPECT_EQ(order[static_cast<size_t>(i)], i);
    for (const std::thread::id& id : threads) EXPECT_NE(id, std::this_thread::get_id());
  }
}

// post() waits while max_pending jobs are queued: nothing is dropped.
TEST(SerialWorker, PostWaitsWhileFull) {
  SerialWorker worker(1);
  std::promise<void> release;
  std::shared_future<void> released = release.get_future().share();
  std::atomic<int> ran{0};
  worker.post([released, &ran] {
    released.wait();
    ++ran;
  });
  // The first job runs (blocked) once taken; one more fits in the queue.
  worker.post([&ran] { ++ran; });
  std::atomic<bool> third_posted{false};
  std::thread poster([&] {
    worker.post([&ran] { ++ran; });
    third_posted = true;
  });
  std::this_thread::sleep_for(50ms);
  EXPECT_FALSE(third_posted.load());  // the queue holds one: it waits
  EXPECT_EQ(worker.pending(), 2u);
  release.set_value();
  poster.join();
  worker.wait_idle();
  EXPECT_TRUE(third_posted.load());
  EXPECT_EQ(ran.load(), 3);
}

// A job's exception reaches the next post(), once; the worker goes on.
TEST(SerialWorker, RethrowsAJobsExceptionAtTheNextPost) {
  SerialWorker worker(2);
  worker.post([] { throw std::runtime_error("a bad view"); });
  worker.wait_idle();
  try {
    worker.post([] {});
    ADD_FAILURE() << "the job's exception was not rethrown";
  } catch (const std::runtime_error& e) {
    EXPECT_STREQ(e.what(), "a bad view");
  }
  int ran = 0;
  worker.post([&ran] { ++ran; });
  worker.wait_idle();
  EXPECT_EQ(ran, 1);
}

// The destructor runs what is still queued.
TEST(SerialWorker, FinishesQueuedJobsWhenDestroyed) {
  std::atomic<int> ran{0};
  {
    SerialWorker worker(4);
    for (int i = 0; i < 4; ++i) {
      worker.post([&ran] {
        std::this_thread::sleep_for(5ms);
        ++ran;
      });
    }
  }
  EXPECT_EQ(ran.load(), 4);
}

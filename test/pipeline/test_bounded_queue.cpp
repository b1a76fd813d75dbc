#include <gtest/gtest.h>

#include <chrono>
#include <thread>

#include "long3r/pipeline/bounded_queue.hpp"

using long3r::BoundedQueue;
using namespace std::chrono_literals;

TEST(BoundedQueue, RejectsZeroCapacity) {
  EXPECT_THROW(BoundedQueue<int>(0), std::invalid_argument);
}

TEST(BoundedQueue, NewestWinsWhenFull) {
  BoundedQueue<int> q(2);
  EXPECT_FALSE(q.push(1));
  EXPECT_FALSE(q.push(2));
  EXPECT_TRUE(q.push(3));  // drops 1
  EXPECT_TRUE(q.push(4));  // drops 2
  EXPECT_EQ(q.dropped(), 2u);
  EXPECT_EQ(q.size(), 2u);
  EXPECT_EQ(*q.pop(0ms), 3);
  EXPECT_EQ(*q.pop(0ms), 4);
  EXPECT_FALSE(q.pop(0ms).has_value());
}

TEST(BoundedQueue, PopTimesOutWhenEmpty) {
  BoundedQueue<int> q(1);
  auto start = std::chrono::steady_clock::now();
  EXPECT_FALSE(q.pop(20ms).has_value());
  EXPECT_GE(std::chrono::steady_clock::now() - start, 15ms);
}

TEST(BoundedQueue, CloseWakesWaiterAndDiscardsLaterPushes) {
  BoundedQueue<int> q(1);
  std::optional<int> got = 42;
  std::thread consumer([&] { got = q.pop(10s); });
  std::this_thread::sleep_for(20ms);
  q.close();
  consumer.join();
  EXPECT_FALSE(got.has_value());
  EXPECT_TRUE(q.push(7));
  EXPECT_EQ(q.size(), 0u);
  EXPECT_EQ(q.dropped(), 1u);
}

TEST(BoundedQueue, HandsItemsAcrossThreadsInOrder) {
  BoundedQueue<int> q(1000);
  std::thread producer([&] {
    for (int i = 0; i < 500; ++i) q.push(i);
  });
  int expected = 0;
  while (expected < 500) {
    auto v = q.pop(1s);
    ASSERT_TRUE(v.has_value());
    EXPECT_EQ(*v, expected++);
  }
  producer.join();
  EXPECT_EQ(q.dropped(), 0u);
}

TEST(BoundedQueue, ClearingCountsTheItemsAsDropped) {
  BoundedQueue<int> q(4);
  q.push(1);
  q.push(2);
  q.push(3);
  q.clear();  // ~reset: the queued frames go, counted
  EXPECT_EQ(q.size(), 0u);
  EXPECT_EQ(q.dropped(), 3u);
}

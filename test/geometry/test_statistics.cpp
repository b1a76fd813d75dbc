#include <gtest/gtest.h>

#include <limits>
#include <vector>

#include "long3r/geometry/statistics.hpp"

using long3r::median;

TEST(Median, OddCountIsTheMiddleValue) {
  EXPECT_DOUBLE_EQ(median({5.0, 1.0, 3.0}), 3.0);
  EXPECT_DOUBLE_EQ(median({7.0}), 7.0);
}

TEST(Median, EvenCountAveragesTheMiddlePair) {
  EXPECT_DOUBLE_EQ(median({4.0, 1.0, 3.0, 2.0}), 2.5);
  EXPECT_DOUBLE_EQ(median({-1.0, 1.0}), 0.0);
  // Repeated values: the middle pair is equal.
  EXPECT_DOUBLE_EQ(median({2.0, 2.0, 9.0, 0.0}), 2.0);
}

TEST(Median, EmptyIsZero) { EXPECT_DOUBLE_EQ(median({}), 0.0); }

TEST(Median, ResistsOutliers) {
  std::vector<double> v(101, 1.0);
  for (int i = 0; i < 50; ++i) v[static_cast<size_t>(i)] = std::numeric_limits<double>::max();
  EXPECT_DOUBLE_EQ(median(v), 1.0);
}

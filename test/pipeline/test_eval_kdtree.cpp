#include <gtest/gtest.h>

#include <algorithm>
#include <random>

#include "long3r/kdtree3.hpp"

TEST(EvalKdTree, MatchesBruteForce) {
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<float> u(-2.0f, 2.0f);
  std::vector<Eigen::Vector3f> pts(3000);
  for (auto& p : pts) p = Eigen::Vector3f(u(rng), u(rng), 0.2f * u(rng));
  // Duplicates must not break the tree.
  for (int i = 0; i < 50; ++i) pts.push_back(pts[i]);
  const long3r::KdTree3 tree(pts);
  ASSERT_EQ(tree.size(), pts.size());
  std::vector<int> idx;
  std::vector<float> d2;
  for (int q = 0; q < 300; ++q) {
    const Eigen::Vector3f query(u(rng) * 1.3f, u(rng) * 1.3f, u(rng));
    std::vector<std::pair<float, int>> brute;
    for (size_t i = 0; i < pts.size(); ++i)
      brute.emplace_back((pts[i] - query).squaredNorm(), static_cast<int>(i));
    std::sort(brute.begin(), brute.end());
    float best;
    const int n = tree.nearest(query, &best);
    EXPECT_EQ(best, brute[0].first);
    EXPECT_EQ((pts[n] - query).squaredNorm(), brute[0].first);
    tree.knn(query, 7, &idx, &d2);
    ASSERT_EQ(idx.size(), 7u);
    for (int k = 0; k < 7; ++k) EXPECT_EQ(d2[k], brute[k].first) << "rank " << k;
  }
}

TEST(EvalKdTree, EmptyAndSmall) {
  long3r::KdTree3 empty;
  float d2 = 0;
  EXPECT_EQ(empty.nearest(Eigen::Vector3f::Zero(), &d2), -1);
  const long3r::KdTree3 two({Eigen::Vector3f(0, 0, 0), Eigen::Vector3f(1, 0, 0)});
  std::vector<int> idx;
  std::vector<float> dd;
  two.knn(Eigen::Vector3f(0.9f, 0, 0), 5, &idx, &dd);
  ASSERT_EQ(idx.size(), 2u);
  EXPECT_EQ(idx[0], 1);
  EXPECT_EQ(idx[1], 0);
}

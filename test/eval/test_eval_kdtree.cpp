// KdTree3 (nanoflann underneath) against brute force: the same squared
// distances, bit for bit, and the same neighbours in (distance, index) order.
#include <gtest/gtest.h>

#include <algorithm>
#include <limits>
#include <random>
#include <utility>

#include "long3r/eval/kdtree3.hpp"
#include "long3r/eval/nearest_carry.hpp"

namespace {
// The reference: (squared distance, index) of every point, closest first.
std::vector<std::pair<float, int>> by_distance(const std::vector<Eigen::Vector3f>& pts,
                                               const Eigen::Vector3f& query) {
  std::vector<std::pair<float, int>> out;
  for (size_t i = 0; i < pts.size(); ++i)
    out.emplace_back((pts[i] - query).squaredNorm(), static_cast<int>(i));
  std::sort(out.begin(), out.end());
  return out;
}
}  // namespace

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
    const auto brute = by_distance(pts, query);
    float best;
    const int n = tree.nearest(query, &best);
    EXPECT_EQ(best, brute[0].first);
    EXPECT_EQ(n, brute[0].second);
    tree.knn(query, 7, &idx, &d2);
    ASSERT_EQ(idx.size(), 7u);
    for (int k = 0; k < 7; ++k) {
      EXPECT_EQ(d2[k], brute[k].first) << "rank " << k;
      EXPECT_EQ(idx[k], brute[k].second) << "rank " << k;
    }
  }
  // Queries on the duplicated points: distance 0 twice, lowest index first.
  for (int i = 0; i < 50; ++i) {
    float best;
    EXPECT_EQ(tree.nearest(pts[i], &best), i);
    EXPECT_EQ(best, 0.0f);
    tree.knn(pts[i], 2, &idx, nullptr);
    EXPECT_EQ(idx, (std::vector<int>{i, 3000 + i}));
  }
}

TEST(EvalKdTree, EmptyAndSmall) {
  long3r::KdTree3 empty;
  float d2 = 0;
  EXPECT_EQ(empty.nearest(Eigen::Vector3f::Zero(), &d2), -1);
  EXPECT_EQ(d2, std::numeric_limits<float>::infinity());
  std::vector<int> none{1};
  empty.knn(Eigen::Vector3f::Zero(), 3, &none, nullptr);
  EXPECT_TRUE(none.empty());
  long3r::KdTree3 two({Eigen::Vector3f(0, 0, 0), Eigen::Vector3f(1, 0, 0)});
  std::vector<int> idx;
  std::vector<float> dd;
  two.knn(Eigen::Vector3f(0.9f, 0, 0), 5, &idx, &dd);
  ASSERT_EQ(idx.size(), 2u);
  EXPECT_EQ(idx[0], 1);
  EXPECT_EQ(idx[1], 0);
  const Eigen::Vector3f q(0.9f, 0, 0);
  EXPECT_EQ(dd,
            (std::vector<float>{(q - Eigen::Vector3f(1, 0, 0)).squaredNorm(), q.squaredNorm()}));
  // A moved tree keeps answering over its own copy of the points.
  long3r::KdTree3 moved(std::move(two));
  EXPECT_EQ(moved.nearest(Eigen::Vector3f(0.1f, 0, 0)), 0);
  long3r::KdTree3 assigned;
  assigned = std::move(moved);
  EXPECT_EQ(assigned.size(), 2u);
  EXPECT_EQ(assigned.nearest(Eigen::Vector3f(0.8f, 0, 0)), 1);
}

// A degenerate prediction (an untrained model collapses to a blob) queried
// from far away, and a cloud of coincident points: results must stay exact.
TEST(EvalKdTree, FarQueriesAndCoincidentPoints) {
  std::mt19937_64 rng(11);
  std::normal_distribution<float> n(0.0f, 0.01f);
  std::vector<Eigen::Vector3f> pts;
  for (int i = 0; i < 2000; ++i) pts.emplace_back(n(rng), n(rng), 1.0f + n(rng));
  const Eigen::Vector3f same(0.5f, 0.5f, 0.5f);
  for (int i = 0; i < 500; ++i) pts.push_back(same);
  const long3r::KdTree3 tree(pts);
  std::uniform_real_distribution<float> u(-20.0f, 20.0f);
  std::vector<int> idx;
  std::vector<float> d2;
  for (int q = 0; q < 200; ++q) {
    const Eigen::Vector3f query = q % 4 == 0
                                      ? Eigen::Vector3f(same + Eigen::Vector3f(0.3f, 0.0f, 0.0f))
                                      : Eigen::Vector3f(u(rng), u(rng), u(rng));
    const auto brute = by_distance(pts, query);
    float best;
    const int i = tree.nearest(query, &best);
    EXPECT_EQ(best, brute[0].first);
    ASSERT_GE(i, 0);
    EXPECT_EQ(i, brute[0].second);
    EXPECT_EQ((pts[i] - query).squaredNorm(), best);
    tree.knn(query, 9, &idx, &d2);
    ASSERT_EQ(idx.size(), 9u);
    for (int k = 0; k < 9; ++k) {
      EXPECT_EQ(d2[k], brute[k].first) << "rank " << k;
      EXPECT_EQ(idx[k], brute[k].second) << "rank " << k;
      EXPECT_EQ((pts[idx[k]] - query).squaredNorm(), d2[k]);
    }
  }
  // On the coincident points: 30 neighbours at distance 0, the lowest indices.
  tree.knn(same, 30, &idx, &d2);
  ASSERT_EQ(idx.size(), 30u);
  for (int k = 0; k < 30; ++k) {
    EXPECT_EQ(idx[k], 2000 + k);
    EXPECT_EQ(d2[k], 0.0f);
  }
  // Very far queries (metres to kilometres from a centimetre blob).
  for (float far : {50.0f, 1e3f, 1e5f}) {
    const Eigen::Vector3f query(far, -0.5f * far, 0.25f * far);
    const auto brute = by_distance(pts, query);
    tree.knn(query, 5, &idx, &d2);
    for (int k = 0; k < 5; ++k) {
      EXPECT_EQ(d2[k], brute[k].first) << far << " rank " << k;
      EXPECT_EQ(idx[k], brute[k].second) << far << " rank " << k;
    }
  }
}

// The nearest point carried along a moving query (ICP's correspondences):
// the same point and squared distance as brute force at every position, on a
// grid full of exact ties and a cloud with duplicates, with steps from far
// below to far above the point spacing; small steps must reuse answers.
TEST(EvalKdTree, NearestCarryMatchesBruteForceAlongAPath) {
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  std::vector<Eigen::Vector3f> pts;
  for (int x = 0; x < 12; ++x) {
    for (int y = 0; y < 12; ++y) pts.emplace_back(0.05f * x, 0.05f * y, 0.0f);  // ties
  }
  for (int i = 0; i < 1500; ++i) pts.emplace_back(0.3f * u(rng), 0.3f * u(rng), 0.1f * u(rng));
  for (int i = 0; i < 40; ++i) pts.push_back(pts[200 + i]);  // duplicates
  const long3r::KdTree3 tree(pts);
  std::vector<int> idx;
  std::vector<float> dd;
  int calls = 0, searches = 0;
  for (int path = 0; path < 60; ++path) {
    long3r::detail::NearestCarry carry;
    Eigen::Vector3f q(0.3f * u(rng), 0.3f * u(rng), 0.1f * u(rng));
    if (path % 3 == 0) q = pts[static_cast<size_t>(path)];  // starts on a grid point
    const float step = path % 4 == 0   ? 1e-7f
                       : path % 4 == 1 ? 1e-4f
                       : path % 4 == 2 ? 3e-3f
                                       : 0.05f;
    for (int s = 0; s < 40; ++s) {
      const auto brute = by_distance(pts, q);
      float d2 = -1.0f;
      const int j = carry.nearest(tree, q, &d2, &idx, &dd);
      ASSERT_EQ(j, brute[0].second) << "path " << path << " step " << s;
      ASSERT_EQ(d2, brute[0].first) << "path " << path << " step " << s;
      q += step * Eigen::Vector3f(u(rng), u(rng), u(rng));
      ++calls;
    }
    searches += carry.searches();
  }
  EXPECT_LT(searches, calls / 2);
}

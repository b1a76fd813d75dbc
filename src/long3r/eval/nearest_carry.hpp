// The nearest point of a query that moves a little between calls (an ICP
// source point under successive transforms), exactly as KdTree3::nearest
// finds it, without searching again while the motion cannot have changed it
// (private helper of the evaluation code).
#pragma once

#include <Eigen/Core>

#include <cmath>
#include <limits>
#include <vector>

#include "long3r/eval/kdtree3.hpp"

namespace long3r::detail {

// A search finds the two nearest points of the query q: j at squared distance
// f1, the next one at f2. At a later position q', delta = |q' - q| away,
// every point but j is at least sqrt(f2) - delta from q', and j at most
// sqrt(f1) + delta (triangle inequality). When the first exceeds the second
// by more than the roundings of float distances (each within a few 2^-24
// relative of the exact one; 2^-16 relative is kept, plus 1e-18 for distances
// that underflow), j is still the nearest point of q' as brute force finds it
// (no tie is possible), and only its distance is computed, as brute force
// computes it. Otherwise the two nearest points are searched again.
class NearestCarry {
 public:
  // `idx` and `dd` are scratch space for the search (reused across calls).
  int nearest(const KdTree3& tree, const Eigen::Vector3f& query, float* squared_distance,
              std::vector<int>* idx, std::vector<float>* dd) {
    if (nearest_ >= 0 && unchanged(query)) {
      *squared_distance = (tree.points()[nearest_] - query).squaredNorm();
      return nearest_;
    }
    ++searches_;
    tree.knn(query, 2, idx, dd);
    at_ = query;
    nearest_ = idx->empty() ? -1 : (*idx)[0];
    first_ = dd->empty() ? std::numeric_limits<float>::infinity() : (*dd)[0];
    // With one point in the tree no other point can come closer.
    second_ = dd->size() > 1 ? (*dd)[1] : std::numeric_limits<float>::infinity();
    *squared_distance = first_;
    return nearest_;
  }

  // Searches done so far (the rest of the calls reused the last answer).
  int searches() const { return searches_; }

 private:
  bool unchanged(const Eigen::Vector3f& query) const {
    constexpr double kSlack = 0x1p-16, kFloor = 1e-18;
    const double delta = (query.cast<double>() - at_.cast<double>()).norm();
    const double others_at_least = std::sqrt(static_cast<double>(second_)) * (1.0 - kSlack) - delta;
    const double nearest_at_most = std::sqrt(static_cast<double>(first_)) * (1.0 + kSlack) + delta;
    return others_at_least > nearest_at_most * (1.0 + kSlack) + kFloor;
  }

  Eigen::Vector3f at_ = Eigen::Vector3f::Zero();
  int nearest_ = -1;
  float first_ = 0.0f, second_ = 0.0f;
  int searches_ = 0;
};

}  // namespace long3r::detail

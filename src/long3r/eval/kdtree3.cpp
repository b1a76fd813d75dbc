#include "long3r/eval/kdtree3.hpp"

#include <algorithm>
#include <limits>
#include <stdexcept>

namespace long3r {

namespace {
constexpr int32_t kLeafSize = 8;

// Fixed-capacity sorted list of the best k candidates (k is small).
class BestK {
 public:
  explicit BestK(int k) : k_(k) {
    idx_.reserve(k);
    d2_.reserve(k);
  }
  float worst() const {
    return static_cast<int>(d2_.size()) < k_ ? std::numeric_limits<float>::infinity() : d2_.back();
  }
  void offer(int index, float d2) {
    if (d2 >= worst()) return;
    auto pos = std::upper_bound(d2_.begin(), d2_.end(), d2) - d2_.begin();
    if (static_cast<int>(d2_.size()) == k_) {
      d2_.pop_back();
      idx_.pop_back();
    }
    d2_.insert(d2_.begin() + pos, d2);
    idx_.insert(idx_.begin() + pos, index);
  }
  std::vector<int> idx_;
  std::vector<float> d2_;

 private:
  int k_;
};
}  // namespace

void KdTree3::build(const std::vector<Eigen::Vector3f>& points) {
  if (points.size() > static_cast<size_t>(std::numeric_limits<int32_t>::max() / 2)) {
    throw std::invalid_argument("KdTree3: too many points");
  }
  points_ = points;
  order_.resize(points_.size());
  for (size_t i = 0; i < order_.size(); ++i) order_[i] = static_cast<int32_t>(i);
  nodes_.clear();
  nodes_.reserve(2 * points_.size() / kLeafSize + 2);
  if (!points_.empty()) build_node(0, static_cast<int32_t>(points_.size()));
}

int32_t KdTree3::build_node(int32_t begin, int32_t end) {
  const int32_t id = static_cast<int32_t>(nodes_.size());
  nodes_.emplace_back();
  Eigen::Vector3f lo = points_[order_[begin]], hi = lo;
  for (int32_t i = begin + 1; i < end; ++i) {
    lo = lo.cwiseMin(points_[order_[i]]);
    hi = hi.cwiseMax(points_[order_[i]]);
  }
  Node& node = nodes_[id];
  node.begin = begin;
  node.end = end;
  node.lo = lo;
  node.hi = hi;
  if (end - begin <= kLeafSize) return id;

  int axis = 0;
  (hi - lo).maxCoeff(&axis);
  if (!(hi(axis) > lo(axis))) {
    // All points equal: one leaf, lowest index first (the tie-break of nearest).
    std::sort(order_.begin() + begin, order_.begin() + end);
    node.coincident = true;
    return id;
  }

  const int32_t mid = begin + (end - begin) / 2;
  std::nth_element(order_.begin() + begin, order_.begin() + mid, order_.begin() + end,
                   [&](int32_t a, int32_t b) { return points_[a](axis) < points_[b](axis); });
  const int32_t left = build_node(begin, mid);
  const int32_t right = build_node(mid, end);
  // nodes_ may have reallocated: index again.
  nodes_[id].axis = axis;
  nodes_[id].left = left;
  nodes_[id].right = right;
  return id;
}

template <typename BoundFn, typename LeafFn>
void KdTree3::traverse(const Eigen::Vector3f& query, BoundFn current_bound,
                       LeafFn visit_leaf) const {
  // Explicit stack of (node, squared distance from the query to its box).
  struct Item {
    int32_t node;
    float bound;
  };
  Item stack[128];
  int top = 0;
  stack[top++] = {0, box_distance2(nodes_[0], query)};
  while (top > 0) {
    const Item item = stack[--top];
    if (item.bound >= current_bound()) continue;
    const Node& n = nodes_[item.node];
    if (n.axis < 0) {
      visit_leaf(n);
      continue;
    }
    const float dl = box_distance2(nodes_[n.left], query);
    const float dr = box_distance2(nodes_[n.right], query);
    // Far side first so the near side is popped (and searched) next.
    stack[top++] = {dl <= dr ? n.right : n.left, std::max(dl, dr)};
    stack[top++] = {dl <= dr ? n.left : n.right, std::min(dl, dr)};
  }
}

int KdTree3::nearest(const Eigen::Vector3f& query, float* squared_distance) const {
  if (points_.empty()) {
    if (squared_distance) *squared_distance = std::numeric_limits<float>::infinity();
    return -1;
  }
  int best = -1;
  float best_d2 = std::numeric_limits<float>::infinity();
  traverse(
      query, [&] { return best_d2; },
      [&](const Node& n) {
        const int32_t end = n.coincident ? n.begin + 1 : n.end;
        for (int32_t i = n.begin; i < end; ++i) {
          const int32_t p = order_[i];
          const float d2 = (points_[p] - query).squaredNorm();
          if (d2 < best_d2 || (d2 == best_d2 && p < best)) {
            best_d2 = d2;
            best = p;
          }
        }
      });
  if (squared_distance) *squared_distance = best_d2;
  return best;
}

void KdTree3::knn(const Eigen::Vector3f& query, int k, std::vector<int>* indices,
                  std::vector<float>* squared_distances) const {
  indices->clear();
  if (squared_distances) squared_distances->clear();
  k = std::min<int>(k, static_cast<int>(points_.size()));
  if (k <= 0) return;
  BestK best(k);
  traverse(
      query, [&] { return best.worst(); },
      [&](const Node& n) {
        const int32_t end = n.coincident ? std::min(n.end, n.begin + k) : n.end;
        for (int32_t i = n.begin; i < end; ++i) {
          const int32_t p = order_[i];
          best.offer(p, (points_[p] - query).squaredNorm());
        }
      });
  *indices = std::move(best.idx_);
  if (squared_distances) *squared_distances = std::move(best.d2_);
}

}  // namespace long3r

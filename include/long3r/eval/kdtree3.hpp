// Exact nearest-neighbour search over a static 3D point set (k-d tree).
//
// Used by the reconstruction metrics (accuracy, completion, normal estimation)
// and ICP. Build once, then query from any number of threads: queries are
// const and allocate nothing shared. Distances are Euclidean, returned squared.
#pragma once

#include <Eigen/Core>

#include <cstdint>
#include <vector>

namespace long3r {

class KdTree3 {
 public:
  KdTree3() = default;
  explicit KdTree3(const std::vector<Eigen::Vector3f>& points) { build(points); }

  // Copies the points and builds the tree (leaves of at most 8 points).
  void build(const std::vector<Eigen::Vector3f>& points);

  size_t size() const { return points_.size(); }
  bool empty() const { return points_.empty(); }
  const std::vector<Eigen::Vector3f>& points() const { return points_; }

  // Index of the nearest point (-1 if empty) and its squared distance.
  int nearest(const Eigen::Vector3f& query, float* squared_distance = nullptr) const;

  // The min(k, size()) nearest points, closest first.
  void knn(const Eigen::Vector3f& query, int k, std::vector<int>* indices,
           std::vector<float>* squared_distances) const;

 private:
  struct Node {
    // Leaf: [begin, end) in order_. Inner: split axis, children.
    int32_t begin = 0, end = 0;
    int32_t left = -1, right = -1;
    int32_t axis = -1;
    // Leaf whose points all coincide (its order_ range is sorted by index):
    // a query need only look at the first k of them.
    bool coincident = false;
    // Tight bounding box of the node's points. Pruning by the distance to
    // the box (not to the split plane alone) keeps queries far from the
    // cloud cheap: with plane bounds alone they visit nearly every node.
    Eigen::Vector3f lo = Eigen::Vector3f::Zero(), hi = Eigen::Vector3f::Zero();
  };
  float box_distance2(const Node& n, const Eigen::Vector3f& q) const {
    return (n.lo - q).cwiseMax(q - n.hi).cwiseMax(0.0f).squaredNorm();
  }
  int32_t build_node(int32_t begin, int32_t end);
  // Depth-first search, nearer child first, skipping nodes whose box is no
  // closer than current_bound(); visit_leaf(node) scores a leaf's points.
  template <typename BoundFn, typename LeafFn>
  void traverse(const Eigen::Vector3f& query, BoundFn current_bound, LeafFn visit_leaf) const;

  std::vector<Eigen::Vector3f> points_;
  std::vector<int32_t> order_;
  std::vector<Node> nodes_;
};

}  // namespace long3r

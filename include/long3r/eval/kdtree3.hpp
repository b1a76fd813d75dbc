// Exact nearest-neighbour search over a static 3D point set: nanoflann's k-d
// tree with a result set that makes the answer exactly that of brute force.
//
// Used by the reconstruction metrics (accuracy, completion, normal estimation)
// and ICP. Build once, then query from any number of threads: queries are
// const and allocate nothing shared. Distances are Euclidean, returned
// squared, computed as (point - query).squaredNorm() in float; neighbours are
// ordered by (squared distance, index), so ties go to the lowest index.
#pragma once

#include <Eigen/Core>

#include <memory>
#include <vector>

namespace long3r {

class KdTree3 {
 public:
  KdTree3();
  explicit KdTree3(const std::vector<Eigen::Vector3f>& points);
  ~KdTree3();
  KdTree3(KdTree3&&) noexcept;
  KdTree3& operator=(KdTree3&&) noexcept;
  KdTree3(const KdTree3&) = delete;
  KdTree3& operator=(const KdTree3&) = delete;

  // Copies the points and builds the tree.
  void build(const std::vector<Eigen::Vector3f>& points);

  size_t size() const { return points_.size(); }
  bool empty() const { return points_.empty(); }
  const std::vector<Eigen::Vector3f>& points() const { return points_; }

  // Index of the nearest point (-1 if empty) and its squared distance
  // (infinity if empty).
  int nearest(const Eigen::Vector3f& query, float* squared_distance = nullptr) const;

  // The min(k, size()) nearest points, closest first.
  void knn(const Eigen::Vector3f& query, int k, std::vector<int>* indices,
           std::vector<float>* squared_distances) const;

 private:
  struct Index;  // nodes and points in leaf order, kept out of this header
  std::vector<Eigen::Vector3f> points_;
  std::unique_ptr<Index> index_;
};

}  // namespace long3r

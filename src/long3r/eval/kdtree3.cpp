#include "long3r/eval/kdtree3.hpp"

#include <nanoflann.hpp>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <stdexcept>
#include <utility>

namespace long3r {

namespace {

// nanoflann's view of the points.
struct Cloud {
  const std::vector<Eigen::Vector3f>* points;
  size_t kdtree_get_point_count() const { return points->size(); }
  float kdtree_get_pt(size_t i, size_t dim) const { return (*points)[i][static_cast<int>(dim)]; }
  template <class Box>
  bool kdtree_get_bbox(Box&) const {
    return false;
  }
};

// Distances in double inside the tree: its box bounds, accumulated level by
// level, then carry no rounding worth the name.
using Tree = nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<float, Cloud, double>,
                                                 Cloud, 3, uint32_t>;

// The k best (squared distance, index) pairs seen, in that order, with the
// distance computed as brute force does ((point - query).squaredNorm() in
// float). nanoflann offers only points closer than worstDist() (in its double
// distance, which differs from the float one by a few float roundings) and
// skips subtrees whose box is not closer; worstDist() is therefore the k-th
// float distance widened by 2^-18 (over ten times those roundings) and one
// step up, so that every point that can still enter the list, ties at the
// k-th distance included, is offered.
class ExactKnn {
 public:
  ExactKnn(const std::vector<Eigen::Vector3f>& points, const Eigen::Vector3f& query, int k,
           int* idx, float* d2)
      : points_(points), query_(query), k_(k), idx_(idx), d2_(d2) {}

  size_t size() const { return static_cast<size_t>(count_); }
  bool full() const { return count_ == k_; }
  double worstDist() const { return bound_; }

  bool addPoint(double /*nanoflann's distance*/, uint32_t index) {
    const int i = static_cast<int>(index);
    const float d = (points_[index] - query_).squaredNorm();
    if (full() && !(d < d2_[k_ - 1] || (d == d2_[k_ - 1] && i < idx_[k_ - 1]))) return true;
    int pos = count_ < k_ ? count_++ : k_ - 1;
    while (pos > 0 && (d < d2_[pos - 1] || (d == d2_[pos - 1] && i < idx_[pos - 1]))) {
      d2_[pos] = d2_[pos - 1];
      idx_[pos] = idx_[pos - 1];
      --pos;
    }
    d2_[pos] = d;
    idx_[pos] = i;
    if (full()) {
      const double w = d2_[k_ - 1];
      bound_ = std::nextafter(w + w * 0x1p-18, std::numeric_limits<double>::infinity());
    }
    return true;
  }

 private:
  const std::vector<Eigen::Vector3f>& points_;
  const Eigen::Vector3f query_;
  const int k_;
  int* idx_;
  float* d2_;
  int count_ = 0;
  double bound_ = std::numeric_limits<double>::infinity();
};

}  // namespace

// Points per leaf. nanoflann bounds a subtree by the distance to its split
// cells, looser than the box of its points, so larger leaves pay off: on the
// scoring benchmark's 200k-point clouds 32 took about half the CPU time of
// nanoflann's default 10 for k = 30 and a third less for the nearest point.
constexpr size_t kLeafSize = 32;

struct KdTree3::Index {
  Cloud cloud;
  Tree tree;
  explicit Index(const std::vector<Eigen::Vector3f>* points)
      : cloud{points}, tree(3, cloud, nanoflann::KDTreeSingleIndexAdaptorParams(kLeafSize)) {}
};

KdTree3::KdTree3() = default;
KdTree3::KdTree3(const std::vector<Eigen::Vector3f>& points) { build(points); }
KdTree3::~KdTree3() = default;
// The index refers to the points_ member: after a move, to the new owner's.
KdTree3::KdTree3(KdTree3&& other) noexcept
    : points_(std::move(other.points_)), index_(std::move(other.index_)) {
  if (index_) index_->cloud.points = &points_;
}
KdTree3& KdTree3::operator=(KdTree3&& other) noexcept {
  points_ = std::move(other.points_);
  index_ = std::move(other.index_);
  if (index_) index_->cloud.points = &points_;
  return *this;
}

void KdTree3::build(const std::vector<Eigen::Vector3f>& points) {
  if (points.size() > static_cast<size_t>(std::numeric_limits<int32_t>::max())) {
    throw std::invalid_argument("KdTree3: too many points");
  }
  index_.reset();
  points_ = points;
  if (!points_.empty()) index_ = std::make_unique<Index>(&points_);
}

int KdTree3::nearest(const Eigen::Vector3f& query, float* squared_distance) const {
  // Two slots for k = 1: GCC cannot see that the insertion never shifts then
  // (-Warray-bounds).
  int best[2] = {-1, -1};
  float best_d2[2] = {std::numeric_limits<float>::infinity(),
                      std::numeric_limits<float>::infinity()};
  if (index_) {
    ExactKnn result(points_, query, 1, best, best_d2);
    index_->tree.findNeighbors(result, query.data(), nanoflann::SearchParams());
  }
  if (squared_distance) *squared_distance = best_d2[0];
  return best[0];
}

void KdTree3::knn(const Eigen::Vector3f& query, int k, std::vector<int>* indices,
                  std::vector<float>* squared_distances) const {
  k = std::min<int>(k, static_cast<int>(points_.size()));
  if (k <= 0) {
    indices->clear();
    if (squared_distances) squared_distances->clear();
    return;
  }
  indices->resize(static_cast<size_t>(k));
  // Without a distance output (normal estimation) small k needs no heap.
  constexpr int kStack = 64;
  float stack[kStack];
  std::vector<float> heap;
  float* d2 = stack;
  if (squared_distances) {
    squared_distances->resize(static_cast<size_t>(k));
    d2 = squared_distances->data();
  } else if (k > kStack) {
    heap.resize(static_cast<size_t>(k));
    d2 = heap.data();
  }
  ExactKnn result(points_, query, k, indices->data(), d2);
  index_->tree.findNeighbors(result, query.data(), nanoflann::SearchParams());
}

}  // namespace long3r

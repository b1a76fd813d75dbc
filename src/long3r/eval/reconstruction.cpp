#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <unordered_map>

#include "long3r/eval/eval.hpp"
#include "long3r/eval/kdtree3.hpp"
#include "long3r/eval/nearest_carry.hpp"
#include "long3r/eval/parallel.hpp"
#include "long3r/geometry/statistics.hpp"

namespace long3r {

using detail::NearestCarry;
using detail::parallel_for;

ErrorStatistics error_statistics(const std::vector<double>& e) {
  ErrorStatistics s;
  s.count = e.size();
  if (e.empty()) return s;
  double sum = 0, sq = 0;
  s.min = std::numeric_limits<double>::infinity();
  s.max = -std::numeric_limits<double>::infinity();
  for (double x : e) {
    sum += x;
    sq += x * x;
    s.min = std::min(s.min, x);
    s.max = std::max(s.max, x);
  }
  const double n = static_cast<double>(e.size());
  s.mean = sum / n;
  s.sse = sq;
  s.rmse = std::sqrt(sq / n);
  double var = 0;
  for (double x : e) var += (x - s.mean) * (x - s.mean);
  s.std = std::sqrt(var / n);
  s.median = median(e);
  return s;
}

namespace {

double median_f(const std::vector<float>& v) {
  return median(std::vector<double>(v.begin(), v.end()));
}
double mean_f(const std::vector<float>& v) {
  if (v.empty()) return 0.0;
  double s = 0;
  for (float x : v) s += x;
  return s / static_cast<double>(v.size());
}

std::vector<Eigen::Vector3f> transformed(const std::vector<Eigen::Vector3f>& pts, const Sim3& s) {
  const Eigen::Matrix3f sr = (s.scale * s.rotation).cast<float>();
  const Eigen::Vector3f t = s.translation.cast<float>();
  std::vector<Eigen::Vector3f> out(pts.size());
  for (size_t i = 0; i < pts.size(); ++i) out[i] = sr * pts[i] + t;
  return out;
}

}  // namespace

std::vector<Eigen::Vector3f> voxel_downsample(const std::vector<Eigen::Vector3f>& points,
                                              double voxel) {
  if (!(voxel > 0.0)) return points;
  struct Acc {
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    int n = 0;
  };
  struct KeyHash {
    size_t operator()(const Eigen::Vector3i& k) const {
      return (static_cast<size_t>(k.x()) * 73856093u) ^ (static_cast<size_t>(k.y()) * 19349663u) ^
             (static_cast<size_t>(k.z()) * 83492791u);
    }
  };
  struct KeyEq {
    bool operator()(const Eigen::Vector3i& a, const Eigen::Vector3i& b) const { return a == b; }
  };
  std::unordered_map<Eigen::Vector3i, size_t, KeyHash, KeyEq> index;
  std::vector<Acc> acc;
  for (const auto& p : points) {
    if (!p.allFinite()) continue;
    const Eigen::Vector3i key((p.cast<double>() / voxel).array().floor().cast<int>());
    auto [it, inserted] = index.emplace(key, acc.size());
    if (inserted) acc.emplace_back();
    acc[it->second].sum += p.cast<double>();
    acc[it->second].n += 1;
  }
  std::vector<Eigen::Vector3f> out;
  out.reserve(acc.size());
  for (const auto& a : acc) out.push_back((a.sum / a.n).cast<float>());
  return out;
}

std::vector<Eigen::Vector3f> backproject_depth(const cv::Mat& depth, const PinholeIntrinsics& k,
                                               const Eigen::Isometry3d& T_W_C, int pixel_step,
                                               double min_depth, double max_depth) {
  if (depth.type() != CV_32FC1) throw std::invalid_argument("backproject_depth: need CV_32FC1");
  if (!k.valid()) throw std::invalid_argument("backproject_depth: invalid intrinsics");
  pixel_step = std::max(1, pixel_step);
  std::vector<Eigen::Vector3f> out;
  for (int v = 0; v < depth.rows; v += pixel_step) {
    const float* row = depth.ptr<float>(v);
    for (int u = 0; u < depth.cols; u += pixel_step) {
      const double z = row[u];
      if (!(z > min_depth && z <= max_depth)) continue;
      out.push_back((T_W_C * k.backproject(u, v, z)).cast<float>());
    }
  }
  return out;
}

std::vector<Eigen::Vector3f> ground_truth_cloud(const TumDataset& ds, const PinholeIntrinsics& k,
                                                const GroundTruthCloudOptions& o) {
  std::vector<Eigen::Vector3f> out;
  int usable = 0;
  for (size_t i = 0; i < ds.size(); ++i) {
    const TumFrame& f = ds.frame(i);
    if (f.depth_path.empty() || !f.pose) continue;
    if (usable++ % std::max(1, o.frame_step) != 0) continue;
    const auto pts =
        backproject_depth(ds.load_depth(i), k, *f.pose, o.pixel_step, o.min_depth, o.max_depth);
    out.insert(out.end(), pts.begin(), pts.end());
  }
  if (usable == 0) throw std::runtime_error("ground_truth_cloud: no frame has depth and a pose");
  return out;
}

std::vector<Eigen::Vector3f> estimate_normals(const std::vector<Eigen::Vector3f>& points, int k,
                                              int threads) {
  std::vector<Eigen::Vector3f> normals(points.size(), Eigen::Vector3f::Zero());
  if (points.empty()) return normals;
  const KdTree3 tree(points);
  parallel_for(points.size(), threads, [&](size_t b, size_t e) {
    std::vector<int> idx;
    for (size_t i = b; i < e; ++i) {
      tree.knn(points[i], k, &idx, nullptr);
      if (idx.size() < 3) continue;
      Eigen::Vector3d mean = Eigen::Vector3d::Zero();
      for (int j : idx) mean += points[j].cast<double>();
      mean /= static_cast<double>(idx.size());
      Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
      for (int j : idx) {
        const Eigen::Vector3d d = points[j].cast<double>() - mean;
        cov += d * d.transpose();
      }
      Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(cov);
      normals[i] = es.eigenvectors().col(0).normalized().cast<float>();  // smallest eigenvalue
    }
  });
  return normals;
}

IcpResult icp_point_to_point(const std::vector<Eigen::Vector3f>& source,
                             const std::vector<Eigen::Vector3f>& target, const Sim3& initial,
                             const IcpOptions& o) {
  if (source.empty() || target.empty()) throw std::invalid_argument("icp: empty cloud");
  const KdTree3 tree(target);
  const float max_d2 =
      static_cast<float>(o.max_correspondence_distance * o.max_correspondence_distance);
  IcpResult r;
  r.transform = initial;
  std::vector<int> match(source.size());
  std::vector<float> d2(source.size());
  std::vector<NearestCarry> carry(source.size());

  // Correspondences of the current transform: fitness and inlier RMSE as Open3D.
  auto evaluate = [&](const Sim3& s, double* fitness, double* rmse) {
    const auto moved = transformed(source, s);
    parallel_for(moved.size(), o.threads, [&](size_t b, size_t e) {
      std::vector<int> idx;
      std::vector<float> dd;
      for (size_t i = b; i < e; ++i) {
        const int j = carry[i].nearest(tree, moved[i], &d2[i], &idx, &dd);
        match[i] = d2[i] <= max_d2 ? j : -1;
      }
    });
    size_t n = 0;
    double sq = 0;
    for (size_t i = 0; i < moved.size(); ++i) {
      if (match[i] < 0) continue;
      ++n;
      sq += d2[i];
    }
    *fitness = static_cast<double>(n) / static_cast<double>(source.size());
    *rmse = n ? std::sqrt(sq / static_cast<double>(n)) : 0.0;
    return n;
  };

  size_t n = evaluate(r.transform, &r.fitness, &r.inlier_rmse);
  for (int it = 0; it < o.max_iterations; ++it) {
    if (n < 3) break;
    Eigen::Matrix3Xd src(3, n), dst(3, n);
    size_t c = 0;
    for (size_t i = 0; i < source.size(); ++i) {
      if (match[i] < 0) continue;
      src.col(c) = source[i].cast<double>();
      dst.col(c) = target[match[i]].cast<double>();
      ++c;
    }
    Sim3 next;
    try {
      // Solve source -> target directly (not as an increment) so the scale
      // stays fixed at the initial one in rigid mode.
      if (o.estimate_scale) {
        next = umeyama_alignment(src, dst, true);
      } else {
        const Eigen::Matrix3Xd scaled = r.transform.scale * src;
        next = umeyama_alignment(scaled, dst, false);
        next.scale = r.transform.scale;
      }
    } catch (const std::invalid_argument&) {
      break;  // degenerate correspondences: keep the last transform
    }
    double fitness, rmse;
    const size_t n_next = evaluate(next, &fitness, &rmse);
    r.iterations = it + 1;
    const bool small = std::abs(fitness - r.fitness) < o.relative_fitness &&
                       std::abs(rmse - r.inlier_rmse) < o.relative_rmse;
    r.transform = next;
    r.fitness = fitness;
    r.inlier_rmse = rmse;
    n = n_next;
    if (small) break;
  }
  return r;
}

ReconstructionMetrics reconstruction_metrics(const std::vector<Eigen::Vector3f>& pred,
                                             const std::vector<Eigen::Vector3f>& gt,
                                             const ReconstructionMetricsOptions& o) {
  if (pred.empty() || gt.empty())
    throw std::invalid_argument("reconstruction_metrics: empty cloud");
  ReconstructionMetrics m;
  m.num_pred = pred.size();
  m.num_gt = gt.size();
  const KdTree3 gt_tree(gt), pred_tree(pred);
  std::vector<float> acc(pred.size()), comp(gt.size());
  std::vector<int> acc_idx(pred.size()), comp_idx(gt.size());
  parallel_for(pred.size(), o.threads, [&](size_t b, size_t e) {
    for (size_t i = b; i < e; ++i) {
      float d2;
      acc_idx[i] = gt_tree.nearest(pred[i], &d2);
      acc[i] = std::sqrt(d2);
    }
  });
  parallel_for(gt.size(), o.threads, [&](size_t b, size_t e) {
    for (size_t i = b; i < e; ++i) {
      float d2;
      comp_idx[i] = pred_tree.nearest(gt[i], &d2);
      comp[i] = std::sqrt(d2);
    }
  });
  m.accuracy_mean = mean_f(acc);
  m.accuracy_median = median_f(acc);
  m.completion_mean = mean_f(comp);
  m.completion_median = median_f(comp);
  size_t within = 0;
  for (float d : comp) within += d < o.completion_ratio_threshold ? 1 : 0;
  m.completion_ratio = static_cast<double>(within) / static_cast<double>(gt.size());

  if (o.normals) {
    const auto n_pred = estimate_normals(pred, o.normal_neighbours, o.threads);
    const auto n_gt = estimate_normals(gt, o.normal_neighbours, o.threads);
    std::vector<float> nc_acc(pred.size()), nc_comp(gt.size());
    for (size_t i = 0; i < pred.size(); ++i) nc_acc[i] = std::abs(n_pred[i].dot(n_gt[acc_idx[i]]));
    for (size_t i = 0; i < gt.size(); ++i) nc_comp[i] = std::abs(n_gt[i].dot(n_pred[comp_idx[i]]));
    m.nc_accuracy_mean = mean_f(nc_acc);
    m.nc_accuracy_median = median_f(nc_acc);
    m.nc_completion_mean = mean_f(nc_comp);
    m.nc_completion_median = median_f(nc_comp);
    m.nc_mean = 0.5 * (m.nc_accuracy_mean + m.nc_completion_mean);
    m.nc_median = 0.5 * (m.nc_accuracy_median + m.nc_completion_median);
  }
  if (o.keep_errors) {
    m.accuracy_errors = std::move(acc);
    m.completion_errors = std::move(comp);
  }
  return m;
}

ReconstructionEvalResult evaluate_reconstruction(const std::vector<Eigen::Vector3f>& pred,
                                                 const std::vector<Eigen::Vector3f>& gt,
                                                 const ReconstructionEvalOptions& o) {
  ReconstructionEvalResult r;
  r.alignment = o.initial;
  if (o.icp) {
    r.icp = icp_point_to_point(pred, gt, o.initial, o.icp_options);
    r.alignment = r.icp->transform;
  }
  r.pred_aligned = transformed(pred, r.alignment);
  r.metrics = reconstruction_metrics(r.pred_aligned, gt, o.metrics);
  return r;
}

}  // namespace long3r

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "long3r/eval/eval.hpp"

namespace long3r {

std::vector<std::pair<int, int>> associate_trajectories(const PoseTrajectory& ref,
                                                        const PoseTrajectory& est, double max_diff,
                                                        double offset) {
  // evo: traj_1 = ref, traj_2 = est; the shorter one drives (est on ties);
  // `offset` shifts est's stamps.
  const bool est_longer = est.stamps.size() > ref.stamps.size();
  const std::vector<double>& short_t = est_longer ? ref.stamps : est.stamps;
  const std::vector<double>& long_t = est_longer ? est.stamps : ref.stamps;
  const double long_offset = est_longer ? offset : -offset;
  std::vector<std::pair<int, int>> out;
  for (size_t i = 0; i < short_t.size(); ++i) {
    int best = -1;
    double best_d = std::numeric_limits<double>::infinity();
    for (size_t j = 0; j < long_t.size(); ++j) {
      const double d = std::abs((long_t[j] + long_offset) - short_t[i]);
      if (d < best_d) {  // first minimum, like np.argmin
        best_d = d;
        best = static_cast<int>(j);
      }
    }
    if (best >= 0 && best_d <= max_diff) {
      if (est_longer) {
        out.emplace_back(static_cast<int>(i), best);
      } else {
        out.emplace_back(best, static_cast<int>(i));
      }
    }
  }
  return out;
}

std::vector<double> ate_translation_errors(const std::vector<Eigen::Isometry3d>& ref,
                                           const std::vector<Eigen::Isometry3d>& est) {
  if (ref.size() != est.size()) throw std::invalid_argument("ate: trajectories differ in size");
  std::vector<double> e(ref.size());
  for (size_t i = 0; i < ref.size(); ++i) {
    e[i] = (est[i].translation() - ref[i].translation()).norm();
  }
  return e;
}

RpeErrors rpe_errors(const std::vector<Eigen::Isometry3d>& ref,
                     const std::vector<Eigen::Isometry3d>& est, int delta, bool all_pairs) {
  if (ref.size() != est.size()) throw std::invalid_argument("rpe: trajectories differ in size");
  if (delta < 1) throw std::invalid_argument("rpe: delta must be >= 1");
  RpeErrors r;
  const int n = static_cast<int>(ref.size());
  if (all_pairs) {
    for (int i = 0; i + delta < n; ++i) r.pairs.emplace_back(i, i + delta);
  } else {
    for (int i = 0; i + delta < n; i += delta) r.pairs.emplace_back(i, i + delta);
  }
  if (r.pairs.empty()) throw std::invalid_argument("rpe: delta produces no pairs");
  for (const auto& [i, j] : r.pairs) {
    const Eigen::Isometry3d q_rel = ref[i].inverse() * ref[j];
    const Eigen::Isometry3d p_rel = est[i].inverse() * est[j];
    const Eigen::Isometry3d e = q_rel.inverse() * p_rel;
    r.translation.push_back(e.translation().norm());
    // Via the quaternion (2 atan2): accurate for small angles, unlike acos.
    r.rotation_deg.push_back(std::abs(Eigen::AngleAxisd(e.rotation()).angle()) * 180.0 / M_PI);
  }
  return r;
}

TrajectoryMetrics evaluate_trajectory(const PoseTrajectory& ref, const PoseTrajectory& est,
                                      const TrajectoryEvalOptions& o) {
  if (ref.stamps.size() != ref.poses.size() || est.stamps.size() != est.poses.size()) {
    throw std::invalid_argument("evaluate_trajectory: stamps and poses differ in size");
  }
  const auto pairs = associate_trajectories(ref, est, o.max_diff, o.offset);
  if (pairs.size() < 3) {
    throw std::invalid_argument("evaluate_trajectory: only " + std::to_string(pairs.size()) +
                                " poses match by timestamp (need 3)");
  }
  TrajectoryMetrics m;
  m.matched = pairs.size();
  std::vector<Eigen::Isometry3d> est_m;
  for (const auto& [i, j] : pairs) {
    m.stamps.push_back(ref.stamps[i]);
    m.ref.push_back(ref.poses[i]);
    est_m.push_back(est.poses[j]);
  }
  if (o.align) {
    Eigen::Matrix3Xd src(3, est_m.size()), dst(3, est_m.size());
    for (size_t k = 0; k < est_m.size(); ++k) {
      src.col(k) = est_m[k].translation();
      dst.col(k) = m.ref[k].translation();
    }
    m.alignment = umeyama_alignment(src, dst, o.correct_scale);
  }
  for (const auto& p : est_m) m.est_aligned.push_back(m.alignment.apply_to_pose(p));
  m.ate_errors = ate_translation_errors(m.ref, m.est_aligned);
  m.ate = error_statistics(m.ate_errors);
  m.rpe = rpe_errors(m.ref, m.est_aligned, o.rpe_delta, o.rpe_all_pairs);
  m.rpe_translation = error_statistics(m.rpe.translation);
  m.rpe_rotation_deg = error_statistics(m.rpe.rotation_deg);
  return m;
}

}  // namespace long3r

// Held-out evaluation of a model or a baseline on generated sequences with
// the paper's metrics: the numbers of docs/model_card.md and of the shipped
// model's regression test.
#include <ATen/ATen.h>
#include <ATen/Parallel.h>

#include <cmath>
#include <limits>
#include <optional>
#include <stdexcept>

#include "long3r/dataset/image_file.hpp"
#include "long3r/eval/eval.hpp"
#include "long3r/geometry/statistics.hpp"
#include "long3r/pipeline/intrinsics.hpp"
#include "long3r/pipeline/pose.hpp"
#include "long3r/train/correspondences.hpp"
#include "long3r/train/cv/train_cv.hpp"

namespace long3r {

namespace {

cv::Mat mat3(const at::Tensor& t) {  // [H, W, 3] float CPU, shares memory
  return cv::Mat(static_cast<int>(t.size(0)), static_cast<int>(t.size(1)), CV_32FC3,
                 t.data_ptr<float>());
}
cv::Mat mat1(const at::Tensor& t) {  // [H, W] float CPU, shares memory
  return cv::Mat(static_cast<int>(t.size(0)), static_cast<int>(t.size(1)), CV_32FC1,
                 t.data_ptr<float>());
}

double nan() { return std::numeric_limits<double>::quiet_NaN(); }

}  // namespace

SequencePrediction true_depth_no_motion_prediction(const SequenceSample& sample) {
  SequencePrediction p;
  for (std::size_t i = 0; i < sample.images.size(); ++i) {
    const at::Tensor gt = sample.pts[static_cast<int64_t>(i)].contiguous();
    const cv::Mat own_mat = points_in_camera(mat3(gt), sample.T_C0_C[i]);
    const at::Tensor own =
        at::from_blob(const_cast<float*>(own_mat.ptr<float>()), gt.sizes(), at::kFloat).clone();
    // Invalid pixels stay at zero, as in the GT.
    const at::Tensor valid = sample.valid[static_cast<int64_t>(i)].unsqueeze(-1);
    p.pts.push_back(at::where(valid, own, at::zeros_like(own)));
    p.conf.push_back(at::ones({own.size(0), own.size(1)}, at::kFloat));
  }
  return p;
}

PredictionMetrics evaluate_prediction(const SequencePrediction& prediction,
                                      const SequenceSample& sample,
                                      const PredictionMetricsOptions& options) {
  const std::size_t n = prediction.pts.size();
  if (n == 0 || n != sample.images.size() || prediction.conf.size() != n) {
    throw std::invalid_argument("evaluate_prediction: prediction and sequence lengths differ");
  }
  if (options.pixel_step < 1) throw std::invalid_argument("evaluate_prediction: pixel_step < 1");
  PredictionMetrics m;
  m.frames = static_cast<int64_t>(n);

  std::vector<Eigen::Vector3f> aligned, gt_pts;
  m.pointmap_error =
      aligned_pointmap_error(prediction, sample, options.pixel_step, &aligned, &gt_pts);
  ReconstructionMetricsOptions ro;
  ro.normals = options.normals;
  ro.keep_errors = !options.picture_path.empty();
  ro.threads = std::max(1, at::get_num_threads());
  const ReconstructionMetrics rm = reconstruction_metrics(aligned, gt_pts, ro);
  if (!options.picture_path.empty()) {
    const cv::Mat img =
        plot_error_top_view(aligned, rm.accuracy_errors, gt_pts, rm.completion_errors,
                            estimate_up_axis(sample.T_C0_C), options.picture_max_error_m);
    write_image_atomically(options.picture_path, img);
  }
  m.acc_mean = rm.accuracy_mean;
  m.acc_median = rm.accuracy_median;
  m.comp_mean = rm.completion_mean;
  m.comp_median = rm.completion_median;
  m.nc_mean = rm.nc_mean;
  m.nc_median = rm.nc_median;

  // Each frame's depth against the truth (its own Sim(3) first).
  std::vector<double> slopes, correlations;
  for (std::size_t i = 0; i < n; ++i) {
    const int64_t f = static_cast<int64_t>(i);
    const std::optional<DepthResponse> d = depth_response(
        prediction.pts[i], sample.pts[f], sample.valid[f], sample.T_C0_C[i], options.pixel_step);
    if (!d) continue;
    slopes.push_back(d->slope);
    correlations.push_back(d->correlation);
  }
  if (!slopes.empty()) {
    m.depth_slope = median(std::move(slopes));
    m.depth_correlation = median(std::move(correlations));
  }

  // Poses as the pipeline estimates them.
  PoseTrajectory ref, est;
  PnpConfig pc;
  pc.conf_threshold = 0.0f;
  pc.ransac = options.pnp_ransac;
  std::optional<PinholeIntrinsics> estimated;
  for (std::size_t i = 0; i < n; ++i) {
    const at::Tensor p = prediction.pts[i].to(at::kFloat).contiguous();
    const at::Tensor c = prediction.conf[i].to(at::kFloat).contiguous();
    if (options.estimate_intrinsics && i == 0) {
      // As the pipeline: no focal from frame 0, no poses at all (never the GT's).
      estimated = estimate_intrinsics(mat3(p), mat1(c));
      if (!estimated) break;
    }
    const PoseResult pr =
        estimate_pose_pnp(mat3(p), mat1(c), estimated ? *estimated : sample.intrinsics[i], pc);
    if (!pr.ok()) continue;
    ref.stamps.push_back(static_cast<double>(i));
    ref.poses.push_back(sample.T_C0_C[i]);
    est.stamps.push_back(static_cast<double>(i));
    est.poses.push_back(pr.T_W_C);
  }
  m.posed = static_cast<int64_t>(est.size());
  m.ate_rmse = m.rpe_trans_rmse = m.rpe_rot_rmse_deg = nan();
  if (est.size() < 3) return m;
  Eigen::Vector3d mean_est = Eigen::Vector3d::Zero(), mean_ref = Eigen::Vector3d::Zero();
  for (std::size_t i = 0; i < est.size(); ++i) {
    mean_est += est.poses[i].translation();
    mean_ref += ref.poses[i].translation();
  }
  mean_est /= static_cast<double>(est.size());
  mean_ref /= static_cast<double>(ref.size());
  double spread_est = 0.0, spread_ref = 0.0;
  for (std::size_t i = 0; i < est.size(); ++i) {
    spread_est += (est.poses[i].translation() - mean_est).squaredNorm();
    spread_ref += (ref.poses[i].translation() - mean_ref).squaredNorm();
  }
  if (spread_est <= 1e-12 * std::max(1.0, spread_ref)) {
    // No motion at all: see the header.
    m.ate_rmse = std::sqrt(spread_ref / static_cast<double>(ref.size()));
    TrajectoryEvalOptions to;
    to.align = false;
    const TrajectoryMetrics tm = evaluate_trajectory(ref, est, to);
    m.rpe_trans_rmse = tm.rpe_translation.rmse;
    m.rpe_rot_rmse_deg = tm.rpe_rotation_deg.rmse;
    return m;
  }
  try {
    const TrajectoryMetrics tm = evaluate_trajectory(ref, est);
    m.ate_rmse = tm.ate.rmse;
    m.rpe_trans_rmse = tm.rpe_translation.rmse;
    m.rpe_rot_rmse_deg = tm.rpe_rotation_deg.rmse;
  } catch (const std::invalid_argument&) {
    // Degenerate (e.g. collinear) estimate: no trajectory numbers.
  }
  return m;
}

PredictionMetrics full_validation_scorer(const SequencePrediction& prediction,
                                         const SequenceSample& sample,
                                         const ValidationConfig& config) {
  PredictionMetricsOptions po;
  po.pixel_step = config.pixel_step;
  po.normals = config.normals;
  return evaluate_prediction(prediction, sample, po);
}

}  // namespace long3r

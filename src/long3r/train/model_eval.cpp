// Held-out evaluation of a model or a baseline on generated sequences: the
// numbers of docs/model_card.md and of the shipped model's regression test.
#include <ATen/ATen.h>
#include <ATen/Parallel.h>
#include <c10/core/InferenceMode.h>

#include <chrono>
#include <cmath>
#include <limits>
#include <optional>
#include <stdexcept>

#include "long3r/dataset/image_file.hpp"
#include "long3r/eval/eval.hpp"
#include "long3r/pipeline/intrinsics.hpp"
#include "long3r/pipeline/pose.hpp"
#include "long3r/train/train.hpp"

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

// Appends the (prediction, GT) points of the valid pixels of one frame
// ([H, W, 3] pointmaps, [H, W] mask), every `step`-th row and column.
// Pixels whose prediction is not finite are left out; returns their count.
int64_t append_correspondences(const at::Tensor& pred, const at::Tensor& gt,
                               const at::Tensor& valid, int step,
                               std::vector<Eigen::Vector3f>* pred_pts,
                               std::vector<Eigen::Vector3f>* gt_pts) {
  const at::Tensor p = pred.to(at::kFloat).contiguous();
  const at::Tensor g = gt.to(at::kFloat).contiguous();
  const at::Tensor v = valid.contiguous();
  const int64_t H = p.size(0), W = p.size(1);
  const float* pp = p.data_ptr<float>();
  const float* gp = g.data_ptr<float>();
  const bool* vp = v.data_ptr<bool>();
  int64_t non_finite = 0;
  for (int64_t y = 0; y < H; y += step) {
    for (int64_t x = 0; x < W; x += step) {
      const int64_t k = y * W + x;
      if (!vp[k]) continue;
      const Eigen::Vector3f q(pp[3 * k], pp[3 * k + 1], pp[3 * k + 2]);
      if (!q.allFinite()) {
        ++non_finite;
        continue;
      }
      pred_pts->push_back(q);
      gt_pts->emplace_back(gp[3 * k], gp[3 * k + 1], gp[3 * k + 2]);
    }
  }
  return non_finite;
}

}  // namespace

SequencePrediction predict_sequence(Long3rModel& model, const SequenceSample& sample) {
  SequencePrediction p;
  const auto t0 = std::chrono::steady_clock::now();
  {
    const TrainingModeGuard inference(model, false);
    c10::InferenceMode guard;
    std::vector<at::Tensor> frames;
    for (const at::Tensor& f : sample.images) frames.push_back(f.unsqueeze(0).to(model.device()));
    const std::vector<StreamOutput> out = model.forward_sequence(frames);
    for (const StreamOutput& o : out) {
      p.pts.push_back(o.pts3d[0].to(at::kCPU, at::kFloat).contiguous());
      p.conf.push_back(o.conf[0].to(at::kCPU, at::kFloat).contiguous());
    }
  }
  p.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return p;
}

SequencePrediction constant_depth_prediction(const SequenceSample& sample, double depth_m) {
  if (!(depth_m > 0.0)) throw std::invalid_argument("constant_depth_prediction: depth must be > 0");
  SequencePrediction p;
  for (std::size_t i = 0; i < sample.images.size(); ++i) {
    const int64_t H = sample.images[i].size(1), W = sample.images[i].size(2);
    const PinholeIntrinsics& k = sample.intrinsics[i];
    const at::Tensor u = at::arange(W, at::kFloat).view({1, W}).expand({H, W});
    const at::Tensor v = at::arange(H, at::kFloat).view({H, 1}).expand({H, W});
    const float z = static_cast<float>(depth_m);
    p.pts.push_back(at::stack({(u - static_cast<float>(k.cx)) * (z / static_cast<float>(k.fx)),
                               (v - static_cast<float>(k.cy)) * (z / static_cast<float>(k.fy)),
                               at::full({H, W}, z)},
                              -1)
                        .contiguous());
    p.conf.push_back(at::ones({H, W}, at::kFloat));
  }
  return p;
}

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

SequencePrediction first_frame_prediction(const SequenceSample& sample) {
  SequencePrediction p;
  for (std::size_t i = 0; i < sample.images.size(); ++i) {
    p.pts.push_back(sample.pts[0].clone());
    p.conf.push_back(at::ones({sample.pts.size(1), sample.pts.size(2)}, at::kFloat));
  }
  return p;
}

LossProbe probe_loss(const SequencePrediction& prediction, const SequenceSample& sample) {
  const std::size_t n = prediction.pts.size();
  if (n < 2 || n != sample.images.size()) {
    throw std::invalid_argument("probe_loss: need a prediction of N >= 2 frames for the sequence");
  }
  std::vector<StreamOutput> outputs(n);
  for (std::size_t i = 0; i < n; ++i) {
    outputs[i].frame_index = static_cast<int64_t>(i);
    outputs[i].pts3d = prediction.pts[i].to(at::kFloat).unsqueeze(0);
  }
  LossConfig lc;
  lc.coarse = false;
  LossProbe r;
  r.regression =
      sequence_loss(outputs, {}, sample.pts.unsqueeze(0), sample.valid.unsqueeze(0), lc).regression;

  // Normalised like the loss: each cloud by its own average distance over the sequence.
  const at::Tensor pred = at::stack(prediction.pts, 0).to(at::kFloat).unsqueeze(0);
  const at::Tensor valid = sample.valid.unsqueeze(0);
  const at::Tensor pred_n = (pred / average_distance(pred, valid).item<double>())[0];
  const at::Tensor gt_n =
      sample.pts / average_distance(sample.pts.unsqueeze(0), valid).item<double>();
  double sum = 0.0;
  for (std::size_t i = 0; i < n; ++i) {
    const int64_t f = static_cast<int64_t>(i);
    std::vector<Eigen::Vector3f> src, dst;
    if (append_correspondences(pred_n[f], gt_n[f], sample.valid[f], 1, &src, &dst) > 0) {
      return {r.regression, nan()};  // so is the loss then
    }
    if (src.size() < 3) continue;  // as the loss: a frame without valid pixels adds 0
    Sim3 T;
    try {
      T = align_correspondences(src, dst, true);
    } catch (const std::invalid_argument&) {
      // A collapsed frame (all points on a line) has no best placement.
      return {r.regression, nan()};
    }
    double err = 0.0;
    for (std::size_t k = 0; k < src.size(); ++k) {
      err += (T * src[k].cast<double>() - dst[k].cast<double>()).norm();
    }
    sum += err / static_cast<double>(src.size());
  }
  r.registered = sum / static_cast<double>(n);
  return r;
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

  // Corresponding valid pixels: one Sim(3) for the whole sequence.
  std::vector<Eigen::Vector3f> pred_pts, gt_pts;
  for (std::size_t i = 0; i < n; ++i) {
    const int64_t f = static_cast<int64_t>(i);
    if (prediction.pts[i].sizes() != sample.pts[f].sizes()) {
      throw std::invalid_argument("evaluate_prediction: pointmap sizes");
    }
    append_correspondences(prediction.pts[i], sample.pts[f], sample.valid[f], options.pixel_step,
                           &pred_pts, &gt_pts);
  }
  if (pred_pts.size() < 3) throw std::runtime_error("evaluate_prediction: too few valid points");
  const Sim3 align = align_correspondences(pred_pts, gt_pts, true);
  std::vector<Eigen::Vector3f> aligned(pred_pts.size());
  double err = 0.0;
  for (std::size_t i = 0; i < pred_pts.size(); ++i) {
    aligned[i] = (align * pred_pts[i].cast<double>()).cast<float>();
    err += (aligned[i] - gt_pts[i]).norm();
  }
  m.pointmap_error = err / static_cast<double>(pred_pts.size());
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

  // Poses as the pipeline estimates them.
  PoseTrajectory ref, est;
  PnpConfig pc;
  pc.conf_threshold = 0.0f;
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

}  // namespace long3r

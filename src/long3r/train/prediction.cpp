// Predictions of a model or of a baseline for a sequence, and the figures
// that need nothing but libtorch and Eigen: the loss probe and the pointmap
// error of validation.
#include <ATen/ATen.h>
#include <c10/core/InferenceMode.h>

#include <chrono>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "long3r/geometry/umeyama.hpp"
#include "long3r/train/correspondences.hpp"
#include "long3r/train/prediction.hpp"
#include "long3r/train/train_config.hpp"
#include "long3r/train/train_data.hpp"
#include "long3r/train/train_loss.hpp"

namespace long3r {

namespace {

double nan() { return std::numeric_limits<double>::quiet_NaN(); }

}  // namespace

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

double aligned_pointmap_error(const SequencePrediction& prediction, const SequenceSample& sample,
                              int step, std::vector<Eigen::Vector3f>* aligned,
                              std::vector<Eigen::Vector3f>* gt_pts) {
  std::vector<Eigen::Vector3f> pred, gt;
  for (std::size_t i = 0; i < prediction.pts.size(); ++i) {
    const int64_t f = static_cast<int64_t>(i);
    if (prediction.pts[i].sizes() != sample.pts[f].sizes()) {
      throw std::invalid_argument("pointmap sizes of the prediction and the sequence differ");
    }
    append_correspondences(prediction.pts[i], sample.pts[f], sample.valid[f], step, &pred, &gt);
  }
  if (pred.size() < 3) throw std::runtime_error("too few valid points to align the prediction");
  const Sim3 align = align_correspondences(pred, gt, true);
  double err = 0.0;
  for (std::size_t i = 0; i < pred.size(); ++i) {
    pred[i] = (align * pred[i].cast<double>()).cast<float>();
    err += (pred[i] - gt[i]).norm();
  }
  const double mean = err / static_cast<double>(pred.size());
  if (aligned != nullptr) *aligned = std::move(pred);
  if (gt_pts != nullptr) *gt_pts = std::move(gt);
  return mean;
}

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

std::optional<DepthResponse> depth_response(const at::Tensor& pred, const at::Tensor& gt,
                                            const at::Tensor& valid,
                                            const Eigen::Isometry3d& T_C0_C, int pixel_step) {
  constexpr std::size_t kMinPixels = 16;
  constexpr double kMinLogSpread = 0.01;
  std::vector<Eigen::Vector3f> src, dst;
  if (append_correspondences(pred.to(at::kFloat).contiguous(), gt.to(at::kFloat).contiguous(),
                             valid, pixel_step, &src, &dst) > 0 ||
      src.size() < kMinPixels) {
    return std::nullopt;
  }
  Sim3 S;
  try {
    S = align_correspondences(src, dst, true);
  } catch (const std::invalid_argument&) {
    return std::nullopt;  // collapsed onto a line
  }
  const Eigen::Isometry3d T_C_C0 = T_C0_C.inverse();
  std::vector<double> x, y;  // log true depth, log predicted depth
  for (std::size_t k = 0; k < src.size(); ++k) {
    const double z_pred = (T_C_C0 * (S * src[k].cast<double>())).z();
    const double z_true = (T_C_C0 * dst[k].cast<double>()).z();
    if (!(z_pred > 0.0) || !(z_true > 0.0)) continue;
    x.push_back(std::log(z_true));
    y.push_back(std::log(z_pred));
  }
  if (x.size() < kMinPixels) return std::nullopt;
  const double n = static_cast<double>(x.size());
  double mx = 0.0, my = 0.0;
  for (std::size_t k = 0; k < x.size(); ++k) {
    mx += x[k];
    my += y[k];
  }
  mx /= n;
  my /= n;
  double sxx = 0.0, syy = 0.0, sxy = 0.0;
  for (std::size_t k = 0; k < x.size(); ++k) {
    sxx += (x[k] - mx) * (x[k] - mx);
    syy += (y[k] - my) * (y[k] - my);
    sxy += (x[k] - mx) * (y[k] - my);
  }
  if (std::sqrt(sxx / n) < kMinLogSpread || !(syy > 0.0)) return std::nullopt;
  DepthResponse r;
  r.slope = sxy / sxx;
  r.correlation = sxy / std::sqrt(sxx * syy);
  r.pixels = static_cast<int64_t>(x.size());
  return r;
}

PredictionMetrics pointmap_metrics(const SequencePrediction& prediction,
                                   const SequenceSample& sample, const ValidationConfig& config) {
  const std::size_t n = prediction.pts.size();
  if (n == 0 || n != sample.images.size()) {
    throw std::invalid_argument("pointmap_metrics: prediction and sequence lengths differ");
  }
  if (config.pixel_step < 1) throw std::invalid_argument("pointmap_metrics: pixel_step < 1");
  PredictionMetrics m;
  m.frames = static_cast<int64_t>(n);
  m.acc_mean = m.acc_median = m.comp_mean = m.comp_median = nan();
  m.nc_mean = m.nc_median = nan();
  m.ate_rmse = m.rpe_trans_rmse = m.rpe_rot_rmse_deg = nan();
  m.pointmap_error =
      aligned_pointmap_error(prediction, sample, config.pixel_step, nullptr, nullptr);
  return m;
}

}  // namespace long3r

// Predictions of a model or of a baseline for a sequence, and the figures
// that need nothing but libtorch and Eigen (train/prediction.cpp): the
// pointmap error of validation and the loss probe; the scores of a
// prediction and the scorer type that validation takes.
#pragma once

#include <ATen/core/Tensor.h>

#include <Eigen/Geometry>

#include <cstdint>
#include <functional>
#include <limits>
#include <optional>
#include <vector>

#include "long3r/model/network/long3r_model.hpp"
#include "long3r/train/train_config.hpp"
#include "long3r/train/train_data.hpp"

namespace long3r {

// Scores of one predicted sequence against its ground truth
// (evaluate_prediction below).
struct PredictionMetrics {
  double pointmap_error = 0;  // mean || aligned pred - gt ||, metres
  double acc_mean = 0, acc_median = 0, comp_mean = 0, comp_median = 0;
  double nc_mean = 0, nc_median = 0;
  double ate_rmse = 0;        // m; NaN when fewer than 3 frames were posed
  double rpe_trans_rmse = 0;  // m per frame step (after the Sim(3) of the ATE)
  double rpe_rot_rmse_deg = 0;
  int64_t frames = 0, posed = 0;
  // Medians over the frames of depth_response (NaN where no frame has one;
  // evaluate_prediction only).
  double depth_slope = std::numeric_limits<double>::quiet_NaN();
  double depth_correlation = std::numeric_limits<double>::quiet_NaN();
};

// How a frame's predicted depth follows the true depth. The frame's points
// are first moved onto its true ones by their own Sim(3) (Umeyama on the
// valid pixels every `pixel_step`-th row and column), so that neither its
// placement nor its scale counts; then, in the true camera, the
// least-squares slope of log predicted depth on log true depth and the
// correlation of the two. A slope of 1 keeps the frame's depth ratios; below
// 1 the depth is compressed towards the frame's middle depth (near things
// too far, far things too near), which no scale undoes and which a chain of
// keyframes scaled one against the next turns into scale drift
// (docs/model_card.md, "Poses from keyframes").
struct DepthResponse {
  double slope = 0.0;
  double correlation = 0.0;
  int64_t pixels = 0;  // that entered the fit
};
// nullopt for a frame with any non-finite predicted point at a valid pixel
// (as probe_loss: such a frame has no placement), with fewer than 16 usable
// pixels (valid, in front of both cameras after the alignment), with points
// on a line, or whose true log depth spreads less than 0.01 (a wall seen
// head-on: no slope to fit). pred and gt: [H, W, 3] in camera 0's frame; valid [H, W];
// T_C0_C the frame's true pose.
std::optional<DepthResponse> depth_response(const at::Tensor& pred, const at::Tensor& gt,
                                            const at::Tensor& valid,
                                            const Eigen::Isometry3d& T_C0_C, int pixel_step);

// Switches a model to training or inference for a scope and restores the
// previous mode when the scope ends, also by an exception. Both switches
// reset the model's stream (set_training).
class TrainingModeGuard {
 public:
  TrainingModeGuard(Long3rModel& model, bool training)
      : model_(model), was_training_(model.training()) {
    model_.set_training(training);
  }
  ~TrainingModeGuard() { model_.set_training(was_training_); }
  TrainingModeGuard(const TrainingModeGuard&) = delete;
  TrainingModeGuard& operator=(const TrainingModeGuard&) = delete;

 private:
  Long3rModel& model_;
  bool was_training_;
};

// A model's (or a baseline's) pointmaps for one sequence, CPU float32.
struct SequencePrediction {
  std::vector<at::Tensor> pts;   // N x [H, W, 3], camera-0 frame
  std::vector<at::Tensor> conf;  // N x [H, W]
  double seconds = 0;            // wall time of the prediction
};

// Scores one predicted validation sequence against its ground truth.
using PredictionScorer = std::function<PredictionMetrics(
    const SequencePrediction&, const SequenceSample&, const ValidationConfig&)>;

// What needs no OpenCV: pointmap_error (mean || aligned pred - gt || after
// one Sim(3), Umeyama on the valid pixels every config.pixel_step-th row and
// column); the point-cloud and trajectory figures NaN. frames = N, posed = 0.
PredictionMetrics pointmap_metrics(const SequencePrediction& prediction,
                                   const SequenceSample& sample, const ValidationConfig& config);

// Streams the sequence through `model` in inference mode (one push per
// frame, the last frame from flush(), as the pipeline does).
SequencePrediction predict_sequence(Long3rModel& model, const SequenceSample& sample);

// The constant-depth baseline: every pixel of every frame at depth `depth_m`
// in its own camera, all cameras at camera 0 (no motion), confidence 1.
SequencePrediction constant_depth_prediction(const SequenceSample& sample, double depth_m);

// Oracle of the loss probe (docs/model_card.md, "Why the model does not
// register"), from the ground truth, confidence 1: frame 0's exact pointmap
// for every frame (ignores the images after the first). The other oracle,
// true_depth_no_motion_prediction, is in cv/train_cv.hpp.
SequencePrediction first_frame_prediction(const SequenceSample& sample);

// What a prediction costs in the training loss, and how much of that is
// registration: `regression` is sequence_loss's mean || x_hat / z_hat - x / z ||
// over the N outputs (coarse supervision off, no confidence); `registered` is
// the same after each frame's normalised prediction is moved by its own best
// similarity transform (Umeyama Sim(3) on the valid pixels: pose and scale)
// onto the normalised GT, so what remains is shape error; regression -
// registered is the share that placing every frame correctly in camera 0's
// frame (registration, and a scale consistent over the sequence) would remove.
// `registered` is NaN when a frame cannot be placed: non-finite predicted
// points, or a frame collapsed onto a line.
struct LossProbe {
  double regression = 0;
  double registered = 0;
};
LossProbe probe_loss(const SequencePrediction& prediction, const SequenceSample& sample);

}  // namespace long3r

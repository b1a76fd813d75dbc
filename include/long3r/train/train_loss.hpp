// The training loss (paper 3.5), initialisation from DUSt3R-family
// checkpoints, and validation (train/train_loss.cpp).
#pragma once

#include <ATen/core/Tensor.h>

#include <cstdint>
#include <functional>
#include <string>
#include <utility>
#include <vector>

#include "long3r/model/network/long3r_model.hpp"
#include "long3r/model/network/streaming.hpp"
#include "long3r/train/blind_control.hpp"
#include "long3r/train/cross_view_completion.hpp"
#include "long3r/train/prediction.hpp"
#include "long3r/train/train_config.hpp"
#include "long3r/train/train_data.hpp"

namespace long3r {

// ====================================================================== loss

// Loss of one sequence batch, all in float32:
//   L = L_conf + scale_weight * L_scale                      (paper Eq. 9)
// L_conf (DUSt3R / Spann3R): for every supervised pointmap (the N refined /
// final outputs except the last, and the N-1 coarse next-frame pointmaps, or
// just the N outputs when coarse supervision is off) the mean over valid
// pixels of  conf * || x_hat / z_hat - x / z || - alpha * log(conf),  averaged
// over the pointmaps; z_hat (z) is the average distance to the origin of the
// prediction's (GT's) valid points over the whole sequence (the N outputs),
// per batch item, camera-0 frame.
// L_scale: the paper states it only in words ("encourages the predicted point
// cloud to have an average distance smaller than that of the ground truth");
// this is Spann3R's form, which the paper follows: the mean of z_hat - z over
// the batch items whose z_hat > z (0 when there are none).
struct LossTerms {
  at::Tensor total;                     // scalar, differentiable
  at::Tensor conf_loss;                 // L_conf
  at::Tensor scale_loss;                // L_scale
  double regression = 0;                // mean || x_hat / z_hat - x / z || (no confidence)
  double pred_scale = 0, gt_scale = 0;  // mean z_hat, z over the batch
};

// Average distance to the origin of the valid points of [B, N, H, W, 3]
// pointmaps, per batch item: [B].
at::Tensor average_distance(const at::Tensor& pts, const at::Tensor& valid);

// One pointmap's confidence-weighted term: pred_n, gt_n [B, H, W, 3] (already
// normalised), conf [B, H, W], valid [B, H, W]. Returns (mean of
// conf * err - alpha * log conf, mean err) over valid pixels; `count`, when
// given, is the number the sums are divided by instead of valid's count.
std::pair<at::Tensor, at::Tensor> confidence_regression(const at::Tensor& pred_n,
                                                        const at::Tensor& gt_n,
                                                        const at::Tensor& conf,
                                                        const at::Tensor& valid, double alpha,
                                                        const at::Tensor& count = {});

// The ranks that each hold a shard of one batch (data-parallel training),
// for the loss's normalisers: a rank's loss is then its part of the whole
// batch's loss (its sums over the whole batch's valid-pixel and item counts)
// times the number of ranks, so that the ranks' mean loss is the whole
// batch's and averaging their gradients gives the whole batch's gradient,
// however the valid pixels fall between the shards.
struct BatchShards {
  int64_t ranks = 1;
  std::function<void(const at::Tensor&)> sum;  // sums a CPU tensor over the ranks, in place
};

// outputs: N model outputs (forward_sequence); coarse: N-1 next-frame
// predictions (may be empty when config.coarse is false); gt_pts
// [B, N, H, W, 3] and gt_valid [B, N, H, W] on the outputs' device.
LossTerms sequence_loss(const std::vector<StreamOutput>& outputs,
                        const std::vector<StreamOutput>& coarse, const at::Tensor& gt_pts,
                        const at::Tensor& gt_valid, const LossConfig& config,
                        const BatchShards* shards = nullptr);

// ============================================================ initialisation

struct InitReport {
  int64_t loaded = 0;          // model tensors copied from the file
  int64_t shape_mismatch = 0;  // same name, different shape: kept fresh
  int64_t unused = 0;          // file tensors with no counterpart in the model
  int64_t fresh = 0;           // model tensors not in the file (new modules)
  std::vector<std::string> mismatched_names;
};
// Copies every tensor of a DUSt3R (names without prefix), Spann3R or LONG3R
// checkpoint whose name (as is, or with "dust3r." prepended) and shape match a
// parameter or buffer of the model; the rest of the model keeps its values.
InitReport init_from_checkpoint(Long3rModel& model, const std::string& path);

// True for the encoder's parameters (dust3r.patch_embed, dust3r.enc_blocks,
// dust3r.enc_norm), which stage 2 freezes.
bool is_encoder_parameter(const std::string& name);

// ================================================================ validation

struct ValidationMetrics {
  double loss = 0, regression = 0;  // sequence_loss over the sequences, averaged
  // probe_loss's `registered` (shape error left once every frame is placed
  // by its own Sim(3)), averaged: regression - registered is what
  // registration costs.
  double registered = 0;
  // evaluate_prediction's figures averaged over the sequences; ate_rmse, the
  // RPE and the depth response over those where they are finite (NaN when
  // there is none);
  // frames and posed are totals.
  PredictionMetrics prediction;
  int64_t sequences = 0;
  // The blind control over validation.blind_* at the first of its strides
  // (NaN figures when not run), and at each of them, in order (the trainer
  // writes these to blind_control.csv).
  BlindControl blind;
  std::vector<std::pair<int64_t, BlindControl>> blind_per_stride;
  // In a cross_view_completion stage, its control on the same pairs.
  CompletionControl completion;
};

// Inference-mode run of `model` (switched to inference and back) over the
// sequences: the loss, probe_loss's registered share, and `score`'s figures
// (pointmap_metrics when empty; cv/train_cv.hpp's full_validation_scorer adds
// Acc / Comp / NC and the ATE of PnP poses). Averages over sequences.
ValidationMetrics validate(Long3rModel& model, const std::vector<SequenceSample>& sequences,
                           const LossConfig& loss, const ValidationConfig& config,
                           const PredictionScorer& score = {});

}  // namespace long3r

// The training loss (paper 3.5), initialisation from DUSt3R-family
// checkpoints, and validation.
#include <ATen/ATen.h>
#include <ATen/Parallel.h>
#include <torch/nn/module.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "long3r/model/loading/safetensors.hpp"
#include "long3r/train/prediction.hpp"
#include "long3r/train/train_config.hpp"
#include "long3r/train/train_data.hpp"
#include "long3r/train/train_loss.hpp"

namespace long3r {

at::Tensor average_distance(const at::Tensor& pts, const at::Tensor& valid) {
  const int64_t B = pts.size(0);
  const at::Tensor m = valid.to(pts.scalar_type());
  const at::Tensor dist = at::linalg_vector_norm(pts, 2, {-1}) * m;
  const at::Tensor count = m.reshape({B, -1}).sum(1).clamp_min(1.0);
  // Clipped like DUSt3R's get_norm_factor so that an empty or degenerate
  // prediction does not divide by zero.
  return (dist.reshape({B, -1}).sum(1) / count).clamp_min(1e-8);
}

std::pair<at::Tensor, at::Tensor> confidence_regression(const at::Tensor& pred_n,
                                                        const at::Tensor& gt_n,
                                                        const at::Tensor& conf,
                                                        const at::Tensor& valid, double alpha,
                                                        const at::Tensor& given_count) {
  const at::Tensor m = valid.to(pred_n.scalar_type());
  const at::Tensor count = given_count.defined() ? given_count : m.sum().clamp_min(1.0);
  const at::Tensor err = at::linalg_vector_norm(pred_n - gt_n, 2, {-1});
  // Masking after the fact keeps invalid pixels out of values and gradients.
  const at::Tensor term = (conf * err - alpha * at::log(conf)) * m;
  return {term.sum() / count, (err * m).sum() / count};
}

LossTerms sequence_loss(const std::vector<StreamOutput>& outputs,
                        const std::vector<StreamOutput>& coarse, const at::Tensor& gt_pts,
                        const at::Tensor& gt_valid, const LossConfig& config,
                        const BatchShards* shards) {
  const int64_t N = static_cast<int64_t>(outputs.size());
  if (N < 2 || gt_pts.dim() != 5 || gt_pts.size(1) != N || gt_valid.size(1) != N) {
    throw std::invalid_argument("sequence_loss: need N >= 2 outputs and [B, N, H, W, 3] targets");
  }
  if (config.coarse && static_cast<int64_t>(coarse.size()) != N - 1) {
    throw std::invalid_argument("sequence_loss: coarse supervision needs N - 1 coarse outputs");
  }
  const int64_t B = gt_pts.size(0);
  std::vector<at::Tensor> pred_list;
  for (const StreamOutput& o : outputs) pred_list.push_back(o.pts3d.to(at::kFloat));
  const at::Tensor pred = at::stack(pred_list, 1);  // [B, N, H, W, 3]
  const at::Tensor gt = gt_pts.to(at::kFloat);
  // Normalisation factors over the whole sequence, each cloud by its own.
  const at::Tensor pred_scale = average_distance(pred, gt_valid);
  const at::Tensor gt_scale = average_distance(gt, gt_valid);
  const at::Tensor pf = pred_scale.view({B, 1, 1, 1});
  const at::Tensor gf = gt_scale.view({B, 1, 1, 1});

  // The supervised pointmaps: (output, frame). As Spann3R with coarse
  // supervision: head 1 for frames 0..N-2, head 2 (next-frame prediction from
  // the previous step) for frames 1..N-1; output N-1 is coarse[N-2].
  std::vector<std::pair<const StreamOutput*, int64_t>> supervised;
  for (int64_t i = 0; i < (config.coarse ? N - 1 : N); ++i) {
    supervised.emplace_back(&outputs[static_cast<std::size_t>(i)], i);
  }
  if (config.coarse) {
    for (int64_t j = 0; j + 1 < N; ++j)
      supervised.emplace_back(&coarse[static_cast<std::size_t>(j)], j + 1);
  }
  // Spann3R's factor loss: only the items whose predicted scale exceeds the
  // GT's are penalised, by the excess, averaged over those items.
  const at::Tensor over = (pred_scale > gt_scale).detach();
  // The normalisers: valid pixels per pointmap and items over scale. For a
  // shard of a batch (BatchShards), the whole batch's, summed over the ranks
  // and divided by their number.
  std::vector<at::Tensor> local;
  for (const auto& [o, frame] : supervised) local.push_back(gt_valid.select(1, frame).sum());
  local.push_back(over.sum());
  const at::Tensor total = at::stack(local).to(at::kCPU, at::kDouble);
  if (shards != nullptr) shards->sum(total);
  const double ranks = shards != nullptr ? static_cast<double>(shards->ranks) : 1.0;
  const at::Tensor counts = (total.clamp_min(1.0) / ranks).to(pred.device(), at::kFloat);
  std::vector<at::Tensor> terms, errs;
  for (std::size_t k = 0; k < supervised.size(); ++k) {
    const auto& [o, frame] = supervised[k];
    const at::Tensor gt_n = gt.select(1, frame) / gf;
    const at::Tensor pred_n = o->pts3d.to(at::kFloat) / pf;
    at::Tensor conf =
        o->conf.defined() ? o->conf.to(at::kFloat) : at::ones_like(pred_n.select(-1, 0));
    auto [t, e] = confidence_regression(pred_n, gt_n, conf, gt_valid.select(1, frame), config.alpha,
                                        counts[static_cast<int64_t>(k)]);
    terms.push_back(t);
    errs.push_back(e);
  }
  LossTerms r;
  r.conf_loss = at::stack(terms).mean();
  // The mean over the items over scale (0 when there are none).
  r.scale_loss = (pred_scale - gt_scale).masked_select(over).sum() / counts[-1];
  r.total = r.conf_loss + config.scale_weight * r.scale_loss;
  r.regression = at::stack(errs).mean().item<double>();
  r.pred_scale = pred_scale.mean().item<double>();
  r.gt_scale = gt_scale.mean().item<double>();
  return r;
}

bool is_encoder_parameter(const std::string& name) {
  for (const char* p : {"dust3r.patch_embed.", "dust3r.enc_blocks.", "dust3r.enc_norm."}) {
    if (name.rfind(p, 0) == 0) return true;
  }
  return false;
}

InitReport init_from_checkpoint(Long3rModel& model, const std::string& path) {
  const TensorFile file = load_safetensors(path);
  std::map<std::string, at::Tensor> targets;
  for (const auto& kv : model.module().named_parameters()) targets[kv.key()] = kv.value();
  for (const auto& kv : model.module().named_buffers()) targets[kv.key()] = kv.value();
  InitReport r;
  std::map<std::string, bool> done;
  torch::NoGradGuard no_grad;
  for (const auto& kv : file.tensors) {
    std::string name = kv.first;
    if (name.rfind("module.", 0) == 0) name = name.substr(7);  // DistributedDataParallel
    // DUSt3R names lack Spann3R's "dust3r." prefix; LONG3R / Spann3R files
    // match as they are.
    auto it = targets.find(name);
    if (it == targets.end()) it = targets.find("dust3r." + name);
    if (it == targets.end()) {
      ++r.unused;
      continue;
    }
    if (it->second.sizes() != kv.second.sizes() || !kv.second.is_floating_point()) {
      ++r.shape_mismatch;
      r.mismatched_names.push_back(it->first);
      continue;
    }
    it->second.copy_(kv.second);
    done[it->first] = true;
    ++r.loaded;
  }
  r.fresh = static_cast<int64_t>(targets.size()) - static_cast<int64_t>(done.size());
  return r;
}

namespace {

// The mean of each figure over the sequences, summed in sequence order;
// trajectory figures over the sequences that have them.
PredictionMetrics average(const std::vector<PredictionMetrics>& all) {
  using M = PredictionMetrics;
  PredictionMetrics mean;
  const double n = static_cast<double>(all.size());
  for (double M::*f : {&M::pointmap_error, &M::acc_mean, &M::acc_median, &M::comp_mean,
                       &M::comp_median, &M::nc_mean, &M::nc_median}) {
    double sum = 0.0;
    for (const PredictionMetrics& m : all) sum += m.*f;
    mean.*f = all.empty() ? 0.0 : sum / n;
  }
  for (double M::*f : {&M::ate_rmse, &M::rpe_trans_rmse, &M::rpe_rot_rmse_deg, &M::depth_slope,
                       &M::depth_correlation}) {
    double sum = 0.0;
    int64_t count = 0;
    for (const PredictionMetrics& m : all) {
      if (!std::isfinite(m.*f)) continue;
      sum += m.*f;
      ++count;
    }
    mean.*f =
        count > 0 ? sum / static_cast<double>(count) : std::numeric_limits<double>::quiet_NaN();
  }
  for (const PredictionMetrics& m : all) {
    mean.frames += m.frames;
    mean.posed += m.posed;
  }
  return mean;
}

}  // namespace

ValidationMetrics validate(Long3rModel& model, const std::vector<SequenceSample>& sequences,
                           const LossConfig& loss_config, const ValidationConfig& config,
                           const PredictionScorer& score) {
  const TrainingModeGuard inference(model, false);
  ValidationMetrics m;
  std::vector<PredictionMetrics> scores;
  for (const SequenceSample& s : sequences) {
    std::vector<at::Tensor> frames;
    for (const at::Tensor& f : s.images) frames.push_back(f.unsqueeze(0).to(model.device()));
    std::vector<StreamOutput> coarse;
    const std::vector<StreamOutput> out =
        model.forward_sequence(frames, loss_config.coarse ? &coarse : nullptr);
    const at::Tensor gt = s.pts.unsqueeze(0).to(model.device());
    const at::Tensor valid = s.valid.unsqueeze(0).to(model.device());
    const LossTerms lt = sequence_loss(out, coarse, gt, valid, loss_config);
    m.loss += lt.total.item<double>();
    m.regression += lt.regression;

    SequencePrediction pred;
    for (const StreamOutput& o : out) {
      pred.pts.push_back(o.pts3d[0].to(at::kCPU, at::kFloat).contiguous());
      pred.conf.push_back(o.conf[0].to(at::kCPU, at::kFloat).contiguous());
    }
    m.registered += probe_loss(pred, s).registered;
    scores.push_back(score ? score(pred, s, config) : pointmap_metrics(pred, s, config));
    ++m.sequences;
  }
  if (m.sequences > 0) {
    m.loss /= static_cast<double>(m.sequences);
    m.regression /= static_cast<double>(m.sequences);
    m.registered /= static_cast<double>(m.sequences);
  }
  m.prediction = average(scores);
  return m;
}

}  // namespace long3r

// Cross-view completion, the pretext task of a "cross_view_completion" stage
// (include/long3r/train/cross_view_completion.hpp): patches, the visible set,
// the loss.
#include <ATen/ATen.h>
#include <ATen/CPUGeneratorImpl.h>
#include <c10/core/InferenceMode.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "long3r/train/cross_view_completion.hpp"
#include "long3r/train/prediction.hpp"
#include "long3r/train/train_data.hpp"

namespace long3r {

at::Tensor patchify(const at::Tensor& images, int64_t patch) {
  TORCH_CHECK(
      images.dim() == 4 && patch > 0 && images.size(2) % patch == 0 && images.size(3) % patch == 0,
      "patchify: expected [B, C, H, W] with H and W multiples of ", patch, ", got ",
      images.sizes());
  const int64_t B = images.size(0), C = images.size(1);
  const int64_t gh = images.size(2) / patch, gw = images.size(3) / patch;
  // [B, C, gh, p, gw, p] -> [B, gh, gw, p, p, C]
  return images.reshape({B, C, gh, patch, gw, patch})
      .permute({0, 2, 4, 3, 5, 1})
      .reshape({B, gh * gw, patch * patch * C});
}

at::Tensor draw_visible_patches(int64_t n, double mask_ratio) {
  if (n < 1 || !(mask_ratio >= 0.0 && mask_ratio < 1.0)) {
    throw std::invalid_argument("draw_visible_patches: need n >= 1 and mask_ratio in [0, 1)");
  }
  const int64_t v = std::max<int64_t>(
      1, static_cast<int64_t>(std::llround(static_cast<double>(n) * (1.0 - mask_ratio))));
  return std::get<0>(at::randperm(n, at::TensorOptions().dtype(at::kLong)).narrow(0, 0, v).sort());
}

at::Tensor completion_loss(const at::Tensor& pred, const at::Tensor& target_patches,
                           const at::Tensor& visible) {
  TORCH_CHECK(pred.dim() == 3 && pred.sizes() == target_patches.sizes(),
              "completion_loss: prediction ", pred.sizes(), " and target ", target_patches.sizes(),
              " differ");
  const int64_t n = pred.size(1);
  at::Tensor hidden = at::ones({n}, at::TensorOptions().dtype(at::kBool));
  hidden.index_fill_(0, visible.to(at::kCPU), false);
  const at::Tensor hidden_index = hidden.nonzero().squeeze(1).to(pred.device());
  TORCH_CHECK(hidden_index.numel() > 0, "completion_loss: no hidden patch");
  const at::Tensor target = target_patches.to(at::kFloat).index_select(1, hidden_index);
  const at::Tensor mean = target.mean(-1, /*keepdim=*/true);
  const at::Tensor var = target.var(-1, /*unbiased=*/true, /*keepdim=*/true);
  const at::Tensor normalised = (target - mean) / (var + 1e-6).sqrt();
  return (pred.to(at::kFloat).index_select(1, hidden_index) - normalised).pow(2).mean();
}

CompletionControl completion_control(Long3rModel& model, torch::nn::Linear& head,
                                     const std::vector<SequenceSample>& pairs, double mask_ratio,
                                     uint64_t seed) {
  if (pairs.size() < 2) throw std::invalid_argument("completion_control: need at least 2 pairs");
  for (const SequenceSample& p : pairs) {
    if (p.images.size() != 2) throw std::invalid_argument("completion_control: pairs only");
  }
  const TrainingModeGuard inference(model, false);
  const bool head_was_training = head->is_training();
  head->eval();
  c10::InferenceMode guard;
  const int64_t patch = model.config().dust3r.patch_size;
  const at::Device device = model.device();
  auto stack = [&](std::size_t frame) {
    std::vector<at::Tensor> v;
    for (const SequenceSample& p : pairs) v.push_back(p.images[frame]);
    return at::stack(v).to(device);
  };
  const at::Tensor reference = stack(0), masked = stack(1);
  const int64_t n = (masked.size(2) / patch) * (masked.size(3) / patch);
  at::Generator gen = at::make_generator<at::CPUGeneratorImpl>(seed);
  const int64_t v = std::max<int64_t>(
      1, static_cast<int64_t>(std::llround(static_cast<double>(n) * (1.0 - mask_ratio))));
  const at::Tensor visible = std::get<0>(
      at::randperm(n, gen, at::TensorOptions().dtype(at::kLong)).narrow(0, 0, v).sort());
  const at::Tensor target = patchify(masked, patch);
  auto loss = [&](const at::Tensor& ref) {
    return completion_loss(head(model.complete_view(masked, ref, visible)).to(at::kFloat), target,
                           visible)
        .item<double>();
  };
  CompletionControl c;
  c.loss_true = loss(reference);
  c.loss_shuffled = loss(reference.roll(1, 0));
  if (head_was_training) head->train();
  return c;
}

}  // namespace long3r

// Cross-view completion, the pretext task of a "cross_view_completion" stage
// (include/long3r/train/train.hpp): patches, the visible set, the loss.
#include <ATen/ATen.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "long3r/train/train.hpp"

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

}  // namespace long3r

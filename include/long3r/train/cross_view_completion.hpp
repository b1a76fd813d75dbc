// Cross-view completion, the pretext task of a "cross_view_completion" stage
// (train/cross_view_completion.cpp): patches, the visible set, the loss, and
// the stage's blind control.
#pragma once

#include <ATen/core/Tensor.h>
#include <torch/nn/modules/linear.h>

#include <cstdint>
#include <limits>
#include <vector>

#include "long3r/model/network/long3r_model.hpp"
#include "long3r/train/train_data.hpp"

namespace long3r {

// Cross-view completion (CroCo, Weinzaepfel et al. 2022), the pretext task of
// a "cross_view_completion" stage.
//
// The patches of images [B, 3, H, W] as [B, N, p * p * 3]: patches in
// row-major grid order, each one's pixels row by row, channels last.
at::Tensor patchify(const at::Tensor& images, int64_t patch);
// Which patches of n the encoder sees: int64 [V] of sorted indices, V =
// max(1, round(n * (1 - mask_ratio))), drawn with torch's CPU generator; the
// rest are hidden.
at::Tensor draw_visible_patches(int64_t n, double mask_ratio);
// CroCo's loss: the mean squared error over the hidden patches (those not in
// `visible`) between `pred` [B, N, p * p * 3] and the target patches, each
// normalised by its own mean and variance (norm_pix_loss). Float32.
at::Tensor completion_loss(const at::Tensor& pred, const at::Tensor& target_patches,
                           const at::Tensor& visible);
// The completion stage's blind control: completion_loss of frame 1 of each
// pair completed from its true reference (frame 0), and from the reference of
// another pair of the batch (the batch rolled by one), same hidden patches
// (drawn from their own generator seeded with `seed`, torch's default
// generator untouched). A true / shuffled ratio near 1: the other view is not
// used. Inference; `head` is the stage's pixel head. Pairs: sequences of 2
// frames, at least 2 of them.
struct CompletionControl {
  double loss_true = std::numeric_limits<double>::quiet_NaN();
  double loss_shuffled = std::numeric_limits<double>::quiet_NaN();
};

CompletionControl completion_control(Long3rModel& model, torch::nn::Linear& head,
                                     const std::vector<SequenceSample>& pairs, double mask_ratio,
                                     uint64_t seed = 0);

}  // namespace long3r

// CroCo's initialisation of a model trained from scratch (CroCoNet's
// initialize_weights, which DUSt3R inherits).
#include <torch/nn/init.h>
#include <torch/nn/modules/conv.h>
#include <torch/nn/modules/linear.h>
#include <torch/nn/modules/normalization.h>

#include "long3r/train/weight_init.hpp"

namespace long3r {

void init_croco_weights(Long3rModel& model) {
  torch::NoGradGuard no_grad;
  for (const auto& item : model.module().named_modules()) {
    const std::string& name = item.key();
    // DUSt3R attaches its downstream heads after CroCo's initialisation, so
    // they keep PyTorch's defaults; so do ours.
    if (name.find("downstream_head") != std::string::npos) continue;
    torch::nn::Module& m = *item.value();
    if (auto* linear = m.as<torch::nn::LinearImpl>()) {
      torch::nn::init::xavier_uniform_(linear->weight);
      if (linear->bias.defined()) torch::nn::init::zeros_(linear->bias);
    } else if (auto* norm = m.as<torch::nn::LayerNormImpl>()) {
      if (norm->weight.defined()) torch::nn::init::ones_(norm->weight);
      if (norm->bias.defined()) torch::nn::init::zeros_(norm->bias);
    } else if (auto* conv = m.as<torch::nn::Conv2dImpl>()) {
      // The patch embedding, initialised as a linear layer over its patch
      // (CroCo views the kernel as [out, in * p * p]).
      if (name.find("patch_embed") == std::string::npos) continue;
      torch::nn::init::xavier_uniform_(conv->weight.view({conv->weight.size(0), -1}));
      if (conv->bias.defined()) torch::nn::init::zeros_(conv->bias);
    }
  }
  for (const auto& kv : model.module().named_parameters()) {
    if (kv.key() == "dust3r.mask_token" || kv.key() == "mask_token") {
      torch::nn::init::normal_(kv.value(), 0.0, 0.02);
    }
  }
  model.to(model.device());  // drops whatever the model derived from its old weights
}

}  // namespace long3r

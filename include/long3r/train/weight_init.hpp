// CroCo's initialisation of a model trained from scratch
// (train/weight_init.cpp).
#pragma once

#include "long3r/model/network/long3r_model.hpp"

namespace long3r {

// CroCo's initialisation (CroCoNet.initialize_weights, which DUSt3R
// inherits) for a model trained from scratch: every linear layer outside the
// downstream heads xavier-uniform with zero bias, the patch embedding's kernel
// xavier-uniform as a linear map of its patch, LayerNorms 1 / 0, mask_token
// normal with std 0.02. The DPT heads keep libtorch's defaults, as DUSt3R's
// (attached after CroCo's initialisation) keep PyTorch's. Draws from torch's
// default generator.
void init_croco_weights(Long3rModel& model);

}  // namespace long3r

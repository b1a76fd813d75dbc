// Strict loading of named tensors into a module tree whose parameter names
// mirror the official PyTorch checkpoints.
#pragma once

#include <ATen/core/Tensor.h>

#include <map>
#include <string>
#include <vector>

#include "long3r/io/safetensors_header.hpp"

namespace torch {
namespace nn {
class Module;
}  // namespace nn
}  // namespace torch

namespace long3r {

// Copies tensors into module's parameters and buffers by name (after stripping
// `strip_prefix` from the tensor names and dropping names that start with any
// of `ignore_prefixes`). Checks presence, shape and dtype of every one first
// and throws a CheckpointError that lists every missing, unexpected and
// mis-shaped tensor at once; on failure the module is left untouched.
void load_module_strict(torch::nn::Module& module, const std::map<std::string, at::Tensor>& tensors,
                        const std::string& source_name, const std::string& strip_prefix = "",
                        const std::vector<std::string>& ignore_prefixes = {});

}  // namespace long3r

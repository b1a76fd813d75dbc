// The shared model shell and the streaming-model factory; see
// include/long3r/model/network/model_shell.hpp and streaming.hpp.
#include "long3r/model/network/model_shell.hpp"

#include <ATen/ATen.h>
#include <torch/nn/module.h>
#include <torch/nn/modules/conv.h>

#include <algorithm>
#include <cstdio>
#include <stdexcept>
#include <string>
#include <utility>

#include "long3r/io/fnv1a.hpp"
#include "long3r/model/loading/checkpoint.hpp"
#include "long3r/model/loading/safetensors.hpp"
#include "long3r/model/network/long3r_model.hpp"
#include "long3r/model/network/spann3r_model.hpp"
#include "long3r/model/network/streaming.hpp"

namespace long3r {
namespace {

std::string fingerprint(const TensorMap& tensors) {
  constexpr int64_t kEndBytes = 4096;
  Fnv1a f;
  for (const auto& [name, t] : tensors) {
    f.add(name);
    f.add(std::string(c10::toString(t.scalar_type())));
    for (const int64_t d : t.sizes()) f.add(&d, sizeof d);
    const at::Tensor flat = t.reshape({-1});
    const int64_t n = flat.numel(), per = std::max<int64_t>(1, kEndBytes / t.element_size());
    for (const at::Tensor& part : {flat.narrow(0, 0, std::min(n, per)),
                                   flat.narrow(0, n - std::min(n, per), std::min(n, per))}) {
      const at::Tensor c = part.to(at::kCPU).contiguous();
      f.add(c.data_ptr(), static_cast<std::size_t>(c.numel() * c.element_size()));
    }
  }
  char hex[17];
  std::snprintf(hex, sizeof hex, "%016llx", static_cast<unsigned long long>(f.h));
  return hex;
}

}  // namespace

StateDict StreamingModel::stream_state() const {
  throw std::logic_error("the " + variant() + " model cannot save its stream (no sessions)");
}

void StreamingModel::restore_stream_state(const StateDict&) {
  throw std::logic_error("the " + variant() + " model cannot restore a stream (no sessions)");
}

ModelShell::ModelShell(const ModelConfig& config, ModelKind kind, const char* needs)
    : config_(config) {
  if (config.kind != kind) {
    throw ModelConfigError(std::string(needs) + ", got " + model_kind_name(config.kind));
  }
  validate_model_config(config);
}

ModelShell::~ModelShell() = default;
ModelShell::ModelShell(ModelShell&&) noexcept = default;
ModelShell& ModelShell::operator=(ModelShell&&) noexcept = default;

void ModelShell::set_module(std::shared_ptr<torch::nn::Module> module) {
  module_ = std::move(module);
}

void ModelShell::load_weights(const TensorMap& tensors, const std::string& source_name,
                              const std::string& strip_prefix) {
  load_module_strict(*module_, tensors, source_name, strip_prefix);
  weights_fingerprint_ = fingerprint(tensors);
  // Floating tensors load as stored (a bfloat16 checkpoint leaves bfloat16
  // weights, unconverted): the model then runs in the checkpoint's precision,
  // dtype(), with what to() keeps float32 on this device. A float32
  // checkpoint needs nothing more.
  bool all_float32 = true;
  for (const auto& p : module_->parameters()) {
    all_float32 = all_float32 && (!p.is_floating_point() || p.scalar_type() == at::kFloat);
  }
  if (all_float32) {
    weights_changed();
  } else {
    to(device(), dtype());
  }
}

void ModelShell::save(const std::string& path) const {
  TensorMap tensors;
  for (const auto& kv : module_->named_parameters()) {
    tensors[kv.key()] = kv.value().detach().to(at::kCPU).contiguous();
  }
  for (const auto& kv : module_->named_buffers()) {
    tensors[kv.key()] = kv.value().detach().to(at::kCPU).contiguous();
  }
  save_safetensors(path, tensors, {{"config", model_config_to_json(config_)}});
}

void ModelShell::to(const at::Device& device) {
  module_->to(device);
  weights_changed();
}

void ModelShell::to(const at::Device& device, at::ScalarType dtype) {
  InferenceTarget target;
  target.device = device;
  target.dtype = dtype;
  target.conv_dtype = device.is_cpu() ? at::kFloat : dtype;
  to(target);
}

void ModelShell::to(const InferenceTarget& target) {
  // The convolutions (patch embeddings, DPT heads) in target.conv_dtype: on a
  // CPU that only emulates bfloat16, libtorch 1.13's bfloat16 convolution
  // loses 5 % (max relative error on a patch embedding against float32 on the
  // same rounded inputs, where a linear loses 0.3 %), so they stay float32
  // there (resolve_inference_target). conv_transpose2d has no bfloat16 CPU
  // kernel at all. Each layer's inputs are cast to its weights' precision
  // (docs/performance.md, "Precision").
  const at::Device& device = target.device;
  // Not Module::to(device, dtype): it would convert integer buffers too.
  for (const auto& item : module_->named_modules()) {
    torch::nn::Module& m = *item.value();
    at::ScalarType want = target.dtype;
    if (m.as<torch::nn::Conv2dImpl>() != nullptr) want = target.conv_dtype;
    if (m.as<torch::nn::ConvTranspose2dImpl>() != nullptr) {
      want = device.is_cpu() ? at::kFloat : target.conv_dtype;
    }
    if (target.dtype == at::kFloat) want = at::kFloat;
    for (auto& p : m.named_parameters(/*recurse=*/false)) {
      p.value().set_data(
          p.value().to(device, p.value().is_floating_point() ? want : p.value().scalar_type()));
    }
    for (auto& b : m.named_buffers(/*recurse=*/false)) {
      b.value().set_data(
          b.value().to(device, b.value().is_floating_point() ? want : b.value().scalar_type()));
    }
  }
  weights_changed();
}

// Every network registers a parameter first (DUSt3R's mask_token) and keeps all
// of them on one device.
at::Device ModelShell::device() const { return module_->parameters().front().device(); }
at::ScalarType ModelShell::dtype() const { return module_->parameters().front().scalar_type(); }

torch::nn::Module& ModelShell::module() { return *module_; }

ModelCheckpoint read_model_checkpoint(const std::string& path) {
  TensorFile file = map_safetensors(path);  // read tensor by tensor as the model takes them
  return {model_config_from_metadata(file.metadata, path), std::move(file.tensors)};
}

namespace {
template <class Model>
std::unique_ptr<StreamingModel> load_to(const ModelCheckpoint& c, const std::string& path,
                                        const InferenceTarget& target) {
  std::unique_ptr<Model> model = model_from_checkpoint<Model>(c, path);
  model->to(target);  // converts only what differs (the convolutions of a bfloat16 file, too)
  return model;
}
}  // namespace

void apply_memory_overrides(const InferenceConfig& inference, ModelConfig* config) {
  for (const auto& [name, value] :
       {std::pair<const char*, int>{"short_term_frames", inference.short_term_frames},
        {"long_term_capacity", inference.long_term_capacity}}) {
    if (value >= 0 && config->kind != ModelKind::kLong3r) {
      throw ConfigError(std::string(name) + ": sets a LONG3R model's memory; this is a " +
                        model_kind_name(config->kind) + " model (leave it at -1)");
    }
  }
  if (inference.short_term_frames >= 0) {
    config->long3r.short_term_frames = inference.short_term_frames;
  }
  if (inference.long_term_capacity >= 0) {
    config->long3r.long_term_capacity = inference.long_term_capacity;
  }
}

std::unique_ptr<StreamingModel> make_streaming_model(const std::string& path,
                                                     const InferenceConfig& inference) {
  const InferenceTarget target = resolve_inference_target(inference);
  try {
    ModelCheckpoint c = read_model_checkpoint(path);
    apply_memory_overrides(inference, &c.config);
    if (c.config.kind == ModelKind::kLong3r) return load_to<Long3rModel>(c, path, target);
    if (c.config.kind == ModelKind::kSpann3r) return load_to<Spann3rModel>(c, path, target);
    if (c.config.kind == ModelKind::kDust3r) {
      throw CheckpointError(path +
                            ": a DUSt3R pair model (AsymmetricCroCo3DStereo), not a streaming "
                            "model; the pipeline needs a Spann3R (or LONG3R) checkpoint");
    }
    throw CheckpointError(path + ": model kind \"" + std::string(model_kind_name(c.config.kind)) +
                          "\" is not supported by the streaming pipeline yet");
  } catch (const ModelConfigError& e) {
    // Every checkpoint error names the file (the metadata reader already does).
    const std::string what = e.what();
    throw CheckpointError(what.rfind(path, 0) == 0 ? what : path + ": " + what);
  }
}

}  // namespace long3r

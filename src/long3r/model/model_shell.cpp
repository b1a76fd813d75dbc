// The shared model shell and the streaming-model factory; see
// include/long3r/model/model_shell.hpp and streaming.hpp.
#include "long3r/model/model_shell.hpp"

#include <ATen/ATen.h>
#include <torch/nn/module.h>

#include "long3r/model/checkpoint.hpp"
#include "long3r/model/long3r_model.hpp"
#include "long3r/model/safetensors.hpp"
#include "long3r/model/spann3r_model.hpp"
#include "long3r/model/streaming.hpp"

namespace long3r {

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
  weights_changed();
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

// Every network registers a parameter first (DUSt3R's mask_token) and keeps all
// of them on one device.
at::Device ModelShell::device() const { return module_->parameters().front().device(); }

torch::nn::Module& ModelShell::module() { return *module_; }

ModelCheckpoint read_model_checkpoint(const std::string& path) {
  TensorFile file = load_safetensors(path);
  return {model_config_from_metadata(file.metadata, path), std::move(file.tensors)};
}

std::unique_ptr<StreamingModel> make_streaming_model(const std::string& path) {
  try {
    const ModelCheckpoint c = read_model_checkpoint(path);
    if (c.config.kind == ModelKind::kLong3r) return model_from_checkpoint<Long3rModel>(c, path);
    if (c.config.kind == ModelKind::kSpann3r) return model_from_checkpoint<Spann3rModel>(c, path);
    if (c.config.kind == ModelKind::kDust3r) {
      throw CheckpointError(path +
                            ": a DUSt3R pair model (AsymmetricCroCo3DStereo), not a streaming "
                            "model; the pipeline needs a Spann3R (or LONG3R) checkpoint");
    }
    throw CheckpointError(path + ": model kind \"" + std::string(model_kind_name(c.config.kind)) +
                          "\" is not supported by the streaming pipeline yet");
  } catch (const ModelConfigError& e) {
    throw CheckpointError(e.what());
  }
}

}  // namespace long3r

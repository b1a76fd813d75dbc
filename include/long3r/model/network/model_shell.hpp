// ModelShell: what every model front-end (Dust3rModel, Spann3rModel,
// Long3rModel) shares around its network: the configuration (kind-checked and
// validated at construction), the module tree, strict loading from and saving
// to safetensors checkpoints, and the device. Each front-end keeps only its own
// inference (and stream state).
#pragma once

#include <ATen/core/Tensor.h>

#include <memory>
#include <string>

#include "long3r/model/network/model_config.hpp"
#include "long3r/model/network/model_trace.hpp"  // TensorMap
#include "long3r/model/runtime/inference.hpp"

namespace torch {
namespace nn {
class Module;
}  // namespace nn
}  // namespace torch

namespace long3r {

// A checkpoint's configuration (metadata "config") and tensors.
struct ModelCheckpoint {
  ModelConfig config;
  TensorMap tensors;
};
// Throws CheckpointError / ModelConfigError.
ModelCheckpoint read_model_checkpoint(const std::string& path);

// A Model built from the checkpoint's configuration, then every tensor loaded
// strictly (what each Model::from_file does).
template <class Model>
std::unique_ptr<Model> model_from_checkpoint(const ModelCheckpoint& checkpoint,
                                             const std::string& source_name) {
  auto model = std::make_unique<Model>(checkpoint.config);
  model->load_weights(checkpoint.tensors, source_name);
  return model;
}

class ModelShell {
 public:
  virtual ~ModelShell();
  ModelShell(ModelShell&&) noexcept;
  ModelShell& operator=(ModelShell&&) noexcept;

  const ModelConfig& config() const { return config_; }

  // Strict load of tensors named as the module tree (a name prefix such as
  // "dust3r." can be stripped; see load_module_strict). Throws CheckpointError.
  // Floating tensors load in their stored dtype (a bfloat16 checkpoint gives a
  // bfloat16 model, converted by nothing but to()'s float32 convolutions on
  // the CPU). Ends a stream in progress.
  void load_weights(const TensorMap& tensors, const std::string& source_name,
                    const std::string& strip_prefix = "");

  // Identifies the weights last loaded by load_weights(): a hash of every
  // tensor's name, dtype, shape and first and last 4 KiB of data (a new
  // training step changes nearly every tensor). Empty before any load.
  const std::string& weights_fingerprint() const { return weights_fingerprint_; }
  // Every parameter and buffer by name, with metadata "config" =
  // model_config_to_json(config()); from_file() reads it back.
  void save(const std::string& path) const;

  // Moves the weights; ends a stream in progress.
  void to(const at::Device& device);
  // Moves and converts the floating-point weights once (e.g. to bfloat16: the
  // model then runs in that precision, see InferenceConfig), the convolutions
  // to target.conv_dtype (float32 on the CPU: the transposed ones); ends a stream.
  void to(const InferenceTarget& target);
  // The same with the convolutions float32 on the CPU, in `dtype` elsewhere.
  void to(const at::Device& device, at::ScalarType dtype);
  at::Device device() const;
  // The weights' precision, in which inputs are given to the network.
  at::ScalarType dtype() const;

  // The module tree (names as in the official state_dict).
  torch::nn::Module& module();

 protected:
  // Throws ModelConfigError "<needs>, got <kind>" unless config.kind == kind,
  // then validates the configuration.
  ModelShell(const ModelConfig& config, ModelKind kind, const char* needs);

  // The network, set once by the derived constructor.
  void set_module(std::shared_ptr<torch::nn::Module> module);

  // Called after load_weights() and to(): drop state computed with the old
  // weights or on the old device.
  virtual void weights_changed() {}

 private:
  ModelConfig config_;
  std::shared_ptr<torch::nn::Module> module_;
  std::string weights_fingerprint_;
};

}  // namespace long3r

// DUSt3R pair inference (the official AsymmetricCroCo3DStereo): two images in,
// two point maps and confidences out, both in the coordinate frame of camera 1.
//
// Parameter names mirror the official state_dict, so official checkpoints
// (converted to safetensors, see docs/checkpoints.md) load by name. Inference
// runs under c10::InferenceMode in float32 on the model's device.
//
// Portrait images (H > W) with `landscape_only` (the official default) give
// maps of shape [B, W, H, .]: the official transpose_to_landscape wrapper
// transposes the heads' outputs and this engine reproduces it.
#pragma once

#include <ATen/core/Tensor.h>

#include <memory>
#include <string>

#include "long3r/model/network/model_shell.hpp"
#include "long3r/model/network/model_trace.hpp"

namespace long3r {

struct PairPrediction {
  at::Tensor pts3d1;  // [B, H1, W1, 3] points of image 1, camera-1 frame
  at::Tensor conf1;   // [B, H1, W1] (>= conf vmin); undefined without a confidence channel
  at::Tensor pts3d2;  // [B, H2, W2, 3] points of image 2, camera-1 frame ("pts3d_in_other_view")
  at::Tensor conf2;   // [B, H2, W2]
};

// Configuration, loading, saving, device and module: see ModelShell.
class Dust3rModel : public ModelShell {
 public:
  // config.kind must be ModelKind::kDust3r. Parameters start default-initialised;
  // load_weights() fills them.
  explicit Dust3rModel(const ModelConfig& config);
  ~Dust3rModel() override;
  Dust3rModel(Dust3rModel&&) noexcept;
  Dust3rModel& operator=(Dust3rModel&&) noexcept;

  // Reads a safetensors checkpoint: configuration from __metadata__["config"],
  // then every tensor strictly (see load_module_strict). Throws
  // CheckpointError / ModelConfigError.
  static Dust3rModel from_file(const std::string& path);

  // img1, img2: [B, 3, H, W] float, values (rgb - 0.5) / 0.5, H and W
  // multiples of the patch size (the two sizes may differ). Images of one
  // shape are encoded as one batch of 2B, as the official model does.
  // With an enabled trace, records the official intermediates under the golden
  // names (img{1,2}.*, dec{1,2}.*, head{1,2}.*, res1.*, res2.*).
  PairPrediction infer(const at::Tensor& img1, const at::Tensor& img2,
                       const Trace& trace = Trace()) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace long3r

// LONG3R online reconstruction (spec "One step of the stream") as a
// StreamingModel: Spann3R's encoder and memory key/value encoders, memory
// gating over a 3D spatio-temporal memory, and the joint decoder whose refined
// branch (frame t) alternates pairwise and memory blocks while the coarse
// branch decodes frame t+1.
//
// Step t runs when frame t+1 arrives (push) and returns frame t:
//   F^I_{t+1} = Enc(I_{t+1});
//   F^fuse_t = F^I_0 at t = 0, else the gated read-out of the memory with the
//   query q_t = attn_head_2(cat(F^I_t, F^c_t)), which also gives the relevant
//   set R that the memory blocks attend to;
//   joint decoding; head1 -> pointmap_t, conf_t; memory write of frame t
//   (k_t = attn_head_1(cat(F^I_t, x_B)), v_t = value encoder of pointmap_t + k_t,
//   token positions = confidence-weighted patch means of pointmap_t);
//   F^c_{t+1} = y_B.
// peek_last() / flush() return the last frame from head2 of the last step. All point maps
// are in the frame of camera 0. Portrait frames with landscape_only give maps
// of shape [B, W, H, .] (as the DUSt3R heads do); the memory always works on
// the token grid of the image (the maps are transposed back for it).
#pragma once

#include <ATen/core/Tensor.h>

#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "long3r/memory/spatio_temporal_memory.hpp"
#include "long3r/model/network/model_shell.hpp"
#include "long3r/model/network/model_trace.hpp"
#include "long3r/model/network/streaming.hpp"

namespace long3r {

// Configuration, loading, saving, device and module: see ModelShell (the module
// tree has Spann3R's names; dust3r.dec_blocks.{odd}.* are memory blocks, see
// docs/checkpoints.md "LONG3R modules"). to() and load_weights() reset the
// stream.
class Long3rModel : public StreamingModel, public ModelShell {
 public:
  // config.kind must be ModelKind::kLong3r. Parameters start with libtorch's
  // default (random) initialisation.
  explicit Long3rModel(const ModelConfig& config);
  ~Long3rModel() override;

  // Configuration from the file's metadata "config", then every tensor strictly.
  static std::unique_ptr<Long3rModel> from_file(const std::string& path);

  // Inference (default): push() runs under c10::InferenceMode, parameters do not
  // require gradients, memory tokens are stored detached, gating uses tau.
  // Training: no inference mode, parameters require gradients, tau = 0 (all
  // memory relevant, W' = W), the memory keeps the graph across steps, and
  // every step also runs head2 (the coarse prediction of the next frame).
  // Resets the stream.
  void set_training(bool training);
  bool training() const;

  // Inference only (training always recomputes): each memory token's projected
  // key and value for every memory block are computed once, when the token is
  // written, and kept with it in the memory, instead of being recomputed for
  // the relevant tokens at every step. The outputs agree to float rounding;
  // the cost that grows with the memory is then the gating and the attention
  // only. On by default; the off path is the reference. Resets the stream.
  void set_memory_projection_cache(bool on);
  bool memory_projection_cache() const;

  // StreamingModel. image: [B, 3, H, W] float, (rgb - 0.5) / 0.5, H and W
  // multiples of the patch size, one size and batch for the whole stream.
  // peek_last() after a single frame returns nothing (the model needs a pair).
  // StepStats: memory sizes after the step's write; mem_long_tokens and
  // relevant_tokens are the maxima over the batch (0 relevant at step 0);
  // voxel_size is v_scene of stream 0 (0 while undefined).
  std::optional<StreamOutput> push(const at::Tensor& image) override;
  std::optional<StreamOutput> peek_last() override;
  void reset() override;
  int64_t frames_pushed() const override;
  std::string variant() const override { return "long3r"; }
  // Sessions: the memory (payloads recomputed on restore), the newest frame's
  // F^I and F^c, the coarse layers head 2 reads (peek_last), the shape and
  // frame count. Inference mode only.
  StateDict stream_state() const override;
  void restore_stream_state(const StateDict& state) override;
  ModelIdentity identity() const override;
  std::array<int64_t, 2> recorded_input_size() const override {
    return {config().input_width, config().input_height};
  }

  // One whole sequence in a single graph (reset, push every frame, flush):
  // returns N outputs, frames 0..N-2 from head1 and frame N-1 from head2. With
  // `coarse`, it receives N-1 head2 predictions: (*coarse)[j] is frame j+1 as
  // predicted at step j (training targets). Needs N >= 2. Works in both modes;
  // use it with set_training(true) to back-propagate. The last step's memory
  // write is skipped: the stream ends there, so nothing would read it (the
  // outputs are those of push() and flush(); that step's StepStats then
  // count the memory without frame N-2).
  std::vector<StreamOutput> forward_sequence(const std::vector<at::Tensor>& frames,
                                             std::vector<StreamOutput>* coarse = nullptr);

  // Cross-view completion, CroCo's pretext task, for a pretraining stage
  // (docs/training.md): `masked` and `reference` [B, 3, H, W] as push() takes
  // them; the encoder sees only the patches of `masked` listed in `visible`
  // (int64 [V], one set for the batch), the coarse decoder branch decodes all
  // of them against the whole `reference`. Returns the last decoder layer
  // (after dec_norm), [B, N, C_d] for the N patches of `masked`, for a pixel
  // head the caller owns. Uses no memory and leaves the stream untouched.
  at::Tensor complete_view(const at::Tensor& masked, const at::Tensor& reference,
                           const at::Tensor& visible);

  // The memory after the last push (that step's read and write done); empty
  // after flush() or reset().
  const SpatioTemporalMemory& memory() const;

 private:
  void weights_changed() override;

  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace long3r

// Spann3R online reconstruction (the official Spann3R eval-mode forward) as a
// StreamingModel: DUSt3R's encoder, decoder and heads plus Spann3R's memory
// key/value encoders and SpatialMemory (long3r::Spann3rMemory).
//
// Step k runs when frame k+1 arrives (push) and returns frame k:
//   step 0 encodes frames 0 and 1 in one batch; later steps reuse frame k's
//   features from the previous step and encode frame k+1;
//   feat_fuse = frame k's features at step 0, else memory.read(feat_k2 of step
//   k-1) (residual read-out);
//   dec1, dec2 = decoder(feat_fuse, feat of frame k+1);
//   feat_k1 = attn_head_1(cat(feat_k, dec1[-1])), feat_k2 = attn_head_2(cat(feat_{k+1}, dec2[-1]));
//   frame k = head1(dec1); value = value encoder of frame k's point map;
//   memory.add_mem_check(feat_k1, value + feat_k1).
// peek_last() / flush() return the last frame from head 2 of the last step. All point maps
// are in the frame of camera 0. Portrait frames with landscape_only (the
// official Spann3R setting) give maps of shape [B, W, H, .], as the official
// model does.
#pragma once

#include <ATen/core/Tensor.h>

#include <memory>
#include <optional>
#include <string>

#include "long3r/memory/spann3r_memory.hpp"
#include "long3r/model/network/model_shell.hpp"
#include "long3r/model/network/model_trace.hpp"
#include "long3r/model/network/streaming.hpp"

namespace long3r {

// Configuration, loading, saving, device and module: see ModelShell (the module
// names are the official state_dict's: dust3r.*, value_encoder.*, attn_head_1.*,
// norm_q.*, ...). to() and load_weights() reset the stream.
class Spann3rModel : public StreamingModel, public ModelShell {
 public:
  // config.kind must be ModelKind::kSpann3r; memory settings come from
  // config.spatial_memory. Parameters start default-initialised.
  explicit Spann3rModel(const ModelConfig& config);
  ~Spann3rModel() override;

  // Configuration from the file's metadata "config", then every tensor strictly.
  static std::unique_ptr<Spann3rModel> from_file(const std::string& path);

  // StreamingModel. image: [B, 3, H, W] float, (rgb - 0.5) / 0.5, H and W
  // multiples of the patch size, the same size for the whole stream.
  // peek_last() after a single frame returns nothing (Spann3R needs a pair).
  std::optional<StreamOutput> push(const at::Tensor& image) override;
  std::optional<StreamOutput> peek_last() override;
  void reset() override;
  int64_t frames_pushed() const override;
  std::string variant() const override { return "spann3r"; }
  // Sessions: the memory (keys, values, counters), the newest frame's
  // features and next query, the coarse layers head 2 reads (peek_last), the
  // shape and frame count.
  StateDict stream_state() const override;
  void restore_stream_state(const StateDict& state) override;
  ModelIdentity identity() const override;
  std::array<int64_t, 2> recorded_input_size() const override {
    return {config().input_width, config().input_height};
  }
  // False with landscape_only (the official setting).
  bool accepts_portrait() const override;

  // Records, per step k, under "step{k}.": the encoder intermediates of the
  // newly encoded frames (img1.* at step 0, img2.*), dec1.* / dec2.*, head1.*,
  // feat_fuse (k >= 1), feat_k1, feat_k2, cur_v, pts3d, conf; peek_last()
  // (and so flush()) records "flush.head2.*", "flush.pts3d", "flush.conf". While a trace is set the
  // memory keeps each read's softmax weights (memory().last_read().attention).
  void set_trace(const Trace& trace);

  // The memory after the last push (that step's read and update done); empty
  // after flush() or reset(), which end the stream.
  const Spann3rMemory& memory() const;

 private:
  void weights_changed() override;

  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace long3r

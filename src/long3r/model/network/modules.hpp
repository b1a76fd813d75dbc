// torch::nn modules of the DUSt3R / Spann3R networks (private to long3r_network
// and its tests; includes torch/nn).
//
// Every submodule is registered under the name the official PyTorch module
// tree uses, so that official state_dicts load by name with
// load_module_strict(): `enc_blocks.3.attn.qkv.weight`,
// `dec_blocks2.0.cross_attn.projq.weight`,
// `downstream_head1.dpt.scratch.refinenet1.resConfUnit1.conv1.weight`, ...
//
// Tensor layouts: tokens [B, N, C] in row-major patch order, positions (y, x);
// feature maps NCHW; point maps [B, H, W, 3] (channel last), confidences
// [B, H, W]. All forward functions are pure (they never modify their inputs).
#pragma once

#include <torch/nn/module.h>
#include <torch/nn/modules/container/modulelist.h>
#include <torch/nn/modules/container/sequential.h>
#include <torch/nn/modules/conv.h>
#include <torch/nn/modules/linear.h>
#include <torch/nn/modules/normalization.h>

#include <chrono>
#include <map>
#include <mutex>
#include <tuple>
#include <vector>

#include "long3r/memory/memory_gating.hpp"  // GatingNorms
#include "long3r/model/loading/state_dict.hpp"
#include "long3r/model/network/model_config.hpp"
#include "long3r/model/network/model_trace.hpp"

namespace long3r {
namespace model {

// nn.LayerNorm (its parameter names) computed by apply_layer_norm, which says
// how it treats the precisions (autocast, bfloat16 on the CPU).
class LayerNormImpl : public torch::nn::LayerNormImpl {
 public:
  using torch::nn::LayerNormImpl::LayerNormImpl;
  at::Tensor forward(const at::Tensor& x) {
    TORCH_CHECK(options.normalized_shape().size() == 1, "LayerNorm: one normalised dimension");
    return apply_layer_norm(x, {weight, bias, options.eps()});
  }
};
TORCH_MODULE(LayerNorm);
inline LayerNorm layer_norm(int64_t dim, double eps) {
  return LayerNorm(torch::nn::LayerNormOptions({dim}).eps(eps));
}

// ---------------------------------------------------------------------------
// 2D rotary position embedding (CroCo RoPE2D): the first half of each head's
// channels rotates with the token's row y, the second half with its column x;
// inside each half, channel pairs (i, i + D/2) rotate by pos * base^(-2i/D).

// Per-token tables for one head width and one patch grid, [N, Dh]: `cos`, and
// `sin` with rotate_half's sign folded in, so that
//   rope(x) = x * cos + swap_halves(x) * sin
// equals the official x * cos + rotate_half(x) * sin value for value.
struct RopeTable {
  at::Tensor cos;
  at::Tensor sin;
  bool defined() const { return cos.defined(); }
};

class Rope2D {
 public:
  explicit Rope2D(double base = 100.0) : base_(base) {}
  Rope2D(const Rope2D&) = delete;
  Rope2D& operator=(const Rope2D&) = delete;

  // Cached per (head_dim, grid, device, dtype); computed once, then shared
  // (thread-safe).
  RopeTable table(int64_t head_dim, int64_t grid_h, int64_t grid_w, const at::Device& device,
                  at::ScalarType dtype) const;
  std::size_t cache_size() const;
  void clear_cache();
  double base() const { return base_; }

  // x: [..., N, Dh] (any strides). Returns a new tensor.
  static at::Tensor apply(const at::Tensor& x, const RopeTable& table);

 private:
  using Key = std::tuple<int64_t, int64_t, int64_t, int, int, int>;
  double base_;
  mutable std::mutex mutex_;
  mutable std::map<Key, RopeTable> cache_;
};

// Row-major (y, x) positions of a grid_h x grid_w patch grid, [B, N, 2] int64
// (what the official PositionGetter returns).
at::Tensor grid_positions(int64_t batch, int64_t grid_h, int64_t grid_w, const at::Device& device);

// softmax(q k^T / sqrt(Dh)) v over [B, H, N, Dh] tensors (plain matmul and
// softmax; the fused kernel where libtorch >= 2 has it).
at::Tensor attend(const at::Tensor& q, const at::Tensor& k, const at::Tensor& v);

// ---------------------------------------------------------------------------
// Transformer parts (CroCo blocks).

class MlpImpl : public torch::nn::Module {
 public:
  MlpImpl(int64_t dim, int64_t hidden);
  at::Tensor forward(const at::Tensor& x);
  torch::nn::Linear fc1{nullptr}, fc2{nullptr};
};
TORCH_MODULE(Mlp);

// Self-attention: qkv Linear, RoPE on q and k, softmax, proj.
class AttentionImpl : public torch::nn::Module {
 public:
  AttentionImpl(int64_t dim, int64_t num_heads, bool qkv_bias);
  // rope: undefined table = no position encoding.
  at::Tensor forward(const at::Tensor& x, const RopeTable& rope);
  torch::nn::Linear qkv{nullptr}, proj{nullptr};
  int64_t num_heads;
};
TORCH_MODULE(Attention);

class CrossAttentionImpl : public torch::nn::Module {
 public:
  CrossAttentionImpl(int64_t dim, int64_t num_heads, bool qkv_bias);
  at::Tensor forward(const at::Tensor& query, const at::Tensor& key, const at::Tensor& value,
                     const RopeTable& qrope, const RopeTable& krope);
  torch::nn::Linear projq{nullptr}, projk{nullptr}, projv{nullptr}, proj{nullptr};
  int64_t num_heads;
};
TORCH_MODULE(CrossAttention);

// Pre-norm encoder block: x + attn(norm1(x)); x + mlp(norm2(x)).
class BlockImpl : public torch::nn::Module {
 public:
  BlockImpl(int64_t dim, int64_t num_heads, int64_t mlp_hidden, bool qkv_bias, double eps);
  at::Tensor forward(const at::Tensor& x, const RopeTable& rope);
  LayerNorm norm1{nullptr}, norm2{nullptr};
  Attention attn{nullptr};
  Mlp mlp{nullptr};
};
TORCH_MODULE(Block);

// Decoder block: self-attention, cross-attention to the other branch (norm_y
// on its tokens when norm_mem), MLP; all pre-norm and residual.
class DecoderBlockImpl : public torch::nn::Module {
 public:
  DecoderBlockImpl(int64_t dim, int64_t num_heads, int64_t mlp_hidden, double eps, bool norm_mem);
  at::Tensor forward(const at::Tensor& x, const at::Tensor& y, const RopeTable& xrope,
                     const RopeTable& yrope);
  LayerNorm norm1{nullptr}, norm2{nullptr}, norm3{nullptr}, norm_y{nullptr};
  Attention attn{nullptr};
  CrossAttention cross_attn{nullptr};
  Mlp mlp{nullptr};
};
TORCH_MODULE(DecoderBlock);

// Random draws the initialisation of a DecoderBlock(dim, ., mlp_hidden, ...)
// makes, and advancing the default generator by n such draws: a network that
// leaves out blocks it once built keeps its seeded initialisation.
int64_t decoder_block_init_draws(int64_t dim, int64_t mlp_hidden);
void skip_init_draws(int64_t n);

// PatchEmbedDust3R: conv patch x patch / stride patch, flattened row-major.
class PatchEmbedImpl : public torch::nn::Module {
 public:
  PatchEmbedImpl(int64_t in_channels, int64_t dim, int64_t patch);
  // [B, C_in, H, W] -> contiguous [B, (H/p)(W/p), dim].
  at::Tensor forward(const at::Tensor& image);
  torch::nn::Conv2d proj{nullptr};
  int64_t patch;
};
TORCH_MODULE(PatchEmbed);

// ---------------------------------------------------------------------------
// DPT head (official DPTOutputAdapter_fix inside PixelwiseTaskWithDPT).

class ResidualConvUnitImpl : public torch::nn::Module {
 public:
  explicit ResidualConvUnitImpl(int64_t features);
  at::Tensor forward(const at::Tensor& x);
  torch::nn::Conv2d conv1{nullptr}, conv2{nullptr};
};
TORCH_MODULE(ResidualConvUnit);

class FeatureFusionBlockImpl : public torch::nn::Module {
 public:
  explicit FeatureFusionBlockImpl(int64_t features);
  // x0 + resConfUnit1(x1) (when x1 is defined), resConfUnit2, 2x bilinear
  // upsampling (align_corners), out_conv.
  at::Tensor forward(const at::Tensor& x0, const at::Tensor& x1 = at::Tensor());
  torch::nn::Conv2d out_conv{nullptr};
  ResidualConvUnit resConfUnit1{nullptr}, resConfUnit2{nullptr};
};
TORCH_MODULE(FeatureFusionBlock);

// `scratch`: layer{1..4}_rn convs, also registered as layer_rn.{0..3} (the
// same modules, as the official make_scratch does), and refinenet1..4.
class ScratchImpl : public torch::nn::Module {
 public:
  ScratchImpl(const std::vector<int64_t>& layer_dims, int64_t features);
  std::vector<torch::nn::Conv2d> layer_rn_convs;  // layer{1..4}_rn
  torch::nn::ModuleList layer_rn{nullptr};
  std::vector<FeatureFusionBlock> refinenet;  // refinenet[i] = refinenet{i+1}
};
TORCH_MODULE(Scratch);

class DptAdapterImpl : public torch::nn::Module {
 public:
  explicit DptAdapterImpl(const Dust3rConfig& config);
  // decout: the decoder outputs (index 0 = encoder output); returns the raw
  // [B, num_channels, H, W] map for an H x W image.
  at::Tensor forward(const std::vector<at::Tensor>& decout, int64_t H, int64_t W,
                     const Trace& trace);
  std::vector<int64_t> hooks;
  int64_t patch;
  torch::nn::ModuleList act_postprocess{nullptr};
  std::vector<torch::nn::Sequential> act_postprocess_seq;
  Scratch scratch{nullptr};
  torch::nn::Sequential head{nullptr};
};
TORCH_MODULE(DptAdapter);

// Point map and confidence of one head.
struct HeadOutput {
  at::Tensor pts3d;  // [B, H, W, 3]
  at::Tensor conf;   // [B, H, W]; undefined with ConfMode::kNone
};

// Official postprocess(): channel-last, depth_mode on xyz, conf_mode on the rest.
HeadOutput postprocess(const at::Tensor& raw, const Dust3rConfig& config);

// One downstream head, as the official head_factory builds it: DPT
// (`dpt.*`) or LinearPts3d (`proj`: a linear layer from each decoder token to
// its patch's p x p pixels of xyz (+ confidence), pixel-shuffled).
class PixelHeadImpl : public torch::nn::Module {
 public:
  explicit PixelHeadImpl(const Dust3rConfig& config);
  // Raw head output [B, channels, H, W] (before postprocess) from the decoder
  // outputs of an H x W image. Records the DPT intermediates and raw.
  at::Tensor forward(const std::vector<at::Tensor>& decout, int64_t H, int64_t W,
                     const Trace& trace);
  DptAdapter dpt{nullptr};          // head_type dpt
  torch::nn::Linear proj{nullptr};  // head_type linear
  int64_t patch = 16;
};
TORCH_MODULE(PixelHead);

// ---------------------------------------------------------------------------
// AsymmetricCroCo3DStereo.

// Decoder outputs of one branch, as the official _decoder returns them:
// [enc_out, block_0, ..., block_{D-2}, dec_norm(block_{D-1})].
using DecoderOutputs = std::vector<at::Tensor>;
// Patch grid (rows, columns).
using Grid = std::pair<int64_t, int64_t>;

class Dust3rNetImpl : public torch::nn::Module {
 public:
  // refined_branch false: `dec_blocks` (the refined branch, decoder 1) is
  // registered empty for a derived network to fill (LONG3R), and decode()
  // does not apply.
  explicit Dust3rNetImpl(const Dust3rConfig& config, bool refined_branch = true);

  const Dust3rConfig& config() const { return config_; }
  // Patch grid (rows, columns) of an H x W image; throws for sizes that are
  // not multiples of the patch size.
  Grid grid(int64_t H, int64_t W) const;
  RopeTable enc_rope(int64_t gh, int64_t gw, const at::Tensor& like) const;
  RopeTable dec_rope(int64_t gh, int64_t gw, const at::Tensor& like) const;

  // images [B, 3, H, W] -> enc_norm(blocks(patch_embed)) [B, N, C_e].
  // Records patch_embed, pos, enc_block{i}, enc_out.
  at::Tensor encode(const at::Tensor& images, const Trace& trace);

  // Two-branch decoder; each branch's tokens lie on their own patch grid
  // (RoPE positions). Records dec{1,2}.embed, dec{1,2}.block{i},
  // dec{1,2}.final under `trace`.
  std::pair<DecoderOutputs, DecoderOutputs> decode(const at::Tensor& f1, Grid grid1,
                                                   const at::Tensor& f2, Grid grid2,
                                                   const Trace& trace);

  // Cross-view completion, CroCo's pretext task (the pretraining DUSt3R
  // starts from): the encoder sees only the patches of `masked` [B, 3, H, W]
  // listed in `visible` (int64 [V], one set for the batch; the rest become
  // mask_token), the coarse branch (dec_blocks2) decodes all of its patches
  // cross-attending to the encoded `reference`, which it sees whole.
  // Returns dec_norm of the last layer, [B, N, C_d], N the patches of
  // `masked`; a pixel head on top predicts the hidden patches (training only).
  at::Tensor complete_view(const at::Tensor& masked, const at::Tensor& reference,
                           const at::Tensor& visible);

  // Head `which` (1 or 2) on an H x W image: DPT or linear + postprocess, with the
  // official transpose_to_landscape behaviour (portrait + landscape_only:
  // the head runs at H x W and the outputs are transposed to [B, W, H, .]).
  // Records act_postprocess{i}, layer_rn{i}, refinenet{n}, raw.
  HeadOutput head(int which, const DecoderOutputs& dec, int64_t H, int64_t W, const Trace& trace);

  at::Tensor mask_token;  // pre-training only; present in every checkpoint
  PatchEmbed patch_embed{nullptr};
  torch::nn::ModuleList enc_blocks{nullptr};
  LayerNorm enc_norm{nullptr};
  torch::nn::Linear decoder_embed{nullptr};
  torch::nn::ModuleList dec_blocks{nullptr};
  torch::nn::ModuleList dec_blocks2{nullptr};
  LayerNorm dec_norm{nullptr};
  PixelHead downstream_head1{nullptr};
  PixelHead downstream_head2{nullptr};
  std::vector<Block> enc;
  std::vector<DecoderBlock> dec1, dec2;
  Rope2D rope;

 private:
  // The encoder blocks and enc_norm on patch tokens `x`, with their RoPE
  // table (one row per token).
  at::Tensor encode_tokens(at::Tensor x, const RopeTable& rope, const Trace& trace);

  Dust3rConfig config_;
};
TORCH_MODULE(Dust3rNet);

// ---------------------------------------------------------------------------
// Spann3R: DUSt3R plus the memory key/value encoders.

class Spann3rNetImpl : public torch::nn::Module {
 public:
  // dust3r_refined_branch: see Dust3rNetImpl.
  explicit Spann3rNetImpl(const ModelConfig& config, bool dust3r_refined_branch = true);

  // attn_head_{num}(cat(feat, dec_last)) [B, N, C_m].
  at::Tensor feat_key(int num, const at::Tensor& feat, const at::Tensor& dec_last);
  // Value of the current frame: value_out(value_norm(value_encoder(x))) with x
  // = pos_patch_embed(pts3d as NCHW) (or dec_last when use_feat). pts3d is the
  // head-1 point map as returned (transposed for portrait inputs).
  at::Tensor cur_value(const at::Tensor& pts3d, const at::Tensor& dec_last, int64_t gh, int64_t gw);
  // norm_q, norm_k, norm_v for the memory read (referenced, not copied).
  GatingNorms gating_norms() const;

  Dust3rNet dust3r{nullptr};
  torch::nn::ModuleList value_encoder{nullptr};
  std::vector<Block> value_blocks;
  LayerNorm value_norm{nullptr};
  torch::nn::Linear value_out{nullptr};
  PatchEmbed pos_patch_embed{nullptr};  // null with use_feat
  LayerNorm norm_q{nullptr}, norm_k{nullptr}, norm_v{nullptr};
  torch::nn::Sequential attn_head_1{nullptr}, attn_head_2{nullptr};

 private:
  ModelConfig config_;
};
TORCH_MODULE(Spann3rNet);

// ---------------------------------------------------------------------------
// Shared by the streaming front-ends (Spann3rModel, Long3rModel).

// The frame size and batch of a stream: the first frame fixes them (H and W
// must be multiples of the patch size), every later one must match. Throws
// std::invalid_argument with messages that start with `who`.
struct StreamShape {
  int64_t H = 0, W = 0, batch = 0;
  void check(const at::Tensor& image, bool first_frame, const Dust3rNetImpl& net, const char* who);
  // Saved stream states (StreamingModel::stream_state): "height", "width",
  // "batch"; read() checks them against the net's patch grid and returns
  // the tokens per frame.
  void put(StateDict& state) const;
  int64_t read(const StateReader& state, const Dust3rNetImpl& net);
};

// The decoder layers a head reads (keep_head_layers) in a saved stream state:
// "<prefix>.layers" and "<prefix>.<i>" for each kept layer; read back as
// [batch, tokens, *] tensors converted to `options`.
void put_head_layers(StateDict& state, const std::string& prefix, const DecoderOutputs& layers);
DecoderOutputs read_head_layers(const StateReader& state, const std::string& prefix,
                                const Dust3rConfig& config, int64_t batch, int64_t tokens,
                                const at::TensorOptions& options);

// Releases the decoder layers the head does not read (DPT: config.dpt.hooks;
// linear: all but the last):
// what a later head call (flush) needs of a decoder branch.
void keep_head_layers(DecoderOutputs& dec, const Dust3rConfig& config);

using Clock = std::chrono::steady_clock;
double ms_since(Clock::time_point t0);

}  // namespace model
}  // namespace long3r

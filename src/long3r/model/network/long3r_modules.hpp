// torch::nn modules of the LONG3R network (private to long3r_network and its
// tests; includes torch/nn).
//
// Long3rNet is Spann3R's module tree (dust3r.*, value_encoder.*, attn_head_1/2,
// norm_q/k/v, ...) whose refined decoder branch `dust3r.dec_blocks` alternates
// pairwise blocks (odd layers i = 1, 3, ...: module index i-1 = 0, 2, ...) and
// memory blocks (even layers: module index 1, 3, ...). The coarse branch
// `dust3r.dec_blocks2` keeps DUSt3R's pairwise blocks. Layouts as in
// modules.hpp: tokens [B, N, C], point maps [B, H, W, 3].
#pragma once

#include <vector>

#include "long3r/model/network/modules.hpp"

namespace long3r {
namespace model {

// Cross-attention from C_d query tokens to C_m memory tokens: projq C_d -> C_d,
// projk / projv C_m -> C_d, proj C_d -> C_d; no RoPE (memory tokens have no
// grid position).
class MemoryCrossAttentionImpl : public torch::nn::Module {
 public:
  MemoryCrossAttentionImpl(int64_t dim, int64_t mem_dim, int64_t num_heads);
  // query [B, N, C_d], key/value [B, R, C_m], valid [B, R] bool or undefined
  // (all valid). Streams with no valid token get a zero output (the caller
  // drops their residual).
  at::Tensor forward(const at::Tensor& query, const at::Tensor& key, const at::Tensor& value,
                     const at::Tensor& valid);
  // forward() with the key/value projections already applied: key_proj =
  // projk(key), value_proj = projv(value), [B, R, C_d].
  at::Tensor forward_projected(const at::Tensor& query, const at::Tensor& key_proj,
                               const at::Tensor& value_proj, const at::Tensor& valid);
  torch::nn::Linear projq{nullptr}, projk{nullptr}, projv{nullptr}, proj{nullptr};
  int64_t num_heads;
};
TORCH_MODULE(MemoryCrossAttention);

// Memory block (spec step 4): x + attn(norm1(x)) with RoPE; then
// x + cross_attn(norm2(x), norm_mem_k(K_R), norm_mem_v(V_R)); then
// x + mlp(norm3(x)). The cross-attention residual is zero for a stream without
// relevant memory (R empty or all its entries invalid).
class MemoryBlockImpl : public torch::nn::Module {
 public:
  MemoryBlockImpl(int64_t dim, int64_t mem_dim, int64_t num_heads, int64_t mlp_hidden, double eps,
                  double mem_eps);
  // keys/values: [B, R, C_m] relevant memory (R may be 0, or undefined
  // tensors = no memory); valid: [B, R] bool or undefined.
  at::Tensor forward(const at::Tensor& x, const RopeTable& xrope, const at::Tensor& keys,
                     const at::Tensor& values, const at::Tensor& valid);
  // The memory side of the cross-attention, per token:
  // [projk(norm_mem_k(keys)), projv(norm_mem_v(values))] -> [B, N, 2 C_d].
  at::Tensor project_memory(const at::Tensor& keys, const at::Tensor& values);
  // forward() on memory already passed through project_memory().
  at::Tensor forward_projected(const at::Tensor& x, const RopeTable& xrope,
                               const at::Tensor& projected, const at::Tensor& valid);
  LayerNorm norm1{nullptr}, norm2{nullptr}, norm3{nullptr};
  LayerNorm norm_mem_k{nullptr}, norm_mem_v{nullptr};
  Attention attn{nullptr};
  MemoryCrossAttention cross_attn{nullptr};
  Mlp mlp{nullptr};

 private:
  at::Tensor finish(const at::Tensor& out, at::Tensor read, const at::Tensor& valid);
};
TORCH_MODULE(MemoryBlock);

// Relevant memory handed to the memory blocks.
struct RelevantMemory {
  at::Tensor keys;    // [B, R, C_m] (undefined: no memory)
  at::Tensor values;  // [B, R, C_m]
  at::Tensor valid;   // [B, R] bool; undefined = all valid
  // [B, R, memory_projection_dim()] from Long3rNet::project_memory of these
  // tokens; when defined the memory blocks read it and not keys/values.
  at::Tensor projected;
};

// Outputs of the joint decoder, in DUSt3R's DecoderOutputs layout
// ([input, block_1, ..., block_{B-1}, dec_norm(block_B)]).
struct JointDecoderOutputs {
  DecoderOutputs refined;  // x: frame t (input F^fuse_t)
  DecoderOutputs coarse;   // y: frame t+1 (input F^I_{t+1})
};

class Long3rNetImpl : public Spann3rNetImpl {
 public:
  explicit Long3rNetImpl(const ModelConfig& config);

  // Spec step 4: x_0 = decoder_embed(fused), y_0 = decoder_embed(next);
  // y_i = Coarse_i(y_{i-1}, x_{i-1}); x_i = Pair_i(x_{i-1}, y_{i-1}) (odd i) or
  // Mem_i(x_{i-1}, memory) (even i); dec_norm on both last layers.
  JointDecoderOutputs decode_joint(const at::Tensor& fused, const at::Tensor& next, Grid grid,
                                   const RelevantMemory& memory);

  // Every memory block's project_memory() of memory tokens keys/values
  // [B, N, C_m], concatenated in layer order -> [B, N, memory_projection_dim()].
  // Per token, so it can be computed once when a token is written.
  at::Tensor project_memory(const at::Tensor& keys, const at::Tensor& values);
  int64_t memory_projection_dim() const;

  // Refined-branch blocks by layer: pair[i] for odd layers, memory[i] for even
  // layers (index = layer - 1; the other entry is null).
  std::vector<DecoderBlock> refined_pair;
  std::vector<MemoryBlock> refined_memory;
};
TORCH_MODULE(Long3rNet);

}  // namespace model
}  // namespace long3r

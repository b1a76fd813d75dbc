// LONG3R modules; see long3r_modules.hpp.
#include "long3r/model/network/long3r_modules.hpp"

#include <ATen/ATen.h>

#include <cmath>
#include <limits>

namespace long3r {
namespace model {

MemoryCrossAttentionImpl::MemoryCrossAttentionImpl(int64_t dim, int64_t mem_dim, int64_t heads)
    : num_heads(heads) {
  projq = register_module("projq", torch::nn::Linear(dim, dim));
  projk = register_module("projk", torch::nn::Linear(mem_dim, dim));
  projv = register_module("projv", torch::nn::Linear(mem_dim, dim));
  proj = register_module("proj", torch::nn::Linear(dim, dim));
}

at::Tensor MemoryCrossAttentionImpl::forward(const at::Tensor& query, const at::Tensor& key,
                                             const at::Tensor& value, const at::Tensor& valid) {
  return forward_projected(query, projk(key), projv(value), valid);
}

at::Tensor MemoryCrossAttentionImpl::forward_projected(const at::Tensor& query,
                                                       const at::Tensor& key_proj,
                                                       const at::Tensor& value_proj,
                                                       const at::Tensor& valid) {
  const int64_t B = query.size(0), N = query.size(1), C = projq->weight.size(0);
  const int64_t R = key_proj.size(1), Dh = C / num_heads;
  TORCH_CHECK(
      key_proj.dim() == 3 && key_proj.size(2) == C && value_proj.sizes() == key_proj.sizes(),
      "memory cross-attention: projected key/value must be [B, R, ", C, "], got ", key_proj.sizes(),
      " and ", value_proj.sizes());
  const at::Tensor q = projq(query).view({B, N, num_heads, Dh}).permute({0, 2, 1, 3});
  const at::Tensor k = key_proj.reshape({B, R, num_heads, Dh}).permute({0, 2, 1, 3});
  const at::Tensor v = value_proj.reshape({B, R, num_heads, Dh}).permute({0, 2, 1, 3});
  at::Tensor out;
  if (!valid.defined()) {
    out = attend(q, k, v);
  } else {
    at::Tensor a = at::matmul(q, k.transpose(-2, -1)).mul(std::pow(static_cast<double>(Dh), -0.5));
    // Finite fill: a stream whose entries are all masked gets a uniform (not
    // NaN) row, zeroed below, so gradients stay finite.
    // In float32 whatever the precision: the fill value and the softmax
    // statistics (no-ops in float32).
    const at::Tensor masked = valid.logical_not().view({B, 1, 1, R});
    a = a.to(at::kFloat).masked_fill(masked, std::numeric_limits<float>::lowest());
    a = at::softmax(a, -1).masked_fill(masked, 0.0);
    out = at::matmul(a.to(v.scalar_type()), v);
  }
  return proj(out.transpose(1, 2).reshape({B, N, C}));
}

MemoryBlockImpl::MemoryBlockImpl(int64_t dim, int64_t mem_dim, int64_t heads, int64_t mlp_hidden,
                                 double eps, double mem_eps) {
  norm1 = register_module("norm1", layer_norm(dim, eps));
  attn = register_module("attn", Attention(dim, heads, /*qkv_bias=*/true));
  norm2 = register_module("norm2", layer_norm(dim, eps));
  norm_mem_k = register_module("norm_mem_k", layer_norm(mem_dim, mem_eps));
  norm_mem_v = register_module("norm_mem_v", layer_norm(mem_dim, mem_eps));
  cross_attn = register_module("cross_attn", MemoryCrossAttention(dim, mem_dim, heads));
  norm3 = register_module("norm3", layer_norm(dim, eps));
  mlp = register_module("mlp", Mlp(dim, mlp_hidden));
}

at::Tensor MemoryBlockImpl::forward(const at::Tensor& x, const RopeTable& xrope,
                                    const at::Tensor& keys, const at::Tensor& values,
                                    const at::Tensor& valid) {
  const at::Tensor out = x + attn(norm1(x), xrope);
  at::Tensor r;
  if (keys.defined() && keys.size(1) > 0) {
    r = cross_attn(norm2(out), norm_mem_k(keys), norm_mem_v(values), valid);
  }
  return finish(out, r, valid);
}

at::Tensor MemoryBlockImpl::project_memory(const at::Tensor& keys, const at::Tensor& values) {
  return at::cat({cross_attn->projk(norm_mem_k(keys)), cross_attn->projv(norm_mem_v(values))}, -1);
}

at::Tensor MemoryBlockImpl::forward_projected(const at::Tensor& x, const RopeTable& xrope,
                                              const at::Tensor& projected,
                                              const at::Tensor& valid) {
  const at::Tensor out = x + attn(norm1(x), xrope);
  at::Tensor r;
  if (projected.defined() && projected.size(1) > 0) {
    const int64_t C = cross_attn->projq->weight.size(0);
    TORCH_CHECK(projected.dim() == 3 && projected.size(2) == 2 * C,
                "memory block: projected memory must be [B, R, ", 2 * C, "], got ",
                projected.sizes());
    r = cross_attn->forward_projected(norm2(out), projected.narrow(2, 0, C),
                                      projected.narrow(2, C, C), valid);
  }
  return finish(out, r, valid);
}

at::Tensor MemoryBlockImpl::finish(const at::Tensor& out, at::Tensor read,
                                   const at::Tensor& valid) {
  at::Tensor y = out;
  if (read.defined()) {
    // Without relevant memory the block reads nothing (proj's bias included).
    if (valid.defined()) read = read * valid.any(1).to(read.scalar_type()).view({-1, 1, 1});
    y = y + read;
  }
  return y + mlp(norm3(y));
}

Long3rNetImpl::Long3rNetImpl(const ModelConfig& c)
    : Spann3rNetImpl(c, /*dust3r_refined_branch=*/false) {
  const Dust3rConfig& d = c.dust3r;
  // The refined branch, in DUSt3R's (empty) `dec_blocks` list: pairwise blocks
  // at odd layers, memory blocks at even layers.
  refined_pair.assign(static_cast<std::size_t>(d.dec_depth), DecoderBlock(nullptr));
  refined_memory.assign(static_cast<std::size_t>(d.dec_depth), MemoryBlock(nullptr));
  for (int64_t i = 0; i < d.dec_depth; ++i) {
    const bool memory_layer = (i + 1) % 2 == 0;
    if (memory_layer) {
      refined_memory[i] = MemoryBlock(d.dec_embed_dim, c.memory_dim(), d.dec_num_heads,
                                      d.mlp_hidden(d.dec_embed_dim), d.norm_eps, d.norm_eps);
      dust3r->dec_blocks->push_back(refined_memory[i]);
    } else {
      refined_pair[i] = DecoderBlock(d.dec_embed_dim, d.dec_num_heads,
                                     d.mlp_hidden(d.dec_embed_dim), d.norm_eps, d.norm_im2_in_dec);
      dust3r->dec_blocks->push_back(refined_pair[i]);
    }
  }
}

JointDecoderOutputs Long3rNetImpl::decode_joint(const at::Tensor& fused, const at::Tensor& next,
                                                Grid grid, const RelevantMemory& memory) {
  Dust3rNetImpl& net = *dust3r;
  TORCH_CHECK(fused.dim() == 3 && next.sizes() == fused.sizes() &&
                  fused.size(1) == grid.first * grid.second,
              "LONG3R decoder: expected two [B, N, C] token sets on the patch grid, got ",
              fused.sizes(), " and ", next.sizes());
  const RopeTable r = net.dec_rope(grid.first, grid.second, fused);
  JointDecoderOutputs out;
  out.refined = {fused};
  out.coarse = {next};
  const std::size_t depth = refined_pair.size();
  int64_t memory_layers = 0, memory_layer = 0;
  for (const MemoryBlock& m : refined_memory) memory_layers += m.is_empty() ? 0 : 1;
  if (memory.projected.defined()) {
    TORCH_CHECK(memory.projected.dim() == 3 && memory.projected.size(2) == memory_projection_dim(),
                "LONG3R decoder: projected memory must be [B, R, ", memory_projection_dim(),
                "], got ", memory.projected.sizes());
  }
  at::Tensor x = net.decoder_embed(fused), y = net.decoder_embed(next);
  for (std::size_t i = 0; i < depth; ++i) {
    at::Tensor ny = net.dec2[i](y, x, r, r);
    at::Tensor nx;
    if (!refined_pair[i].is_empty()) {
      nx = refined_pair[i](x, y, r, r);
    } else if (memory.projected.defined()) {
      const int64_t width = memory.projected.size(2) / memory_layers;
      nx = refined_memory[i]->forward_projected(
          x, r, memory.projected.narrow(2, width * memory_layer, width), memory.valid);
      ++memory_layer;
    } else {
      nx = refined_memory[i](x, r, memory.keys, memory.values, memory.valid);
    }
    x = std::move(nx);
    y = std::move(ny);
    if (i + 1 < depth) {
      out.refined.push_back(x);
      out.coarse.push_back(y);
    }
  }
  out.refined.push_back(net.dec_norm(x));
  out.coarse.push_back(net.dec_norm(y));
  return out;
}

at::Tensor Long3rNetImpl::project_memory(const at::Tensor& keys, const at::Tensor& values) {
  std::vector<at::Tensor> parts;
  for (MemoryBlock& m : refined_memory) {
    if (!m.is_empty()) parts.push_back(m->project_memory(keys, values));
  }
  return at::cat(parts, -1);
}

int64_t Long3rNetImpl::memory_projection_dim() const {
  int64_t dim = 0;
  for (const MemoryBlock& m : refined_memory) {
    if (!m.is_empty()) dim += 2 * m->cross_attn->projq->weight.size(0);
  }
  return dim;
}

}  // namespace model
}  // namespace long3r

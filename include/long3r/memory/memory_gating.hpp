// LONG3R attention-based memory gating (paper 3.2, spec "One step of the
// stream", item 3).
//
// The query tokens of the current frame attend to every memory token; the
// attention weights W decide which memory tokens are relevant for the refined
// decoder (R), give the residual read-out F^fuse that starts the refined branch,
// and the per-token increment of the memory's cumulative attention.
//
// All tensors are batched: B independent streams. A memory whose streams hold
// different numbers of tokens is passed padded to a common length S with a
// validity mask (see SpatioTemporalMemory::valid_mask()). Works with autograd
// and under c10::InferenceMode; it never switches modes itself.
#pragma once

#include <ATen/core/Tensor.h>

#include <optional>

namespace long3r {

// Parameters of one LayerNorm over the last dimension (PyTorch nn.LayerNorm).
// weight/bias may be undefined (no affine part).
struct LayerNormParams {
  at::Tensor weight;  // [C]
  at::Tensor bias;    // [C]
  double eps = 1e-5;  // nn.LayerNorm's default, which Spann3R's norm_q/k/v use
};

// nn.LayerNorm over the last dimension, in any precision; the one layer norm
// of every model (model::LayerNorm calls it). The output has x's dtype except
// under autocast (below).
// - x follows the weights' dtype when they differ: under CPU autocast
//   (mixed-precision training) a bfloat16 activation meets float32 weights,
//   which libtorch 1.13's CPU layer norm refuses; the norm then runs, and
//   returns, float32, as CUDA autocast runs layer norms.
// - bfloat16 on the CPU is computed in float32 and rounded back: libtorch
//   1.13's bfloat16 CPU layer norm is about 11x slower than that and less
//   accurate (scripts/bench_cpu_kernels.py, docs/performance.md).
at::Tensor apply_layer_norm(const at::Tensor& x, const LayerNormParams& p);

// norm_q, norm_k, norm_v of the model (width C_m).
struct GatingNorms {
  LayerNormParams q;
  LayerNormParams k;
  LayerNormParams v;
};

// The thresholded attention read both memories make (Spann3rMemory::read and
// memory_gating). B streams, P queries, S memory tokens, C channels.
struct GatedRead {
  // W = softmax(norm_q(q) norm_k(K)^T / sqrt(C)) over the valid tokens; exactly
  // 0 at invalid ones. [B, P, S]
  at::Tensor weights;
  // W' = W with entries < threshold set to 0 and each row renormalised to sum 1;
  // a row whose entries all fall below the threshold stays all-zero (that query
  // reads nothing). Without a threshold W' = W. [B, P, S]
  at::Tensor gated_weights;
  // Rows left all-zero by the threshold: [B, P, 1] bool; undefined without one.
  at::Tensor empty_rows;
  // W' norm_v(V) (no residual). [B, P, C]
  at::Tensor readout;
};

// queries [B, P, C], keys and values [B, S, C] (the norms are applied here);
// valid: optional [B, S] bool, false at padded memory tokens. S may be 0. The
// scale 1 / sqrt(C) is taken in float, as the official Spann3R code does.
GatedRead gated_read(const at::Tensor& queries, const at::Tensor& keys, const at::Tensor& values,
                     const GatingNorms& norms, std::optional<double> threshold,
                     const at::Tensor& valid = at::Tensor());

// Result of memory_gating(). B streams, P query tokens, S memory tokens (padded
// length), C channels, R = max relevant-set size over the batch.
struct GatingResult {
  // W = softmax(norm_q(q) norm_k(K)^T / sqrt(C)) over the valid memory tokens;
  // exactly 0 at padded tokens. [B, P, S]
  at::Tensor weights;
  // R as a mask: relevant[b, s] = max_p W[b, p, s] > tau (inference), or
  // = valid[b, s] (training). Padded tokens are never relevant. [B, S] bool
  at::Tensor relevant_mask;
  // R as indices into the memory, ascending, left-aligned and padded to R
  // columns with index 0 (always in range, but meaningless: mask it with
  // relevant_valid). For B = 1 there is no padding. [B, R] int64
  at::Tensor relevant_index;
  // relevant_valid[b, r] = r < |R_b|; use as the key-padding mask of the
  // MemoryBlock's cross-attention. [B, R] bool
  at::Tensor relevant_valid;
  // Number of relevant tokens per stream, |R_b|. [B] int64
  at::Tensor relevant_count;
  // W' = W with entries < tau set to 0 and each row renormalised to sum 1
  // (inference). A row whose entries all fall below tau stays all-zero: that
  // query token reads nothing from memory. Training: W' = W. [B, P, S]
  at::Tensor gated_weights;
  // F^fuse = F^I + W' norm_v(V). [B, P, C]
  at::Tensor fused;
  // Cumulative-attention increment sum_p W'[b, p, s]; 0 at padded tokens.
  // Same token order as the memory passed in. [B, S]
  at::Tensor attention_increment;
};

// Memory gating and read-out.
//   queries   q = attn_head_2(cat(F^I_t, F^c_t))   [B, P, C]  (norm_q applied here)
//   keys      memory keys K                          [B, S, C]  (norm_k applied here)
//   values    memory values V                        [B, S, C]  (norm_v applied here)
//   features  F^I_t, the residual of the read-out    [B, P, C]
//   tau       relevance threshold (5e-4 in the paper); inference only
//   training  true: threshold 0 with no renormalisation (as Spann3R trains), every
//             valid token relevant, nothing detached
//   valid     optional [B, S] bool, false at padded memory tokens; undefined = all
//             valid
// S may be 0 (empty memory): then fused = features and R is empty.
// Note: an entry exactly equal to tau survives in W' while its token is in R only
// if some entry of its column is strictly above tau (the paper's two rules).
GatingResult memory_gating(const at::Tensor& queries, const at::Tensor& keys,
                           const at::Tensor& values, const at::Tensor& features,
                           const GatingNorms& norms, double tau, bool training,
                           const at::Tensor& valid = at::Tensor());

// Gathers tokens by a [B, R] index: x [B, S, D] -> [B, R, D] (differentiable in x).
// Use with GatingResult::relevant_index to form K_R and V_R.
at::Tensor gather_tokens(const at::Tensor& x, const at::Tensor& index);

}  // namespace long3r

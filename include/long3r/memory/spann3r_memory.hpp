// Spann3R's spatial memory (SpatialMemory of the official Spann3R code), used by
// the Spann3R mode of the engine (spec "Spann3R mode").
//
// The memory holds keys K and values V of past frames ([B, M, C], M = memory
// tokens, P tokens per frame) plus two per-token counters:
//   mem_attn   cumulative attention: every read adds, per memory token, the sum
//              over the query tokens of the thresholded, renormalised weights W';
//   mem_count  number of frames added after the token (0 for the newest frame).
// The newest `work_mem_size` added frames form the working memory; tokens beyond
// it count towards the long memory, which is pruned to the top_k tokens by
// mem_attn / mem_count (the working memory and the tokens added fewer than
// work_mem_size + 5 frames ago are always kept) once it exceeds long_mem_size.
// A new frame is not added at all when its key is too similar to a working-memory
// frame (mean cosine similarity over the P tokens > sim_thresh).
//
// All tensors are batched ([B, ...], B >= 1 independent streams). As in the
// official code, the similarity skip is decided once for the whole batch (the
// maximum over streams), so all streams always hold the same number of tokens.
// Tensors live on the device and in the dtype of the first key added; the
// norm parameters must be on the same device. The class never switches autograd
// modes; inference code runs it under c10::InferenceMode. Not thread-safe.
#pragma once

#include <ATen/core/Tensor.h>

#include <cstdint>

#include "long3r/memory/memory_config.hpp"  // Spann3rMemoryConfig
#include "long3r/memory/memory_gating.hpp"  // LayerNormParams, GatingNorms

namespace long3r {

// Per-read details, for diagnostics and parity checks. Counts are over the
// whole batch; they stay on the model's device as 0-dim int64 tensors (no
// host sync inside the step) until read through the accessors, and are
// undefined (read as 0) when the read does not threshold.
struct Spann3rReadStats {
  int64_t memory_tokens = 0;  // M at the read
  // Softmax weights strictly below attn_thresh, set to 0 (over B x P x M).
  at::Tensor zeroed_count;
  // Query rows whose weights were all below attn_thresh. The official code
  // divides 0 by 0 there (NaN); this class leaves such a row at 0 (the query
  // reads nothing), the only place where it departs from the official numbers.
  at::Tensor empty_row_count;
  int64_t n_zeroed() const;
  int64_t n_empty_rows() const;
  // softmax(norm_q(q) norm_k(K)^T / sqrt(C)) before thresholding, [B, P, M];
  // only defined when read() was asked to keep it.
  at::Tensor attention;
  // What the read added to mem_attn, sum_p W'[b, p, m]: [B, M] (memory order at
  // the read).
  at::Tensor attention_increment;
};

// What the last add_mem_check() did.
struct Spann3rAddStats {
  // The similarity check ran (memory non-empty and sim_thresh != 1).
  bool checked = false;
  // max over batch and working-memory frames of the mean over the P tokens of
  // the cosine similarity between the new key and the frame's key; NaN if not
  // checked.
  double similarity = 0.0;
  bool skipped = false;  // similarity > sim_thresh: nothing was added
  bool pruned = false;
  int64_t tokens_before_prune = 0;  // M just before the prune (if pruned)
  // Indices into the memory before the prune, in the order torch::topk returns
  // them (descending score), which is the new memory order: [B, top_k] int64.
  // Undefined unless pruned.
  at::Tensor kept_indices;
};

// A snapshot of the memory. Tensors are shared, not copied; the memory never
// modifies its tensors in place, so a snapshot stays valid.
struct Spann3rMemoryState {
  at::Tensor keys;               // [B, M, C]
  at::Tensor values;             // [B, M, C]
  at::Tensor mem_attn;           // [B, M], dtype of the keys
  at::Tensor mem_count;          // [B, M], dtype of the keys (float, as officially)
  int64_t working_frames = 0;    // official `wm`
  int64_t long_mem_counter = 0;  // official `lm`
  int64_t num_patches = 0;       // P (0: not known yet)
};

class Spann3rMemory {
 public:
  // norms: the model's norm_q / norm_k / norm_v (parameters `norm_q.weight`,
  // `norm_q.bias`, ...; eps 1e-5, nn.LayerNorm's default). The tensors are
  // referenced, not copied, so later in-place updates of the model's parameters
  // are seen.
  Spann3rMemory(const GatingNorms& norms, const Spann3rMemoryConfig& config = {});

  // Memory read-out for query tokens q [B, P', C] (Spann3R: attn_head_2 of the
  // previous step's second view), gated_read() with threshold attn_thresh
  // (none when attn_thresh <= 0):
  //   out = W' norm_v(V) (+ q if residual)
  // and mem_attn += sum over queries of W'. Returns out [B, P', C]. Throws if the
  // memory is empty. keep_attention: keep W in last_read().attention.
  at::Tensor read(const at::Tensor& query, bool residual = true, bool keep_attention = false);

  // Spann3R's memory update for one frame (key = attn_head_1 output k, value =
  // value encoder output + k, both [B, P, C]): the similarity check, the append
  // (existing mem_count += 1, new tokens 0 with mem_attn 0), the working/long
  // memory bookkeeping and, when the long memory exceeds long_mem_size, the
  // prune. Returns true if the frame was added. Details in last_add().
  bool add_mem_check(const at::Tensor& key, const at::Tensor& value);

  // The plain append of the official add_mem (no similarity check, no working /
  // long memory bookkeeping, no prune): what Spann3R's training forward does.
  void add_mem(const at::Tensor& key, const at::Tensor& value);

  // Reorders / subsets every memory tensor by index [B, R] int64 (the gather a
  // prune does). Counters are left unchanged.
  void gather(const at::Tensor& index);

  // Forgets everything (config and norms are kept).
  void reset();

  // No tokens (also after long_mem_size = work_mem_size = 0 dropped them all).
  bool empty() const { return size() == 0; }
  int64_t batch_size() const { return keys_.defined() ? keys_.size(0) : 0; }
  int64_t size() const { return keys_.defined() ? keys_.size(1) : 0; }  // M
  int64_t channels() const { return keys_.defined() ? keys_.size(2) : 0; }
  int64_t num_patches() const { return num_patches_; }
  int64_t working_frames() const { return working_frames_; }
  int64_t long_mem_counter() const { return long_mem_counter_; }
  int64_t top_k() const;
  const Spann3rMemoryConfig& config() const { return config_; }

  // Undefined before the first add.
  const at::Tensor& keys() const { return keys_; }            // [B, M, C]
  const at::Tensor& values() const { return values_; }        // [B, M, C]
  const at::Tensor& mem_attn() const { return mem_attn_; }    // [B, M]
  const at::Tensor& mem_count() const { return mem_count_; }  // [B, M]

  const Spann3rReadStats& last_read() const { return last_read_; }
  const Spann3rAddStats& last_add() const { return last_add_; }

  Spann3rMemoryState state() const;
  // Replaces the memory by a snapshot (validated: consistent shapes, same
  // device). An undefined state.keys empties the memory.
  void set_state(const Spann3rMemoryState& state);

 private:
  void prune();

  GatingNorms norms_;
  Spann3rMemoryConfig config_;
  at::Tensor keys_, values_, mem_attn_, mem_count_;
  int64_t num_patches_ = 0;
  int64_t working_frames_ = 0;
  int64_t long_mem_counter_ = 0;
  Spann3rReadStats last_read_;
  Spann3rAddStats last_add_;
};

// Spann3R's similarity: max over b and over the frames t of
// mean_p cos(key[b, p], window[b, t*P + p]) for key [B, P, C] and window
// [B, T*P, C]; as a float (the dtype's precision).
double spann3r_similarity(const at::Tensor& key, const at::Tensor& window);

// Spann3R's prune score, attention per frame of age: attention / age, with the
// score of tokens whose age < protect_below replaced by 1e8 (none when
// protect_below <= 0). Element-wise on tensors of one shape, in their dtype.
at::Tensor spann3r_prune_score(const at::Tensor& attention, const at::Tensor& age,
                               int64_t protect_below);

// Spann3R's prune order: torch::topk (largest, sorted) over
// spann3r_prune_score(mem_attn, mem_count, work_mem_size + 5).
// mem_attn, mem_count [B, M]; returns [B, top_k] int64. Tokens tied at 1e8 come
// first in torch's (implementation-specific) order.
at::Tensor spann3r_prune_order(const at::Tensor& mem_attn, const at::Tensor& mem_count,
                               int64_t work_mem_size, int64_t top_k);

}  // namespace long3r

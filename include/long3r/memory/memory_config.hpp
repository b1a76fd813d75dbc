// Settings of the two memories, torch-free: Spann3R's spatial memory
// (Spann3rMemory, JSON section "spatial_memory" of a Spann3R model) and
// LONG3R's 3D spatio-temporal memory (SpatioTemporalMemory, section "long3r").
// The model configuration embeds these structs; each lists its fields once
// (visit_fields, see include/long3r/config/config_json.hpp) and checks itself
// (validate).
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <utility>

#include "long3r/config/config_fields.hpp"

namespace long3r {

struct Spann3rMemoryConfig {
  // The official SpatialMemory defaults (long_mem_size 4000, work_mem_size 5,
  // attn_thresh 5e-4, sim_thresh 0.95) are what Spann3R's eval-mode forward uses.
  // long_mem_size is compared with the long-memory token counter (tokens beyond
  // the working memory), so it is a number of tokens, not of frames.
  int64_t long_mem_size = 4000;
  // Tokens kept by a prune; 0 means long_mem_size (the official choice). A JSON
  // config without "top_k" takes its long_mem_size.
  int64_t top_k = 0;
  // Frames in the working memory; also the similarity window and, plus 5, the
  // age (in frames) below which a token is protected from pruning.
  int64_t work_mem_size = 5;
  // Softmax weights below this are zeroed and rows renormalised; 0 disables
  // the thresholding (Spann3R's training mode uses 0).
  double attn_thresh = 5e-4;
  // A frame whose max mean cosine similarity to a working-memory frame is
  // > sim_thresh is not added; exactly 1.0 disables the check (as officially).
  double sim_thresh = 0.95;
  // Tokens per frame P; 0 takes it from the first key added (the official
  // forward leaves it unset too).
  int64_t num_patches = 0;

  // Throws ConfigError naming the field ("<check.what>: <check.path>.top_k: ...").
  void validate(const config::FieldCheck& check) const;
};

template <class S, class V>
config::FieldsOf<S, Spann3rMemoryConfig> visit_fields(S& s, V& v) {
  v("long_mem_size", s.long_mem_size);
  v.derive(s.top_k, s.long_mem_size);
  v("top_k", s.top_k);
  v("work_mem_size", s.work_mem_size);
  v("attn_thresh", s.attn_thresh);
  v("sim_thresh", s.sim_thresh);
  v("num_patches", s.num_patches);
  v.reject("mem_dropout", "memory dropout is a training setting; must be null");
}

// Statistic of the per-token neighbour distances d_i that gives a frame's v_img.
enum class VoxelStatistic {
  kMin,         // min_i d_i (the paper)
  kPercentile,  // the given percentile of d_i, linear interpolation (numpy default)
};
inline const std::array<std::pair<VoxelStatistic, const char*>, 2>& enum_names(VoxelStatistic) {
  static const std::array<std::pair<VoxelStatistic, const char*>, 2> names{
      {{VoxelStatistic::kMin, "min"}, {VoxelStatistic::kPercentile, "percentile"}}};
  return names;
}

// How long-term memory is kept bounded.
enum class LongTermPolicy {
  kVoxel,    // the paper: one token per adaptive voxel, then the L most attended
  kSpann3r,  // ablation: Spann3R's rules instead (no voxels): the L tokens with the
             // highest cumulative attention per frame of age (a_s / age_s, age in
             // frames since the token's frame, >= 1; ties: newer), and a frame
             // whose keys are too similar to a short-term frame's is not added
};
inline const std::array<std::pair<LongTermPolicy, const char*>, 2>& enum_names(LongTermPolicy) {
  static const std::array<std::pair<LongTermPolicy, const char*>, 2> names{
      {{LongTermPolicy::kVoxel, "voxel"}, {LongTermPolicy::kSpann3r, "spann3r"}}};
  return names;
}

// LONG3R memory (spec "3D spatio-temporal memory"). The decoder layout is fixed
// by the spec: odd layers of the refined branch are pairwise blocks, even
// layers memory blocks.
struct SpatioTemporalMemoryConfig {
  int64_t short_term_frames = 10;     // K (0: every frame goes straight to long-term)
  int64_t long_term_capacity = 3000;  // L, in tokens
  double tau = 5e-4;                  // gating threshold used by read()
  VoxelStatistic voxel_statistic = VoxelStatistic::kMin;
  double voxel_percentile = 5.0;  // in [0, 100]; used with kPercentile only
  LongTermPolicy long_term_policy = LongTermPolicy::kVoxel;
  // kSpann3r only: a frame is skipped when the mean over its P tokens of the
  // cosine similarity between its key and a short-term frame's key exceeds
  // this for some short-term frame (max over the batch, as Spann3R). 1 = off.
  double sim_thresh = 0.95;

  void validate(const config::FieldCheck& check) const;
};

template <class S, class V>
config::FieldsOf<S, SpatioTemporalMemoryConfig> visit_fields(S& s, V& v) {
  v("short_term_frames", s.short_term_frames);
  v("long_term_capacity", s.long_term_capacity);
  v("tau", s.tau);
  v("voxel_statistic", s.voxel_statistic);
  v("voxel_percentile", s.voxel_percentile);
  v("long_term_policy", s.long_term_policy);
  v("sim_thresh", s.sim_thresh);
}

}  // namespace long3r

// Checks of the memory settings; see include/long3r/memory/memory_config.hpp.
#include "long3r/memory/memory_config.hpp"

namespace long3r {

void Spann3rMemoryConfig::validate(const config::FieldCheck& c) const {
  c.require(long_mem_size >= 0, "long_mem_size", "must not be negative");
  c.require(top_k >= 0, "top_k", "must not be negative (0: long_mem_size)");
  c.require(work_mem_size >= 1, "work_mem_size", "must be at least 1");
  c.require(attn_thresh >= 0 && attn_thresh < 1, "attn_thresh", "must lie in [0, 1)");
  c.require(sim_thresh > -1 && sim_thresh <= 1, "sim_thresh", "must lie in (-1, 1]");
  c.require(num_patches >= 0, "num_patches", "must not be negative");
}

void SpatioTemporalMemoryConfig::validate(const config::FieldCheck& c) const {
  c.require(short_term_frames >= 0, "short_term_frames", "must not be negative");
  c.require(long_term_capacity >= 0, "long_term_capacity", "must not be negative");
  c.require(tau >= 0 && tau < 1, "tau", "must lie in [0, 1)");
  c.require(voxel_percentile >= 0 && voxel_percentile <= 100, "voxel_percentile",
            "must lie in [0, 100]");
  c.require(sim_thresh > -1 && sim_thresh <= 1, "sim_thresh", "must be in (-1, 1]");
}

}  // namespace long3r

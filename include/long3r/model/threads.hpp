// CPU thread settings for inference.
//
// libtorch on Debian starts with one intra-op thread, and OpenBLAS (used by
// torch's CPU matmuls) reads its own thread count, not torch's. Call this once
// in the thread that runs the model.
#pragma once

namespace long3r {

struct ThreadConfig {
  int torch_threads = 0;  // intra-op threads; 0 = all hardware threads
  // 0 = leave OpenBLAS as the environment set it. 1 by default because
  // torch's OpenMP pool and OpenBLAS's own pthread pool both busy-wait
  // between calls: with both at the core count they fight over the cores, and
  // a 2-core machine measured 2 to 2.5x slower per frame (docs/performance.md).
  int openblas_threads = 1;
};

// Applies the config; returns the intra-op thread count now in effect.
int apply_thread_config(const ThreadConfig& config);

}  // namespace long3r

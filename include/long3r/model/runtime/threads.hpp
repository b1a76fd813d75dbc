// CPU thread settings for inference.
//
// libtorch on Debian starts with one intra-op thread, and OpenBLAS (used by
// torch's float32 CPU matmuls) reads its own thread count, not torch's. Call
// apply_thread_config once in the thread that runs the model.
#pragma once

#include <string>

#include "long3r/config/config_fields.hpp"

namespace long3r {

class CliOptions;

// How the OpenBLAS that torch loaded runs its threads (openblas_get_parallel).
enum class BlasThreading {
  kNotOpenblas,  // another BLAS, or none loaded
  kSequential,   // OpenBLAS built without threads
  kPthread,      // its own pool of pthreads (Debian's libopenblas0-pthread)
  kOpenmp,       // OpenMP, the pool torch uses too (Debian's libopenblas0-openmp)
};

BlasThreading loaded_blas_threading();
const char* blas_threading_name(BlasThreading threading);

struct ThreadConfig {
  // Sentinel of openblas_threads: chosen from the OpenBLAS build (below).
  static constexpr int kOpenblasThreadsAuto = -1;

  int torch_threads = 0;  // intra-op threads; 0 = all hardware threads
  // OpenBLAS threads. kOpenblasThreadsAuto (the default): the OpenMP build
  // shares torch's OpenMP pool, so it gets torch's thread count and float32
  // GEMMs use every core; the pthread build has its own pool, which
  // busy-waits against torch's between calls (a 2-core machine measured 2 to
  // 2.5x slower per frame with both at the core count, docs/performance.md),
  // so it gets 1. 0 leaves OPENBLAS_NUM_THREADS in charge; N > 0 sets N.
  int openblas_threads = kOpenblasThreadsAuto;
  // glibc malloc keeps freed memory for reuse: blocks up to 32 MiB (its
  // limit) come from the heap, which is not trimmed back to the system.
  // Otherwise every large tensor of every step (1.6 MB for a q/k of the
  // paper's encoder) is a fresh mapping whose pages fault in zeroed, one per
  // 4 KiB: on a VM that made the shipped model's float32 step up to 1.7x
  // slower end to end (docs/performance.md, "The host allocator"). The
  // process then holds its peak heap, which a steady stream reuses. false:
  // glibc's defaults. Process-wide, set once by apply_thread_config.
  bool reuse_freed_memory = true;

  // Throws ConfigError naming the field.
  void validate(const config::FieldCheck& check) const;
};

template <class S, class V>
config::FieldsOf<S, ThreadConfig> visit_fields(S& s, V& v) {
  v("torch_threads", s.torch_threads, "(all cores)");
  v("openblas_threads", s.openblas_threads);
  v("reuse_freed_memory", s.reuse_freed_memory);
}

// What apply_thread_config put in effect.
struct ThreadState {
  int torch_threads = 0;
  int openblas_threads = 0;  // 0: not set (no OpenBLAS, or left to the environment)
  BlasThreading blas = BlasThreading::kNotOpenblas;
  bool reuse_freed_memory = false;  // glibc accepted the settings
};

// Applies the config in the calling thread and returns what is now in effect.
ThreadState apply_thread_config(const ThreadConfig& config);

// --threads N (0 = all cores), --openblas-threads auto|N and
// --return-freed-memory, the same in every program that runs the model.
void add_thread_options(CliOptions& cli, ThreadConfig* config);

// "2 torch threads, OpenBLAS (OpenMP build) 2 threads, freed memory reused",
// for start-up logs.
std::string describe(const ThreadState& state);

}  // namespace long3r

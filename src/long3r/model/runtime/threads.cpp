#include "long3r/model/runtime/threads.hpp"

#include <ATen/Parallel.h>
#include <dlfcn.h>

#include <algorithm>
#include <string>
#include <thread>
#include <vector>

#if defined(__GLIBC__)
#include <malloc.h>
#endif

#include "long3r/config/cli_options.hpp"

namespace long3r {

void ThreadConfig::validate(const config::FieldCheck& check) const {
  check.require(torch_threads >= 0 && torch_threads <= 256, "torch_threads",
                "must be in [0, 256] (0 = all cores)");
  check.require(openblas_threads >= kOpenblasThreadsAuto && openblas_threads <= 256,
                "openblas_threads",
                "must be -1 (by the OpenBLAS build), 0 (leave as the environment set it) or in "
                "[1, 256]");
}

namespace {
// OpenBLAS is loaded by torch at run time (or not at all, with another BLAS),
// so look its functions up instead of linking against it.
template <class Fn>
Fn openblas_fn(const char* name) {
  return reinterpret_cast<Fn>(dlsym(RTLD_DEFAULT, name));
}
}  // namespace

BlasThreading loaded_blas_threading() {
  const auto get_parallel = openblas_fn<int (*)()>("openblas_get_parallel");
  if (get_parallel == nullptr) return BlasThreading::kNotOpenblas;
  switch (get_parallel()) {
    case 0:
      return BlasThreading::kSequential;
    case 1:
      return BlasThreading::kPthread;
    case 2:
      return BlasThreading::kOpenmp;
    default:
      return BlasThreading::kNotOpenblas;
  }
}

const char* blas_threading_name(BlasThreading threading) {
  switch (threading) {
    case BlasThreading::kSequential:
      return "OpenBLAS (sequential build)";
    case BlasThreading::kPthread:
      return "OpenBLAS (pthread build)";
    case BlasThreading::kOpenmp:
      return "OpenBLAS (OpenMP build)";
    case BlasThreading::kNotOpenblas:
      break;
  }
  return "no OpenBLAS";
}

ThreadState apply_thread_config(const ThreadConfig& config) {
  int n = config.torch_threads;
  if (n <= 0) n = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  at::set_num_threads(n);
  ThreadState state;
  state.torch_threads = at::get_num_threads();
  state.blas = loaded_blas_threading();
  int blas_threads = config.openblas_threads;
  if (blas_threads == ThreadConfig::kOpenblasThreadsAuto) {
    blas_threads = state.blas == BlasThreading::kOpenmp ? state.torch_threads : 1;
  }
  const auto set_threads = openblas_fn<void (*)(int)>("openblas_set_num_threads");
  if (blas_threads > 0 && set_threads != nullptr && state.blas != BlasThreading::kSequential) {
    set_threads(blas_threads);
    state.openblas_threads = blas_threads;
  }
#if defined(__GLIBC__)
  if (config.reuse_freed_memory) {
    constexpr int kMmapThresholdBytes = 32 << 20;  // glibc's maximum on 64-bit hosts
    constexpr int kTrimThresholdBytes = 1 << 30;   // in effect: never trimmed
    state.reuse_freed_memory = ::mallopt(M_MMAP_THRESHOLD, kMmapThresholdBytes) == 1 &&
                               ::mallopt(M_TRIM_THRESHOLD, kTrimThresholdBytes) == 1;
  }
#endif
  return state;
}

void add_thread_options(CliOptions& cli, ThreadConfig* config) {
  cli.option("--threads", "N", &config->torch_threads, "torch intra-op threads (0 = all cores)")
      .min(0);
  cli.custom(
         "--openblas-threads", {"N"},
         [config](const std::vector<std::string>& v) {
           if (v[0] == "auto") {
             config->openblas_threads = ThreadConfig::kOpenblasThreadsAuto;
             return;
           }
           const int n = parse_cli_value<int>("--openblas-threads", v[0]);
           if (n < 0) {
             throw UsageError("--openblas-threads: must be auto, 0 or a positive count (got " +
                              v[0] + ")");
           }
           config->openblas_threads = n;
         },
         "OpenBLAS threads: auto (torch's count with the OpenMP build of OpenBLAS, 1 with the "
         "pthread build), 0 (OPENBLAS_NUM_THREADS) or N")
      .shown_default(config->openblas_threads == ThreadConfig::kOpenblasThreadsAuto
                         ? "auto"
                         : std::to_string(config->openblas_threads));
  cli.flag("--return-freed-memory", &config->reuse_freed_memory,
           "leave glibc malloc's defaults: large tensors mapped afresh each step and freed "
           "memory returned to the system (slower; see docs/performance.md)",
           false);
}

std::string describe(const ThreadState& state) {
  std::string s =
      std::to_string(state.torch_threads) + " torch thread(s), " + blas_threading_name(state.blas);
  if (state.blas == BlasThreading::kPthread || state.blas == BlasThreading::kOpenmp) {
    s += state.openblas_threads > 0 ? " " + std::to_string(state.openblas_threads) + " thread(s)"
                                    : " threads from the environment";
  }
  return s + (state.reuse_freed_memory ? ", freed memory reused" : "");
}

}  // namespace long3r

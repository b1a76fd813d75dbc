#include "long3r/model/threads.hpp"

#include <ATen/Parallel.h>
#include <dlfcn.h>

#include <algorithm>
#include <thread>

namespace long3r {

namespace {
// OpenBLAS is loaded by torch at run time (or not at all, with another BLAS),
// so look its setter up instead of linking against it.
void set_openblas_threads(int n) {
  using SetFn = void (*)(int);
  auto fn = reinterpret_cast<SetFn>(dlsym(RTLD_DEFAULT, "openblas_set_num_threads"));
  if (fn != nullptr) fn(n);
}
}  // namespace

int apply_thread_config(const ThreadConfig& config) {
  int n = config.torch_threads;
  if (n <= 0) n = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  at::set_num_threads(n);
  if (config.openblas_threads > 0) set_openblas_threads(config.openblas_threads);
  return at::get_num_threads();
}

}  // namespace long3r

// Splits [0, n) into contiguous chunks run on std::threads (private helper of
// the evaluation code; results must not depend on the thread count).
#pragma once

#include <algorithm>
#include <thread>
#include <vector>

namespace long3r::detail {

template <typename Fn>
void parallel_for(size_t n, int threads, Fn&& fn) {
  const size_t t = static_cast<size_t>(std::max(1, threads));
  if (t == 1 || n < 1024) {
    fn(size_t{0}, n);
    return;
  }
  std::vector<std::thread> pool;
  const size_t chunk = (n + t - 1) / t;
  for (size_t b = 0; b < n; b += chunk) {
    pool.emplace_back([&fn, b, e = std::min(n, b + chunk)] { fn(b, e); });
  }
  for (auto& th : pool) th.join();
}

}  // namespace long3r::detail

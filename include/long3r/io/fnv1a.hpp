// FNV-1a, 64 bits: the fingerprints of weights and of training replicas.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>

namespace long3r {

struct Fnv1a {
  uint64_t h = 1469598103934665603ull;
  void add(const void* data, std::size_t n) {
    const auto* p = static_cast<const unsigned char*>(data);
    for (std::size_t i = 0; i < n; ++i) h = (h ^ p[i]) * 1099511628211ull;
  }
  // The string and its terminator, so that "ab" + "c" differs from "a" + "bc".
  void add(const std::string& s) { add(s.data(), s.size() + 1); }
};

}  // namespace long3r

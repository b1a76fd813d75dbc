// The libtorch side of InferenceConfig: checks that this machine can serve a
// device and precision request, before any weights are read, and says what to
// set instead when it cannot. Nothing falls back silently: a request for CUDA
// on a CPU-only libtorch, a missing GPU, float16 on the CPU, or bfloat16 on a
// CPU that only emulates it, is an error.
#pragma once

#include <c10/core/Device.h>
#include <c10/core/ScalarType.h>

#include <stdexcept>
#include <string>

#include "long3r/model/inference_config.hpp"

namespace long3r {

// The request cannot be served here; the message names what is missing.
class InferenceUnsupportedError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct InferenceTarget {
  at::Device device = at::kCPU;
  at::ScalarType dtype = at::kFloat;
};

at::ScalarType precision_dtype(Precision precision);

// Whether this CPU computes bfloat16 natively (x86: AVX512-BF16 or AMX-BF16);
// elsewhere oneDNN emulates it, slower than float32.
bool cpu_has_native_bfloat16();

// Validates the config and checks this machine; throws ConfigError for a
// malformed request and InferenceUnsupportedError for one this machine (or
// this libtorch build) cannot serve.
InferenceTarget resolve_inference_target(const InferenceConfig& config);

// "cpu float32", "cuda:0 bfloat16", for logs and reports.
std::string describe(const InferenceTarget& target);

}  // namespace long3r

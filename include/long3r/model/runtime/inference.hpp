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

#include "long3r/model/runtime/inference_config.hpp"

namespace long3r {

// The request cannot be served here; the message names what is missing.
class InferenceUnsupportedError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct InferenceTarget {
  at::Device device = at::kCPU;
  at::ScalarType dtype = at::kFloat;
  // Of the convolutions (InferenceConfig::conv_precision as this machine
  // serves it); the CPU's transposed convolutions are float32 whatever this says.
  at::ScalarType conv_dtype = at::kFloat;
};

at::ScalarType precision_dtype(Precision precision);

// Whether this CPU computes bfloat16 natively (x86: AVX512-BF16 or AMX-BF16);
// elsewhere oneDNN emulates it, slower than float32.
bool cpu_has_native_bfloat16();

// This machine's CPU for reports, so that every figure names what it was
// measured on: the model name, the x86 extensions that decide the speed of
// each precision (AVX2, AVX-512, AVX512-BF16, AMX), the vector ISA ATen's
// kernels dispatch to, and the ISA oneDNN (matrix products, convolutions)
// runs with, e.g. "AMD EPYC; avx2 avx512f avx512_bf16 (no amx_bf16); ATen
// AVX512; oneDNN 2.6.3 avx512_core_bf16".
std::string describe_cpu();

// Validates the config and checks this machine; throws ConfigError for a
// malformed request and InferenceUnsupportedError for one this machine (or
// this libtorch build) cannot serve.
InferenceTarget resolve_inference_target(const InferenceConfig& config);

// "cpu float32", "cuda:0 bfloat16", "cpu bfloat16 (convolutions float32)",
// for logs and reports.
std::string describe(const InferenceTarget& target);

}  // namespace long3r

// Device and precision checks; see include/long3r/model/inference.hpp.
#include "long3r/model/inference.hpp"

#include <ATen/Context.h>
#include <ATen/detail/CUDAHooksInterface.h>

#include <cctype>

#include "long3r/io/cli_options.hpp"

namespace long3r {

namespace {

bool is_digits(const std::string& s) {
  if (s.empty() || s.size() > 4) return false;
  for (const char c : s) {
    if (!std::isdigit(static_cast<unsigned char>(c))) return false;
  }
  return true;
}

}  // namespace

bool is_device_name(const std::string& name) {
  return name == "cpu" || name == "cuda" ||
         (name.rfind("cuda:", 0) == 0 && is_digits(name.substr(5)));
}

void InferenceConfig::validate(const config::FieldCheck& check) const {
  check.require(is_device_name(device), "device",
                "must be cpu, cuda or cuda:N, got \"" + device + "\"");
}

void add_inference_options(CliOptions& cli, InferenceConfig* config) {
  cli.option("--device", "DEV", &config->device, "cpu, cuda or cuda:N");
  cli.custom(
         "--precision", {"P"},
         [config](const std::vector<std::string>& v) {
           if (!config::enum_from_name(v[0], &config->precision)) {
             throw UsageError("must be float32, bfloat16 or float16 (got \"" + v[0] + "\")");
           }
         },
         "float32, bfloat16 or float16 (weights and activations)")
      .shown_default(config::enum_name(config->precision));
  cli.flag("--allow-emulated-precision", &config->allow_emulated_precision,
           "run bfloat16 on a CPU that only emulates it (slow; to measure accuracy)");
}

at::ScalarType precision_dtype(Precision precision) {
  switch (precision) {
    case Precision::kBFloat16:
      return at::kBFloat16;
    case Precision::kFloat16:
      return at::kHalf;
    case Precision::kFloat32:
      break;
  }
  return at::kFloat;
}

bool cpu_has_native_bfloat16() {
#if defined(__x86_64__) || defined(__i386__)
  __builtin_cpu_init();
  return __builtin_cpu_supports("avx512bf16") || __builtin_cpu_supports("amx-bf16");
#else
  return false;
#endif
}

InferenceTarget resolve_inference_target(const InferenceConfig& config) {
  config.validate({"inference config", ""});
  InferenceTarget target;
  target.device = at::Device(config.device);
  target.dtype = precision_dtype(config.precision);
  if (target.device.is_cuda()) {
    if (!at::hasCUDA()) {
      throw InferenceUnsupportedError(
          "device " + config.device +
          ": no CUDA device available (this libtorch is built without CUDA, as Debian's is, or "
          "no GPU or driver was found); set device to cpu, or build against a CUDA libtorch "
          "(-DTorch_DIR=..., docs/performance.md) on a machine with an NVIDIA GPU");
    }
    const int count = at::detail::getCUDAHooks().getNumGPUs();
    if (target.device.has_index() && target.device.index() >= count) {
      throw InferenceUnsupportedError("device " + config.device + ": this machine has " +
                                      std::to_string(count) + " CUDA device(s); use cuda:0 to " +
                                      "cuda:" + std::to_string(count - 1));
    }
    return target;
  }
  if (config.precision == Precision::kFloat16) {
    throw InferenceUnsupportedError(
        "precision float16 on the CPU: this libtorch has no float16 CPU kernels for the "
        "model's layers; use bfloat16 (fast on CPUs with AVX512-BF16 or AMX) or float32 on the "
        "CPU, or float16 on a CUDA device");
  }
  if (config.precision == Precision::kBFloat16 && !cpu_has_native_bfloat16() &&
      !config.allow_emulated_precision) {
    throw InferenceUnsupportedError(
        "precision bfloat16 on the CPU: this CPU has no native bfloat16 arithmetic "
        "(AVX512-BF16 or AMX-BF16), so it would be emulated, slower than float32; use float32, "
        "or set allow_emulated_precision (--allow-emulated-precision) to run it anyway, e.g. "
        "to measure its accuracy");
  }
  return target;
}

std::string describe(const InferenceTarget& target) {
  for (const auto& entry : enum_names(Precision{})) {
    if (precision_dtype(entry.first) == target.dtype)
      return target.device.str() + " " + entry.second;
  }
  return target.device.str() + " " + c10::toString(target.dtype);
}

}  // namespace long3r

// Device and precision checks; see include/long3r/model/runtime/inference.hpp.
#include "long3r/model/runtime/inference.hpp"

#include <ATen/Context.h>
#include <ATen/Version.h>
#include <ATen/detail/CUDAHooksInterface.h>
#include <dlfcn.h>

#include <cctype>
#include <fstream>
#include <set>
#include <sstream>

#include "long3r/config/cli_options.hpp"

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
  check.require(short_term_frames >= -1, "short_term_frames",
                "must be -1 (the checkpoint's) or >= 0");
  check.require(long_term_capacity >= -1, "long_term_capacity",
                "must be -1 (the checkpoint's) or >= 0");
}

void add_inference_options(CliOptions& cli, InferenceConfig* config) {
  cli.option("--device", "DEV", &config->device, "cpu, cuda or cuda:N");
  cli.option("--precision", "P", &config->precision,
             "float32, bfloat16 or float16 (weights and activations)");
  cli.flag("--allow-emulated-precision", &config->allow_emulated_precision,
           "run bfloat16 on a CPU that only emulates it (slow; to measure accuracy)");
  cli.option("--conv-precision", "P", &config->conv_precision,
             "convolutions of a bfloat16 / float16 model: auto (in that precision where the "
             "device computes it natively, else float32) or float32");
}

void add_memory_options(CliOptions& cli, InferenceConfig* config) {
  cli.option("--short-term-frames", "K", &config->short_term_frames,
             "a LONG3R model's short-term memory in frames, in place of the checkpoint's (-1)")
      .min(-1);
  cli.option("--long-term-capacity", "L", &config->long_term_capacity,
             "a LONG3R model's long-term memory in tokens, in place of the checkpoint's (-1; 0: "
             "none)")
      .min(-1);
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
  const bool reduced_convs = config.conv_precision == ConvPrecision::kAuto;
  target.conv_dtype = reduced_convs ? target.dtype : at::kFloat;
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
  if (!cpu_has_native_bfloat16()) target.conv_dtype = at::kFloat;  // emulated: 5 % off
  return target;
}

namespace {

// The first "model name" and the "flags" of /proc/cpuinfo.
std::pair<std::string, std::set<std::string>> read_cpuinfo() {
  std::ifstream in("/proc/cpuinfo");
  std::string line, model;
  std::set<std::string> flags;
  while (std::getline(in, line)) {
    const std::size_t colon = line.find(':');
    if (colon == std::string::npos) continue;
    std::string key = line.substr(0, colon);
    key.erase(key.find_last_not_of(" \t") + 1);
    const std::string value = colon + 2 <= line.size() ? line.substr(colon + 2) : "";
    if (key == "model name" && model.empty()) model = value;
    if (key == "flags" && flags.empty()) {
      std::istringstream words(value);
      for (std::string w; words >> w;) flags.insert(w);
    }
  }
  return {model.empty() ? "unknown CPU" : model, flags};
}

// oneDNN's own report of the ISA it runs with, read from the library libtorch
// loaded (no oneDNN headers needed); the names are oneDNN 2.x's.
std::string onednn_isa() {
  struct Version {
    int major, minor, patch;
    const char* hash;
    unsigned cpu_runtime, gpu_runtime;
  };
  using IsaFn = int (*)();
  using VersionFn = const Version* (*)();
  const auto isa_fn = reinterpret_cast<IsaFn>(::dlsym(RTLD_DEFAULT, "dnnl_get_effective_cpu_isa"));
  const auto version_fn = reinterpret_cast<VersionFn>(::dlsym(RTLD_DEFAULT, "dnnl_version"));
  if (isa_fn == nullptr || version_fn == nullptr) return "oneDNN not loaded";
  const Version* v = version_fn();
  const int isa = isa_fn();
  std::ostringstream out;
  out << "oneDNN " << v->major << "." << v->minor << "." << v->patch << " ";
  const std::pair<int, const char*> names[] = {{0x0, "all"},
                                               {0x1, "sse41"},
                                               {0x3, "avx"},
                                               {0x7, "avx2"},
                                               {0xf, "avx512_mic"},
                                               {0x1f, "avx512_mic_4ops"},
                                               {0x27, "avx512_core"},
                                               {0x67, "avx512_core_vnni"},
                                               {0xe7, "avx512_core_bf16"},
                                               {0x3e7, "avx512_core_amx"},
                                               {0x407, "avx2_vnni"}};
  const char* name = nullptr;
  if (v->major == 2) {
    for (const auto& n : names) {
      if (n.first == isa) name = n.second;
    }
  }
  if (name != nullptr) {
    out << name;
  } else {
    out << "ISA 0x" << std::hex << isa;
  }
  return out.str();
}

}  // namespace

std::string describe_cpu() {
  const auto [model, flags] = read_cpuinfo();
  std::string out = model + ";";
  std::string missing;
  for (const char* f : {"avx2", "avx512f", "avx512_bf16", "amx_bf16"}) {
    (flags.count(f) ? out : missing) += std::string(" ") + f;
  }
  if (!missing.empty()) out += " (no" + missing + ")";
  // ATen's own line: "CPU capability usage: AVX512".
  const std::string config = at::show_config();
  const std::string key = "CPU capability usage: ";
  const std::size_t at_key = config.find(key);
  std::string cap = "unknown";
  if (at_key != std::string::npos) {
    const std::size_t from = at_key + key.size();
    cap = config.substr(from, config.find('\n', from) - from);
  }
  return out + "; ATen " + cap + "; " + onednn_isa();
}

std::string describe(const InferenceTarget& target) {
  auto name = [](at::ScalarType dtype) -> std::string {
    for (const auto& entry : enum_names(Precision{})) {
      if (precision_dtype(entry.first) == dtype) return entry.second;
    }
    return c10::toString(dtype);
  };
  std::string out = target.device.str() + " " + name(target.dtype);
  if (target.conv_dtype != target.dtype) out += " (convolutions " + name(target.conv_dtype) + ")";
  return out;
}

}  // namespace long3r

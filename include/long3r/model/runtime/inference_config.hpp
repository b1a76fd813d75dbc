// Where and in which precision a model runs (torch-free, so the nodelet's
// parameters, the tools' flags and JSON all fill the same struct). The
// libtorch side, which checks that this machine can serve the request and
// converts a model, is include/long3r/model/runtime/inference.hpp.
#pragma once

#include <array>
#include <string>
#include <utility>

#include "long3r/config/config_fields.hpp"

namespace long3r {

class CliOptions;

// Storage and compute precision of the weights and activations. Layer norms,
// softmax statistics and the heads' postprocess stay float32 whatever is set
// (docs/performance.md, "Precision").
enum class Precision { kFloat32, kBFloat16, kFloat16 };
inline const std::array<std::pair<Precision, const char*>, 3>& enum_names(Precision) {
  static const std::array<std::pair<Precision, const char*>, 3> names{
      {{Precision::kFloat32, "float32"},
       {Precision::kBFloat16, "bfloat16"},
       {Precision::kFloat16, "float16"}}};
  return names;
}

// Precision of the convolutions (patch embeddings, DPT heads) of a model run
// in bfloat16 or float16. auto: the model's on CUDA and on a CPU with native
// bfloat16 (AVX512-BF16 or AMX), float32 on a CPU that only emulates it
// (libtorch 1.13's emulated bfloat16 convolution loses 5 %, a native one
// 0.3 %); float32: always float32. On the CPU the transposed convolutions
// (no bfloat16 kernel) and the bilinear upsampling (whose bfloat16 kernel
// misplaces samples) run in float32 either way (docs/performance.md).
enum class ConvPrecision { kAuto, kFloat32 };
inline const std::array<std::pair<ConvPrecision, const char*>, 2>& enum_names(ConvPrecision) {
  static const std::array<std::pair<ConvPrecision, const char*>, 2> names{
      {{ConvPrecision::kAuto, "auto"}, {ConvPrecision::kFloat32, "float32"}}};
  return names;
}

constexpr const char* kDefaultInferenceDevice = "cpu";

struct InferenceConfig {
  // "cpu", "cuda" (the current CUDA device) or "cuda:N".
  std::string device = kDefaultInferenceDevice;
  Precision precision = Precision::kFloat32;
  // bfloat16 on a CPU without native bfloat16 arithmetic (AVX512-BF16 or
  // AMX) is emulated: correct but slower than float32. Refused unless this is
  // set, e.g. to measure its accuracy on such a machine.
  bool allow_emulated_precision = false;
  ConvPrecision conv_precision = ConvPrecision::kAuto;
  // The memory a LONG3R model runs with, in place of the checkpoint's
  // (-1: the checkpoint's): K, the short-term frames, and L, the long-term
  // tokens (0: none). A model trained with K = 10 on strides of 2-16 frames
  // held 200 frames at stride 2 together only with K = 5 (docs/model_card.md,
  // "The depth response, and the short-term memory at inference").
  int short_term_frames = -1;
  int long_term_capacity = -1;

  // Syntax only (what any machine can check); whether this machine can serve
  // it is resolve_inference_target()'s job. Throws ConfigError naming the field.
  void validate(const config::FieldCheck& check) const;
};

// "cpu", "cuda" or "cuda:N" (N up to 4 digits).
bool is_device_name(const std::string& name);

template <class S, class V>
config::FieldsOf<S, InferenceConfig> visit_fields(S& s, V& v) {
  v("device", s.device);
  v("precision", s.precision);
  v("allow_emulated_precision", s.allow_emulated_precision);
  v("conv_precision", s.conv_precision);
  v("short_term_frames", s.short_term_frames);
  v("long_term_capacity", s.long_term_capacity);
}

// --device, --precision, --allow-emulated-precision and --conv-precision,
// written once for every tool that runs a model.
void add_inference_options(CliOptions& cli, InferenceConfig* config);
// --short-term-frames and --long-term-capacity, for the tools that build their
// model by make_streaming_model or apply_memory_overrides.
void add_memory_options(CliOptions& cli, InferenceConfig* config);

}  // namespace long3r

// Model configuration of the DUSt3R / Spann3R inference engine, parsed from the
// JSON a checkpoint stores in its safetensors `__metadata__["config"]`.
//
// Torch-free. Field names follow the official constructor arguments (see
// docs/checkpoints.md, "Model configuration"). Missing optional fields take the
// defaults of the official DUSt3R ViT-L / BaseDecoder DPT model (the network
// Spann3R is built on); unknown keys inside the known sections are errors, so a
// misspelt field is reported instead of silently defaulted.
#pragma once

#include <array>
#include <cstdint>
#include <limits>
#include <map>
#include <nlohmann/json_fwd.hpp>
#include <string>
#include <utility>
#include <vector>

#include "long3r/config/config_fields.hpp"
#include "long3r/memory/memory_config.hpp"

namespace long3r {

// Malformed or unsupported model configuration; the message names the field
// (e.g. "model config: dust3r.enc_num_heads: ...").
using ModelConfigError = ConfigError;

// kLong3r: Spann3R's encoders and memory key/value encoders with LONG3R's
// memory-gated joint decoder and 3D spatio-temporal memory.
enum class ModelKind { kDust3r, kSpann3r, kLong3r };
// Point-map regression (official reg_dense_depth): pts = xyz/|xyz| * f(|xyz|).
enum class DepthMode { kLinear, kSquare, kExp };
// Confidence (official reg_dense_conf): exp: vmin + min(exp(c), vmax - vmin);
// sigmoid: (vmax - vmin) * sigmoid(c) + vmin. kNone: the head has no
// confidence channel.
enum class ConfMode { kNone, kExp, kSigmoid };
// PatchEmbedDust3R, or ManyAR_PatchEmbed (same weights and, for landscape
// images, the same result; portrait images are refused with it).
enum class PatchEmbedKind { kDust3r, kManyAR };

// The official head_type: "dpt" (PixelwiseTaskWithDPT, the DUSt3R 512
// checkpoints) or "linear" (LinearPts3d, the DUSt3R 224 linear checkpoint):
// one linear layer per decoder token to its patch's p x p pixels.
enum class HeadType { kDpt, kLinear };
inline const std::array<std::pair<HeadType, const char*>, 2>& enum_names(HeadType) {
  static const std::array<std::pair<HeadType, const char*>, 2> names{
      {{HeadType::kDpt, "dpt"}, {HeadType::kLinear, "linear"}}};
  return names;
}

// DPT head (official PixelwiseTaskWithDPT + DPTOutputAdapter_fix).
struct DptHeadConfig {
  int64_t feature_dim = 256;                           // F: width of the fusion path
  int64_t last_dim = 128;                              // width before the last 1x1 conv
  std::vector<int64_t> layer_dims{96, 192, 384, 768};  // after act_postprocess
  std::vector<int64_t> hooks;       // decoder-output indices; default [0, B/2, 3B/4, B]
  std::vector<int64_t> dim_tokens;  // widths of the hooked tokens; default [C_e, C_d x3]
  int64_t num_channels = 4;         // 3 + (conf_mode != none)
};

// AsymmetricCroCo3DStereo: ViT encoder, two-branch decoder, two heads.
struct Dust3rConfig {
  int64_t patch_size = 16;
  int64_t enc_embed_dim = 1024;
  int64_t enc_depth = 24;
  int64_t enc_num_heads = 16;
  int64_t dec_embed_dim = 768;
  int64_t dec_depth = 12;
  int64_t dec_num_heads = 12;
  double mlp_ratio = 4.0;
  double norm_eps = 1e-6;  // every LayerNorm of encoder, decoder and heads
  bool norm_im2_in_dec = true;
  double rope_freq = 100.0;  // "RoPE100"
  DepthMode depth_mode = DepthMode::kExp;
  ConfMode conf_mode = ConfMode::kExp;
  double conf_vmin = 1.0;
  double conf_vmax = std::numeric_limits<double>::infinity();
  // Portrait inputs: the heads' output maps are transposed ([B, W, H, .]),
  // exactly as the official transpose_to_landscape wrapper does with
  // PatchEmbedDust3R.
  bool landscape_only = true;
  PatchEmbedKind patch_embed = PatchEmbedKind::kDust3r;
  std::vector<int64_t> img_size{512, 512};  // training size; informational (RoPE has no table)
  HeadType head_type = HeadType::kDpt;
  DptHeadConfig dpt;  // head_type dpt only

  int64_t mlp_hidden(int64_t dim) const { return static_cast<int64_t>(dim * mlp_ratio); }
};

// Spann3R's value encoder: blocks over pos_patch_embed(pointmap) (or over the
// decoder output when use_feat), then value_norm and value_out.
struct ValueEncoderConfig {
  int64_t depth = 6;
  int64_t embed_dim = 1024;
  int64_t num_heads = 16;
  double mlp_ratio = 4.0;
  bool qkv_bias = true;
  double norm_eps = 1e-6;
  int64_t out_dim = 1024;  // C_m
};

struct Spann3rConfig {
  bool use_feat = false;     // values from dec1[-1] instead of the pointmap
  bool mem_pos_enc = false;  // RoPE inside the value encoder
  ValueEncoderConfig value_encoder;
  double norm_qkv_eps = 1e-5;  // norm_q / norm_k / norm_v (nn.LayerNorm default)
};

struct ModelConfig {
  ModelKind kind = ModelKind::kDust3r;
  Dust3rConfig dust3r;
  Spann3rConfig spann3r;  // kSpann3r and kLong3r (memory encoders)
  // kSpann3r only (JSON "spatial_memory"). A model stores top_k resolved: the
  // official long_mem_size when the section does not give it.
  Spann3rMemoryConfig spatial_memory{/*long_mem_size=*/4000, /*top_k=*/4000};
  SpatioTemporalMemoryConfig long3r;  // kLong3r only (JSON "long3r")
  // The input size the weights were trained at and run at (JSON top-level
  // "input_width" / "input_height", written by the trainer); 0 when the file
  // does not say (official checkpoints: dust3r.img_size is their backbone's
  // pretraining size, not always the size they run at; Spann3R's says 512 and
  // runs at 224). Both or neither, multiples of the patch size.
  int64_t input_width = 0;
  int64_t input_height = 0;

  // Width of the memory tokens (C_m) of a Spann3R model.
  int64_t memory_dim() const { return spann3r.value_encoder.out_dim; }
};

// Parses and validates; throws ModelConfigError naming the field.
ModelConfig parse_model_config(const std::string& json_text);
ModelConfig parse_model_config(const nlohmann::ordered_json& config);

// The configuration a checkpoint stores as metadata "config"; `source` names
// the file in errors.
ModelConfig model_config_from_metadata(const std::map<std::string, std::string>& metadata,
                                       const std::string& source);

// Consistency checks (head counts divide widths, RoPE needs head dims that are
// multiples of 4, hooks within the decoder, DPT widths, Spann3R widths that
// must agree, ...). parse_model_config calls it; call it again after editing a
// config by hand.
void validate_model_config(const ModelConfig& config);

const char* model_kind_name(ModelKind kind);

// JSON text of a configuration, in the layout parse_model_config reads
// (parse_model_config(model_config_to_json(c)) gives c back); what a
// checkpoint stores as metadata "config".
std::string model_config_to_json(const ModelConfig& config);

// Built-in LONG3R configurations (kind kLong3r):
//   "long3r_paper": the paper's model: ViT-L encoder 1024 x 24 (16 heads),
//     decoder 768 x 12 (12 heads), value encoder 6 x 1024, C_m 1024, K 10,
//     L 3000, tau 5e-4, the official DPT widths.
//   "long3r_small": a CPU-sized model of the same structure (encoder 192 x 6
//     (3 heads), decoder 128 x 6 (4 heads), value encoder 2 x 192, C_m 192,
//     DPT 64/32 with layer widths 48..384, K 10, L 3000).
//   "long3r_ship": the model that ships with the package (encoder 128 x 4
//     (4 heads), decoder 96 x 4 (3 heads), value encoder 2 x 128, C_m 128,
//     DPT 48/24 with layer widths 24..192, K 10, L 1000): >= 5 FPS at
//     224 x 224 on two CPU cores.
//   "long3r_tiny": for tests (encoder 32 x 1, decoder 32 x 4, value encoder
//     1 x 32, DPT 16/8, K 2, L 64).
// Throws ModelConfigError for other names.
ModelConfig named_model_config(const std::string& name);

}  // namespace long3r

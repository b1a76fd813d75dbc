// Tests of the model configuration parser (include/long3r/model/network/model_config.hpp):
// the golden checkpoints' configs, defaults, and one error per rule.
#include <gtest/gtest.h>

#include <cmath>
#include <nlohmann/json.hpp>
#include <string>

#include "long3r/model/loading/safetensors.hpp"
#include "long3r/model/network/model_config.hpp"

namespace {

using long3r::ModelConfig;
using long3r::ModelConfigError;
using long3r::parse_model_config;
using Json = nlohmann::ordered_json;

const std::string kGolden = std::string(LONG3R_GOLDEN_DIR) + "/";

// A complete tiny Spann3R config (the golden land96x64 model's fields).
Json tiny_spann3r() {
  return Json::parse(R"json({
    "model": "Spann3R",
    "dust3r": {"output_mode": "pts3d", "head_type": "dpt",
               "depth_mode": ["exp", "-inf", "inf"], "conf_mode": ["exp", 1, "inf"],
               "freeze": "none", "landscape_only": true, "patch_embed_cls": "PatchEmbedDust3R",
               "img_size": [64, 96], "patch_size": 16,
               "enc_embed_dim": 32, "enc_depth": 3, "enc_num_heads": 2,
               "dec_embed_dim": 16, "dec_depth": 10, "dec_num_heads": 2,
               "mlp_ratio": 4, "norm_layer": "LayerNorm(eps=1e-6)", "norm_im2_in_dec": true,
               "pos_embed": "RoPE100", "mask_ratio": 0.9,
               "dpt_head": {"feature_dim": 12, "last_dim": 8, "layer_dims": [8, 12, 16, 16],
                            "hooks": [0, 5, 7, 10], "dim_tokens": [32, 16, 16, 16],
                            "num_channels": 4, "head_type": "regression",
                            "output_width_ratio": 1, "stride_level": 1, "patch_size": 16,
                            "use_bn": false, "note": "tiny"}},
    "spann3r": {"use_feat": false, "mem_pos_enc": false, "memory_dropout": 0.15,
                "value_encoder": {"depth": 2, "embed_dim": 32, "num_heads": 2, "mlp_ratio": 4,
                                  "qkv_bias": true, "norm_layer": "LayerNorm(eps=1e-6)",
                                  "rope": null, "out_dim": 32},
                "pos_patch_embed": "PatchEmbedDust3R", "norm_qkv": "LayerNorm(32) eps=1e-5",
                "attn_head": "Sequential(...)"},
    "spatial_memory": {"long_mem_size": 156, "top_k": 156, "work_mem_size": 1,
                       "attn_thresh": 0.0005, "sim_thresh": 0.95, "mem_dropout": null,
                       "num_patches": 24},
    "seed": 3252
  })json");
}

// Sets obj[path...] = v (objects only).
void set_path(Json& root, const std::vector<std::string>& path, Json v) {
  Json* cur = &root;
  for (std::size_t i = 0; i + 1 < path.size(); ++i) cur = &(*cur)[path[i]];
  (*cur)[path.back()] = std::move(v);
}

void erase_key(Json& obj, const std::string& key) { obj.erase(key); }

// The error message of parsing `cfg`, or "" if it parses.
std::string error_of(const Json& cfg) {
  try {
    parse_model_config(cfg);
  } catch (const ModelConfigError& e) {
    return e.what();
  }
  return "";
}

TEST(ModelConfig, GoldenCheckpointConfigs) {
  for (const char* c : {"dust3r_pair_sq224", "dust3r_pair_port80x112", "spann3r_seq_land96x64"}) {
    const std::string path = kGolden + c + "/weights.safetensors";
    const long3r::TensorFile f = long3r::load_safetensors(path);
    const ModelConfig cfg = long3r::model_config_from_metadata(f.metadata, path);
    EXPECT_EQ(cfg.dust3r.enc_embed_dim, 32);
    EXPECT_EQ(cfg.dust3r.dec_depth, 10);
    EXPECT_EQ(cfg.dust3r.dpt.hooks, (std::vector<int64_t>{0, 5, 7, 10}));
    EXPECT_EQ(cfg.dust3r.dpt.layer_dims, (std::vector<int64_t>{8, 12, 16, 16}));
    EXPECT_DOUBLE_EQ(cfg.dust3r.norm_eps, 1e-6);
    EXPECT_DOUBLE_EQ(cfg.dust3r.rope_freq, 100.0);
    EXPECT_TRUE(cfg.dust3r.landscape_only);
    EXPECT_EQ(cfg.dust3r.conf_mode, long3r::ConfMode::kExp);
    EXPECT_TRUE(std::isinf(cfg.dust3r.conf_vmax));
  }
  const std::string path = kGolden + "spann3r_seq_land96x64/weights.safetensors";
  const ModelConfig s =
      long3r::model_config_from_metadata(long3r::load_safetensors(path).metadata, path);
  EXPECT_EQ(s.kind, long3r::ModelKind::kSpann3r);
  EXPECT_EQ(s.spann3r.value_encoder.depth, 2);
  EXPECT_EQ(s.memory_dim(), 32);
  EXPECT_DOUBLE_EQ(s.spann3r.norm_qkv_eps, 1e-5);
  EXPECT_EQ(s.spatial_memory.long_mem_size, 156);
  EXPECT_EQ(s.spatial_memory.work_mem_size, 1);
  EXPECT_EQ(s.spatial_memory.num_patches, 24);
}

TEST(ModelConfig, MissingOptionalFieldsTakeDust3rDefaults) {
  const ModelConfig c = parse_model_config(std::string(R"({"dust3r": {}})"));
  EXPECT_EQ(c.kind, long3r::ModelKind::kDust3r);
  EXPECT_EQ(c.dust3r.enc_embed_dim, 1024);
  EXPECT_EQ(c.dust3r.enc_depth, 24);
  EXPECT_EQ(c.dust3r.dec_embed_dim, 768);
  EXPECT_EQ(c.dust3r.dec_depth, 12);
  EXPECT_EQ(c.dust3r.dpt.hooks, (std::vector<int64_t>{0, 6, 9, 12}));
  EXPECT_EQ(c.dust3r.dpt.dim_tokens, (std::vector<int64_t>{1024, 768, 768, 768}));
  EXPECT_EQ(c.dust3r.dpt.feature_dim, 256);
  EXPECT_EQ(c.dust3r.dpt.num_channels, 4);

  // Spann3R defaults follow the encoder width; hooks follow the decoder depth.
  const ModelConfig s = parse_model_config(std::string(
      R"({"model": "Spann3R", "dust3r": {"enc_embed_dim": 64, "enc_num_heads": 4,
          "dec_depth": 8}})"));
  EXPECT_EQ(s.spann3r.value_encoder.embed_dim, 64);
  EXPECT_EQ(s.spann3r.value_encoder.out_dim, 64);
  EXPECT_EQ(s.dust3r.dpt.hooks, (std::vector<int64_t>{0, 4, 6, 8}));
  EXPECT_EQ(s.spatial_memory.long_mem_size, 4000);
  EXPECT_EQ(s.spatial_memory.work_mem_size, 5);
}

TEST(ModelConfig, TinyConfigParses) {
  const ModelConfig c = parse_model_config(tiny_spann3r());
  EXPECT_EQ(c.dust3r.img_size, (std::vector<int64_t>{64, 96}));
  EXPECT_EQ(c.spatial_memory.top_k, 156);
}

struct BadCase {
  std::vector<std::string> path;
  const char* value_json;  // nullptr: erase the key
  const char* expected;    // substring of the message
};

TEST(ModelConfig, ErrorsNameTheField) {
  const std::vector<BadCase> cases = {
      {{"dust3r", "enc_num_heads"}, "3", "dust3r.enc_num_heads: must divide"},
      {{"dust3r", "dec_num_heads"}, "8", "head width divisible by 4"},
      {{"dust3r", "enc_embed_dim"}, "\"32\"", "dust3r.enc_embed_dim: expected an integer"},
      {{"dust3r", "enc_depth"}, "2.5", "dust3r.enc_depth: expected an integer"},
      {{"dust3r", "enc_depth"}, "0", "dust3r.enc_depth: must be at least 1"},
      {{"dust3r", "enc_embed_dims"}, "32", "unknown field(s) \"enc_embed_dims\""},
      {{"dust3r", "head_type"},
       "\"conv\"",
       "dust3r.head_type: must be \"dpt\" or \"linear\", got \"conv\""},
      // A linear head takes no DPT arguments: a dpt_head section is a mistake.
      {{"dust3r", "head_type"}, "\"linear\"", "unknown field(s) \"dpt_head\""},
      {{"dust3r", "pos_embed"}, "\"cosine\"", "only RoPE"},
      {{"dust3r", "patch_embed_cls"}, "\"Foo\"", "unknown class"},
      {{"dust3r", "norm_layer"}, "\"BatchNorm\"", "only LayerNorm"},
      {{"dust3r", "depth_mode"}, "[\"exp\", 0, \"inf\"]", "unbounded"},
      {{"dust3r", "depth_mode"}, "[\"log\", \"-inf\", \"inf\"]", "unknown mode \"log\""},
      {{"dust3r", "conf_mode"}, "[\"exp\", 1]", "expected [mode, vmin, vmax]"},
      {{"dust3r", "dpt_head", "hooks"}, "[0, 5, 7, 11]", "dust3r.dpt_head.hooks[3]: must lie"},
      {{"dust3r", "dpt_head", "hooks"}, "[0, 5, 7]", "needs 4 entries"},
      {{"dust3r", "dpt_head", "dim_tokens"},
       "[16, 16, 16, 16]",
       "dim_tokens[0]: must be the width"},
      {{"dust3r", "dpt_head", "num_channels"}, "3", "num_channels: must be 4"},
      {{"dust3r", "dpt_head", "use_bn"}, "true", "batch-norm"},
      {{"dust3r", "dpt_head", "output_width_ratio"}, "2", "only 1"},
      {{"spann3r", "value_encoder", "out_dim"}, "16", "value_encoder.out_dim: must equal"},
      {{"spann3r", "value_encoder", "embed_dim"}, "16", "value_encoder.embed_dim: must equal"},
      {{"spann3r", "value_encoder", "rope"}, "\"RoPE100\"", "mem_pos_enc"},
      {{"spann3r", "norm_qkv"}, "\"LayerNorm eps=abc\"", "cannot read a positive eps"},
      {{"spatial_memory", "work_mem_size"}, "0", "work_mem_size: must be at least 1"},
      {{"spatial_memory", "mem_dropout"}, "0.1", "training setting"},
      {{"model"}, "\"CroCoNet\"", "unknown model"},
      {{"input_width"}, "24", "input_width: must be a positive multiple of dust3r.patch_size (16)"},
      // Both sizes or neither.
      {{"input_width"}, "32", "input_height: must be a positive multiple"},
      {{"dust3r"}, nullptr, "dust3r: missing"},
  };
  for (const BadCase& c : cases) {
    Json cfg = tiny_spann3r();
    if (c.value_json == nullptr) {
      erase_key(cfg, c.path.back());
    } else {
      set_path(cfg, c.path, Json::parse(c.value_json));
    }
    const std::string msg = error_of(cfg);
    EXPECT_NE(msg.find(c.expected), std::string::npos)
        << "path " << c.path.back() << ": got \"" << msg << "\"";
  }
}

// The writer keeps the official encodings; memory settings are the memories'
// own structs, enums written by name.
TEST(ModelConfig, WritesTheOfficialEncodings) {
  ModelConfig c = parse_model_config(tiny_spann3r());
  const Json s = Json::parse(long3r::model_config_to_json(c));
  EXPECT_EQ(s.at("dust3r").at("norm_layer"), "LayerNorm(eps=1e-06)");
  EXPECT_EQ(s.at("dust3r").at("pos_embed"), "RoPE100.0");
  EXPECT_EQ(s.at("dust3r").at("depth_mode"), Json::parse(R"(["exp", "-inf", "inf"])"));
  EXPECT_EQ(s.at("dust3r").at("conf_mode"), Json::parse(R"(["exp", 1.0, "inf"])"));
  EXPECT_EQ(s.at("spann3r").at("norm_qkv"), "LayerNorm(eps=1e-05)");
  EXPECT_FALSE(s.at("spann3r").at("value_encoder").contains("rope"));
  EXPECT_EQ(s.at("spatial_memory").at("top_k"), 156);
  c.dust3r.conf_mode = long3r::ConfMode::kNone;
  c.dust3r.dpt.num_channels = 3;
  EXPECT_TRUE(Json::parse(long3r::model_config_to_json(c)).at("dust3r").at("conf_mode").is_null());

  // Without "top_k" a Spann3R model keeps long_mem_size tokens.
  Json cfg = tiny_spann3r();
  cfg["spatial_memory"].erase("top_k");
  EXPECT_EQ(parse_model_config(cfg).spatial_memory.top_k, 156);
  cfg["spatial_memory"]["top_k"] = 0;
  EXPECT_NE(error_of(cfg).find("spatial_memory.top_k: must be positive"), std::string::npos);

  ModelConfig l = long3r::named_model_config("long3r_tiny");
  l.long3r.voxel_statistic = long3r::VoxelStatistic::kPercentile;
  l.long3r.long_term_policy = long3r::LongTermPolicy::kSpann3r;
  const Json lj = Json::parse(long3r::model_config_to_json(l));
  EXPECT_EQ(lj.at("long3r").at("voxel_statistic"), "percentile");
  EXPECT_EQ(lj.at("long3r").at("long_term_policy"), "spann3r");
  EXPECT_EQ(parse_model_config(lj.dump()).long3r.long_term_policy,
            long3r::LongTermPolicy::kSpann3r);
  Json bad = lj;
  bad["long3r"]["long_term_policy"] = "lru";
  EXPECT_NE(error_of(bad).find("long3r.long_term_policy: must be \"voxel\" or \"spann3r\", got "
                               "\"lru\""),
            std::string::npos);
}

// The size a file was trained at is written only where it is known, so the
// files of official checkpoints read and write as before.
TEST(ModelConfig, InputSizeIsWrittenOnlyWhereRecorded) {
  ModelConfig c = parse_model_config(tiny_spann3r());
  EXPECT_EQ(c.input_width, 0);
  EXPECT_EQ(c.input_height, 0);
  EXPECT_FALSE(Json::parse(long3r::model_config_to_json(c)).contains("input_width"));
  c.input_width = 64;
  c.input_height = 48;
  const ModelConfig back = parse_model_config(long3r::model_config_to_json(c));
  EXPECT_EQ(back.input_width, 64);
  EXPECT_EQ(back.input_height, 48);
}

// DUSt3R's linear head (official head_type 'linear', LinearPts3d): no DPT
// section read or written, any patch size.
TEST(ModelConfig, LinearHead) {
  Json cfg = tiny_spann3r();
  cfg["dust3r"]["head_type"] = "linear";
  cfg["dust3r"]["patch_size"] = 8;
  cfg["dust3r"].erase("dpt_head");
  const ModelConfig c = parse_model_config(cfg);
  EXPECT_EQ(c.dust3r.head_type, long3r::HeadType::kLinear);
  EXPECT_EQ(c.dust3r.patch_size, 8);
  const Json written = Json::parse(long3r::model_config_to_json(c));
  EXPECT_EQ(written.at("dust3r").at("head_type"), "linear");
  EXPECT_FALSE(written.at("dust3r").contains("dpt_head"));
  EXPECT_EQ(parse_model_config(written.dump()).dust3r.head_type, long3r::HeadType::kLinear);
  // The DPT default stays what it was.
  EXPECT_EQ(parse_model_config(tiny_spann3r()).dust3r.head_type, long3r::HeadType::kDpt);
  EXPECT_EQ(Json::parse(long3r::model_config_to_json(parse_model_config(tiny_spann3r())))
                .at("dust3r")
                .at("head_type"),
            "dpt");
}

TEST(ModelConfig, BadJsonAndMissingMetadata) {
  EXPECT_THROW(parse_model_config(std::string("{\"dust3r\": {,}}")), ModelConfigError);
  EXPECT_THROW(parse_model_config(std::string("[]")), ModelConfigError);
  try {
    long3r::model_config_from_metadata({{"format", "pt"}}, "x.safetensors");
    FAIL() << "expected an error";
  } catch (const ModelConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("x.safetensors: no model configuration"),
              std::string::npos);
  }
}

}  // namespace

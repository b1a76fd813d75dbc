// Parsing and validation of the model configuration; see
// include/long3r/model/model_config.hpp.
#include "long3r/model/model_config.hpp"

#include <cmath>
#include <cstdlib>
#include <set>
#include <sstream>

#include "long3r/io/json.hpp"

namespace long3r {

namespace {

[[noreturn]] void fail(const std::string& path, const std::string& what) {
  throw ModelConfigError("model config: " + path + ": " + what);
}

std::string join(const std::string& path, const std::string& key) {
  return path.empty() ? key : path + "." + key;
}

// Member or nullptr (missing or null).
const json::Value* member(const json::Value& obj, const std::string& key) {
  const json::Value* v = obj.find(key);
  return (v == nullptr || v->is_null()) ? nullptr : v;
}

void check_keys(const json::Value& obj, const std::string& path,
                const std::set<std::string>& known) {
  std::string unknown;
  for (const json::Member& m : obj.as_object()) {
    if (known.count(m.first) == 0 && m.first != "note") {
      unknown += (unknown.empty() ? "\"" : ", \"") + m.first + "\"";
    }
  }
  if (!unknown.empty()) fail(path, "unknown field(s) " + unknown);
}

const json::Value& object_at(const json::Value& obj, const std::string& key,
                             const std::string& path) {
  const json::Value* v = member(obj, key);
  if (v == nullptr) fail(join(path, key), "missing");
  if (!v->is_object()) {
    fail(join(path, key), std::string("expected an object, found ") + json::type_name(v->type()));
  }
  return *v;
}

int64_t get_int(const json::Value& obj, const std::string& key, int64_t def,
                const std::string& path) {
  const json::Value* v = member(obj, key);
  if (v == nullptr) return def;
  if (!v->is_int()) {
    fail(join(path, key),
         std::string("expected an integer, found ") +
             (v->is_number() ? "a non-integer number" : json::type_name(v->type())));
  }
  return v->as_int();
}

// Number, or the strings "inf" / "-inf" (how the configs store infinities).
double number_or_inf(const json::Value& v, const std::string& path) {
  if (v.is_number()) return v.as_double();
  if (v.is_string()) {
    if (v.as_string() == "inf") return std::numeric_limits<double>::infinity();
    if (v.as_string() == "-inf") return -std::numeric_limits<double>::infinity();
  }
  fail(path, "expected a number, \"inf\" or \"-inf\"");
}

double get_double(const json::Value& obj, const std::string& key, double def,
                  const std::string& path) {
  const json::Value* v = member(obj, key);
  if (v == nullptr) return def;
  return number_or_inf(*v, join(path, key));
}

bool get_bool(const json::Value& obj, const std::string& key, bool def, const std::string& path) {
  const json::Value* v = member(obj, key);
  if (v == nullptr) return def;
  if (!v->is_bool()) {
    fail(join(path, key), std::string("expected true/false, found ") + json::type_name(v->type()));
  }
  return v->as_bool();
}

std::string get_string(const json::Value& obj, const std::string& key, const std::string& def,
                       const std::string& path) {
  const json::Value* v = member(obj, key);
  if (v == nullptr) return def;
  if (!v->is_string()) {
    fail(join(path, key), std::string("expected a string, found ") + json::type_name(v->type()));
  }
  return v->as_string();
}

std::vector<int64_t> get_int_list(const json::Value& obj, const std::string& key,
                                  const std::vector<int64_t>& def, const std::string& path) {
  const json::Value* v = member(obj, key);
  if (v == nullptr) return def;
  if (!v->is_array()) {
    fail(join(path, key),
         std::string("expected a list of integers, found ") + json::type_name(v->type()));
  }
  std::vector<int64_t> out;
  for (std::size_t i = 0; i < v->size(); ++i) {
    const json::Value& e = v->at(i);
    if (!e.is_int()) fail(join(path, key) + "[" + std::to_string(i) + "]", "expected an integer");
    out.push_back(e.as_int());
  }
  return out;
}

// "LayerNorm(eps=1e-6)" -> 1e-6; "LayerNorm" -> 1e-5 (nn.LayerNorm's default).
// Descriptive strings such as "LayerNorm(32) eps=1e-5 (...)" work too.
double parse_layer_norm_eps(const std::string& s, const std::string& path) {
  if (s.rfind("LayerNorm", 0) != 0) fail(path, "only LayerNorm is supported, found \"" + s + "\"");
  const std::size_t at = s.find("eps=");
  if (at == std::string::npos) return 1e-5;
  const char* begin = s.c_str() + at + 4;
  char* end = nullptr;
  const double eps = std::strtod(begin, &end);
  if (end == begin || !(eps > 0.0) || !std::isfinite(eps)) {
    fail(path, "cannot read a positive eps from \"" + s + "\"");
  }
  return eps;
}

DepthMode parse_depth_mode(const json::Value& obj, const std::string& path) {
  const json::Value* v = member(obj, "depth_mode");
  const std::string p = join(path, "depth_mode");
  if (v == nullptr) return DepthMode::kExp;
  if (!v->is_array() || v->size() != 3 || !v->at(0).is_string()) {
    fail(p, "expected [mode, vmin, vmax]");
  }
  const double vmin = number_or_inf(v->at(1), p + "[1]");
  const double vmax = number_or_inf(v->at(2), p + "[2]");
  // The official reg_dense_depth asserts unbounded ranges.
  if (!(std::isinf(vmin) && vmin < 0 && std::isinf(vmax) && vmax > 0)) {
    fail(p, "only unbounded ranges (-inf, inf) are supported");
  }
  const std::string& mode = v->at(0).as_string();
  if (mode == "exp") return DepthMode::kExp;
  if (mode == "linear") return DepthMode::kLinear;
  if (mode == "square") return DepthMode::kSquare;
  fail(p, "unknown mode \"" + mode + "\" (exp, linear, square)");
}

void parse_conf_mode(const json::Value& obj, const std::string& path, Dust3rConfig& c) {
  const json::Value* v = obj.find("conf_mode");
  const std::string p = join(path, "conf_mode");
  if (v == nullptr) return;  // default exp [1, inf]
  if (v->is_null()) {
    c.conf_mode = ConfMode::kNone;
    return;
  }
  if (!v->is_array() || v->size() != 3 || !v->at(0).is_string()) {
    fail(p, "expected [mode, vmin, vmax] or null");
  }
  c.conf_vmin = number_or_inf(v->at(1), p + "[1]");
  c.conf_vmax = number_or_inf(v->at(2), p + "[2]");
  const std::string& mode = v->at(0).as_string();
  if (mode == "exp") {
    c.conf_mode = ConfMode::kExp;
  } else if (mode == "sigmoid") {
    c.conf_mode = ConfMode::kSigmoid;
  } else {
    fail(p, "unknown mode \"" + mode + "\" (exp, sigmoid)");
  }
}

void parse_dpt(const json::Value& d, const std::string& path, Dust3rConfig& c) {
  check_keys(d, path,
             {"feature_dim", "last_dim", "layer_dims", "hooks", "dim_tokens", "num_channels",
              "head_type", "output_width_ratio", "stride_level", "patch_size", "use_bn"});
  DptHeadConfig& h = c.dpt;
  h.feature_dim = get_int(d, "feature_dim", h.feature_dim, path);
  h.last_dim = get_int(d, "last_dim", h.last_dim, path);
  h.layer_dims = get_int_list(d, "layer_dims", h.layer_dims, path);
  h.hooks = get_int_list(d, "hooks", h.hooks, path);
  h.dim_tokens = get_int_list(d, "dim_tokens", h.dim_tokens, path);
  h.num_channels = get_int(d, "num_channels", h.num_channels, path);
  if (get_string(d, "head_type", "regression", path) != "regression") {
    fail(join(path, "head_type"), "only \"regression\" is supported");
  }
  if (get_double(d, "output_width_ratio", 1.0, path) != 1.0) {
    fail(join(path, "output_width_ratio"), "only 1 is supported");
  }
  if (get_int(d, "stride_level", 1, path) != 1)
    fail(join(path, "stride_level"), "only 1 is supported");
  if (get_int(d, "patch_size", c.patch_size, path) != c.patch_size) {
    fail(join(path, "patch_size"), "must equal dust3r.patch_size");
  }
  if (get_bool(d, "use_bn", false, path)) {
    fail(join(path, "use_bn"), "batch-norm DPT heads are not supported");
  }
}

void parse_dust3r(const json::Value& d, Dust3rConfig& c) {
  const std::string path = "dust3r";
  check_keys(d, path,
             {"output_mode",    "head_type",       "depth_mode",      "conf_mode",  "freeze",
              "landscape_only", "patch_embed_cls", "img_size",        "patch_size", "enc_embed_dim",
              "enc_depth",      "enc_num_heads",   "dec_embed_dim",   "dec_depth",  "dec_num_heads",
              "mlp_ratio",      "norm_layer",      "norm_im2_in_dec", "pos_embed",  "mask_ratio",
              "dpt_head"});
  if (get_string(d, "output_mode", "pts3d", path) != "pts3d") {
    fail(join(path, "output_mode"), "only \"pts3d\" is supported");
  }
  const std::string head_type = get_string(d, "head_type", "dpt", path);
  if (head_type != "dpt") {
    fail(join(path, "head_type"), "only \"dpt\" heads are supported, found \"" + head_type + "\"");
  }
  c.depth_mode = parse_depth_mode(d, path);
  parse_conf_mode(d, path, c);
  c.landscape_only = get_bool(d, "landscape_only", c.landscape_only, path);
  const std::string pe = get_string(d, "patch_embed_cls", "PatchEmbedDust3R", path);
  if (pe == "PatchEmbedDust3R") {
    c.patch_embed = PatchEmbedKind::kDust3r;
  } else if (pe == "ManyAR_PatchEmbed") {
    c.patch_embed = PatchEmbedKind::kManyAR;
  } else {
    fail(join(path, "patch_embed_cls"), "unknown class \"" + pe + "\"");
  }
  if (const json::Value* v = member(d, "img_size")) {
    if (v->is_int()) {
      c.img_size = {v->as_int(), v->as_int()};
    } else {
      c.img_size = get_int_list(d, "img_size", {}, path);
      if (c.img_size.size() != 2) fail(join(path, "img_size"), "expected an integer or [H, W]");
    }
  }
  c.patch_size = get_int(d, "patch_size", c.patch_size, path);
  c.enc_embed_dim = get_int(d, "enc_embed_dim", c.enc_embed_dim, path);
  c.enc_depth = get_int(d, "enc_depth", c.enc_depth, path);
  c.enc_num_heads = get_int(d, "enc_num_heads", c.enc_num_heads, path);
  c.dec_embed_dim = get_int(d, "dec_embed_dim", c.dec_embed_dim, path);
  c.dec_depth = get_int(d, "dec_depth", c.dec_depth, path);
  c.dec_num_heads = get_int(d, "dec_num_heads", c.dec_num_heads, path);
  c.mlp_ratio = get_double(d, "mlp_ratio", c.mlp_ratio, path);
  if (const json::Value* v = member(d, "norm_layer")) {
    if (!v->is_string()) fail(join(path, "norm_layer"), "expected a string");
    c.norm_eps = parse_layer_norm_eps(v->as_string(), join(path, "norm_layer"));
  }
  c.norm_im2_in_dec = get_bool(d, "norm_im2_in_dec", c.norm_im2_in_dec, path);
  const std::string pos = get_string(d, "pos_embed", "RoPE100", path);
  if (pos.rfind("RoPE", 0) != 0) {
    fail(join(path, "pos_embed"),
         "only RoPE position embeddings are supported, found \"" + pos + "\"");
  }
  {
    const char* begin = pos.c_str() + 4;
    char* end = nullptr;
    c.rope_freq = std::strtod(begin, &end);
    if (end == begin || *end != '\0' || !(c.rope_freq > 0.0)) {
      fail(join(path, "pos_embed"), "cannot read the RoPE base frequency from \"" + pos + "\"");
    }
  }
  get_double(d, "mask_ratio", 0.0, path);  // pre-training only; type-checked
  get_string(d, "freeze", "none", path);   // training only; type-checked

  // Official create_dpt_head values, derived from the widths.
  c.dpt.hooks = {0, c.dec_depth * 2 / 4, c.dec_depth * 3 / 4, c.dec_depth};
  c.dpt.dim_tokens = {c.enc_embed_dim, c.dec_embed_dim, c.dec_embed_dim, c.dec_embed_dim};
  c.dpt.num_channels = c.conf_mode == ConfMode::kNone ? 3 : 4;
  if (const json::Value* v = member(d, "dpt_head")) {
    if (!v->is_object()) fail(join(path, "dpt_head"), "expected an object");
    parse_dpt(*v, join(path, "dpt_head"), c);
  }
}

void parse_spann3r(const json::Value& s, const Dust3rConfig& d, Spann3rConfig& c) {
  const std::string path = "spann3r";
  check_keys(s, path,
             {"use_feat", "mem_pos_enc", "memory_dropout", "value_encoder", "pos_patch_embed",
              "norm_qkv", "attn_head"});
  c.use_feat = get_bool(s, "use_feat", c.use_feat, path);
  c.mem_pos_enc = get_bool(s, "mem_pos_enc", c.mem_pos_enc, path);
  // Official defaults: values encoded at the width of what they are made from.
  c.value_encoder.embed_dim = c.use_feat ? d.dec_embed_dim : d.enc_embed_dim;
  get_double(s, "memory_dropout", 0.0, path);  // training only; type-checked
  get_string(s, "pos_patch_embed", "", path);  // descriptive
  get_string(s, "attn_head", "", path);        // descriptive; widths follow from the model
  if (const json::Value* v = member(s, "norm_qkv")) {
    if (!v->is_string()) fail(join(path, "norm_qkv"), "expected a string");
    c.norm_qkv_eps = parse_layer_norm_eps(v->as_string(), join(path, "norm_qkv"));
  }
  if (const json::Value* v = member(s, "value_encoder")) {
    const std::string vp = join(path, "value_encoder");
    if (!v->is_object()) fail(vp, "expected an object");
    check_keys(*v, vp,
               {"depth", "embed_dim", "num_heads", "mlp_ratio", "qkv_bias", "norm_layer", "rope",
                "out_dim"});
    ValueEncoderConfig& e = c.value_encoder;
    e.depth = get_int(*v, "depth", e.depth, vp);
    e.embed_dim = get_int(*v, "embed_dim", e.embed_dim, vp);
    e.num_heads = get_int(*v, "num_heads", e.num_heads, vp);
    e.mlp_ratio = get_double(*v, "mlp_ratio", e.mlp_ratio, vp);
    e.qkv_bias = get_bool(*v, "qkv_bias", e.qkv_bias, vp);
    e.out_dim = get_int(*v, "out_dim", e.out_dim, vp);
    if (const json::Value* n = member(*v, "norm_layer")) {
      if (!n->is_string()) fail(join(vp, "norm_layer"), "expected a string");
      e.norm_eps = parse_layer_norm_eps(n->as_string(), join(vp, "norm_layer"));
    }
    // "rope" records what mem_pos_enc implies (the DUSt3R RoPE or null).
    const bool has_rope = member(*v, "rope") != nullptr;
    if (has_rope != c.mem_pos_enc) {
      fail(join(vp, "rope"), "must be set exactly when spann3r.mem_pos_enc is true");
    }
  }
}

void parse_spatial_memory(const json::Value& m, SpatialMemoryConfig& c) {
  const std::string path = "spatial_memory";
  check_keys(m, path,
             {"long_mem_size", "top_k", "work_mem_size", "attn_thresh", "sim_thresh", "mem_dropout",
              "num_patches"});
  c.long_mem_size = get_int(m, "long_mem_size", c.long_mem_size, path);
  c.top_k = get_int(m, "top_k", c.long_mem_size, path);
  c.work_mem_size = get_int(m, "work_mem_size", c.work_mem_size, path);
  c.attn_thresh = get_double(m, "attn_thresh", c.attn_thresh, path);
  c.sim_thresh = get_double(m, "sim_thresh", c.sim_thresh, path);
  c.num_patches = get_int(m, "num_patches", 0, path);
  if (member(m, "mem_dropout") != nullptr) {
    fail(join(path, "mem_dropout"), "memory dropout is a training setting; must be null");
  }
}

void parse_long3r(const json::Value& m, Long3rConfig& c) {
  const std::string path = "long3r";
  check_keys(m, path,
             {"short_term_frames", "long_term_capacity", "tau", "voxel_statistic",
              "voxel_percentile", "long_term_policy", "sim_thresh"});
  c.short_term_frames = get_int(m, "short_term_frames", c.short_term_frames, path);
  c.long_term_capacity = get_int(m, "long_term_capacity", c.long_term_capacity, path);
  c.tau = get_double(m, "tau", c.tau, path);
  c.voxel_statistic = get_string(m, "voxel_statistic", c.voxel_statistic, path);
  c.voxel_percentile = get_double(m, "voxel_percentile", c.voxel_percentile, path);
  c.long_term_policy = get_string(m, "long_term_policy", c.long_term_policy, path);
  c.sim_thresh = get_double(m, "sim_thresh", c.sim_thresh, path);
}

void require(bool ok, const std::string& path, const std::string& what) {
  if (!ok) fail(path, what);
}

void validate_heads(int64_t dim, int64_t heads, bool rope, const std::string& dim_path,
                    const std::string& heads_path) {
  require(dim > 0, dim_path, "must be positive, got " + std::to_string(dim));
  require(heads > 0, heads_path, "must be positive, got " + std::to_string(heads));
  require(dim % heads == 0, heads_path,
          "must divide " + dim_path + " (" + std::to_string(dim) + " % " + std::to_string(heads) +
              " != 0)");
  if (rope) {
    require((dim / heads) % 4 == 0, heads_path,
            "2D RoPE needs a head width divisible by 4, got " + std::to_string(dim / heads));
  }
}

}  // namespace

const char* model_kind_name(ModelKind kind) {
  switch (kind) {
    case ModelKind::kSpann3r:
      return "Spann3R";
    case ModelKind::kLong3r:
      return "LONG3R";
    case ModelKind::kDust3r:
      break;
  }
  return "AsymmetricCroCo3DStereo";
}

void validate_model_config(const ModelConfig& config) {
  const Dust3rConfig& d = config.dust3r;
  require(d.patch_size > 0, "dust3r.patch_size", "must be positive");
  validate_heads(d.enc_embed_dim, d.enc_num_heads, true, "dust3r.enc_embed_dim",
                 "dust3r.enc_num_heads");
  validate_heads(d.dec_embed_dim, d.dec_num_heads, true, "dust3r.dec_embed_dim",
                 "dust3r.dec_num_heads");
  require(d.enc_depth >= 1, "dust3r.enc_depth", "must be at least 1");
  require(d.dec_depth >= 1, "dust3r.dec_depth", "must be at least 1");
  require(d.mlp_ratio > 0 && d.mlp_hidden(std::min(d.enc_embed_dim, d.dec_embed_dim)) >= 1,
          "dust3r.mlp_ratio", "must give a positive MLP width");
  require(d.norm_eps > 0, "dust3r.norm_layer", "eps must be positive");
  require(d.rope_freq > 0, "dust3r.pos_embed", "RoPE frequency must be positive");
  if (d.conf_mode == ConfMode::kExp) {
    require(std::isfinite(d.conf_vmin) && d.conf_vmax > d.conf_vmin, "dust3r.conf_mode",
            "exp needs a finite vmin below vmax");
  } else if (d.conf_mode == ConfMode::kSigmoid) {
    require(std::isfinite(d.conf_vmin) && std::isfinite(d.conf_vmax) && d.conf_vmax > d.conf_vmin,
            "dust3r.conf_mode", "sigmoid needs finite vmin < vmax");
  }

  const DptHeadConfig& h = d.dpt;
  const std::string hp = "dust3r.dpt_head";
  require(h.feature_dim >= 2, hp + ".feature_dim", "must be at least 2");
  require(h.last_dim >= 1, hp + ".last_dim", "must be positive");
  require(h.layer_dims.size() == 4, hp + ".layer_dims", "needs 4 entries");
  for (int64_t v : h.layer_dims) require(v >= 1, hp + ".layer_dims", "entries must be positive");
  require(h.hooks.size() == 4, hp + ".hooks", "needs 4 entries");
  require(h.dim_tokens.size() == 4, hp + ".dim_tokens", "needs 4 entries");
  for (std::size_t i = 0; i < 4; ++i) {
    const std::string ip = "[" + std::to_string(i) + "]";
    require(h.hooks[i] >= 0 && h.hooks[i] <= d.dec_depth, hp + ".hooks" + ip,
            "must lie in [0, dec_depth = " + std::to_string(d.dec_depth) + "], got " +
                std::to_string(h.hooks[i]));
    const int64_t width = h.hooks[i] == 0 ? d.enc_embed_dim : d.dec_embed_dim;
    require(h.dim_tokens[i] == width, hp + ".dim_tokens" + ip,
            "must be the width of hooked layer " + std::to_string(h.hooks[i]) + " (" +
                std::to_string(width) + "), got " + std::to_string(h.dim_tokens[i]));
  }
  const int64_t channels = d.conf_mode == ConfMode::kNone ? 3 : 4;
  require(h.num_channels == channels, hp + ".num_channels",
          "must be " + std::to_string(channels) + " (xyz" +
              (channels == 4 ? " + confidence)" : ", no confidence)"));

  if (config.kind == ModelKind::kDust3r) return;
  const Spann3rConfig& s = config.spann3r;
  const ValueEncoderConfig& e = s.value_encoder;
  const std::string vp = "spann3r.value_encoder";
  require(e.depth >= 0, vp + ".depth", "must not be negative");
  validate_heads(e.embed_dim, e.num_heads, s.mem_pos_enc, vp + ".embed_dim", vp + ".num_heads");
  require(e.mlp_ratio > 0 && static_cast<int64_t>(e.embed_dim * e.mlp_ratio) >= 1,
          vp + ".mlp_ratio", "must give a positive MLP width");
  require(e.norm_eps > 0, vp + ".norm_layer", "eps must be positive");
  const int64_t value_in = s.use_feat ? d.dec_embed_dim : d.enc_embed_dim;
  require(e.embed_dim == value_in, vp + ".embed_dim",
          std::string("must equal ") +
              (s.use_feat ? "dust3r.dec_embed_dim" : "dust3r.enc_embed_dim") + " (" +
              std::to_string(value_in) + "), got " + std::to_string(e.embed_dim));
  // The memory read-out replaces the encoder features of the decoder's first
  // branch, so the memory width must be the encoder width.
  require(e.out_dim == d.enc_embed_dim, vp + ".out_dim",
          "must equal dust3r.enc_embed_dim (" + std::to_string(d.enc_embed_dim) + "), got " +
              std::to_string(e.out_dim));
  require(s.norm_qkv_eps > 0, "spann3r.norm_qkv", "eps must be positive");

  if (config.kind == ModelKind::kLong3r) {
    const Long3rConfig& l = config.long3r;
    require(l.short_term_frames >= 0, "long3r.short_term_frames", "must not be negative");
    require(l.long_term_capacity >= 0, "long3r.long_term_capacity", "must not be negative");
    require(l.tau >= 0 && l.tau < 1, "long3r.tau", "must lie in [0, 1)");
    require(l.voxel_statistic == "min" || l.voxel_statistic == "percentile",
            "long3r.voxel_statistic",
            "must be \"min\" or \"percentile\", got \"" + l.voxel_statistic + "\"");
    require(l.voxel_percentile >= 0 && l.voxel_percentile <= 100, "long3r.voxel_percentile",
            "must lie in [0, 100]");
    require(l.long_term_policy == "voxel" || l.long_term_policy == "spann3r",
            "long3r.long_term_policy",
            "must be \"voxel\" or \"spann3r\", got \"" + l.long_term_policy + "\"");
    require(l.sim_thresh > -1 && l.sim_thresh <= 1, "long3r.sim_thresh", "must be in (-1, 1]");
    return;
  }

  const SpatialMemoryConfig& m = config.spatial_memory;
  const std::string mp = "spatial_memory";
  require(m.long_mem_size >= 0, mp + ".long_mem_size", "must not be negative");
  require(m.top_k >= 1, mp + ".top_k", "must be positive");
  require(m.work_mem_size >= 1, mp + ".work_mem_size", "must be at least 1");
  require(m.attn_thresh >= 0 && m.attn_thresh < 1, mp + ".attn_thresh", "must lie in [0, 1)");
  require(m.sim_thresh > -1 && m.sim_thresh <= 1, mp + ".sim_thresh", "must lie in (-1, 1]");
  require(m.num_patches >= 0, mp + ".num_patches", "must not be negative");
}

ModelConfig parse_model_config(const json::Value& config) {
  ModelConfig out;
  try {
    if (!config.is_object()) {
      fail("(top level)",
           std::string("expected an object, found ") + json::type_name(config.type()));
    }
    const std::string model = get_string(config, "model", "", "");
    if (model == "AsymmetricCroCo3DStereo") {
      out.kind = ModelKind::kDust3r;
    } else if (model == "Spann3R") {
      out.kind = ModelKind::kSpann3r;
    } else if (model == "LONG3R") {
      out.kind = ModelKind::kLong3r;
    } else if (model.empty()) {
      out.kind = member(config, "spann3r") != nullptr ? ModelKind::kSpann3r : ModelKind::kDust3r;
    } else {
      fail("model", "unknown model \"" + model + "\" (AsymmetricCroCo3DStereo, Spann3R, LONG3R)");
    }
    parse_dust3r(object_at(config, "dust3r", ""), out.dust3r);
    if (out.kind != ModelKind::kDust3r) {
      // Official Spann3R defaults: the memory encoders follow the encoder width.
      ValueEncoderConfig& e = out.spann3r.value_encoder;
      e.embed_dim = out.dust3r.enc_embed_dim;
      e.out_dim = out.dust3r.enc_embed_dim;
      if (const json::Value* s = member(config, "spann3r")) {
        if (!s->is_object()) fail("spann3r", "expected an object");
        parse_spann3r(*s, out.dust3r, out.spann3r);
      }
      if (const json::Value* m = member(config, "spatial_memory")) {
        if (out.kind == ModelKind::kLong3r) {
          fail("spatial_memory", "Spann3R memory settings; LONG3R reads the \"long3r\" section");
        }
        if (!m->is_object()) fail("spatial_memory", "expected an object");
        parse_spatial_memory(*m, out.spatial_memory);
      }
      if (const json::Value* m = member(config, "long3r")) {
        if (out.kind != ModelKind::kLong3r) fail("long3r", "only for \"model\": \"LONG3R\"");
        if (!m->is_object()) fail("long3r", "expected an object");
        parse_long3r(*m, out.long3r);
      }
    }
  } catch (const json::Error& e) {
    throw ModelConfigError(std::string("model config: ") + e.what());
  }
  validate_model_config(out);
  return out;
}

ModelConfig parse_model_config(const std::string& json_text) {
  json::Value v;
  try {
    v = json::parse(json_text);
  } catch (const json::Error& e) {
    throw ModelConfigError(std::string("model config is not valid JSON: ") + e.what());
  }
  return parse_model_config(v);
}

ModelConfig model_config_from_metadata(const std::map<std::string, std::string>& metadata,
                                       const std::string& source) {
  const auto it = metadata.find("config");
  if (it == metadata.end()) {
    throw ModelConfigError(source + ": no model configuration (metadata \"config\") in the file");
  }
  try {
    return parse_model_config(it->second);
  } catch (const ModelConfigError& e) {
    throw ModelConfigError(source + ": " + e.what());
  }
}

namespace {

// Shortest text that reads back as the same double (as json dumps it).
std::string number_text(double v) { return json::Value(v).dump(); }

json::Value number_or_inf_value(double v) {
  if (std::isinf(v)) return json::Value(v > 0 ? "inf" : "-inf");
  return json::Value(v);
}

std::string layer_norm_text(double eps) { return "LayerNorm(eps=" + number_text(eps) + ")"; }

json::Value int_list(const std::vector<int64_t>& v) {
  json::Array a;
  for (int64_t x : v) a.emplace_back(x);
  return json::Value(std::move(a));
}

const char* depth_mode_name(DepthMode m) {
  switch (m) {
    case DepthMode::kLinear:
      return "linear";
    case DepthMode::kSquare:
      return "square";
    case DepthMode::kExp:
      break;
  }
  return "exp";
}

}  // namespace

std::string model_config_to_json(const ModelConfig& config) {
  const Dust3rConfig& d = config.dust3r;
  json::Value dust3r{json::Object{}};
  dust3r.set("patch_size", d.patch_size);
  dust3r.set("img_size", int_list(d.img_size));
  dust3r.set("enc_embed_dim", d.enc_embed_dim);
  dust3r.set("enc_depth", d.enc_depth);
  dust3r.set("enc_num_heads", d.enc_num_heads);
  dust3r.set("dec_embed_dim", d.dec_embed_dim);
  dust3r.set("dec_depth", d.dec_depth);
  dust3r.set("dec_num_heads", d.dec_num_heads);
  dust3r.set("mlp_ratio", d.mlp_ratio);
  dust3r.set("norm_layer", layer_norm_text(d.norm_eps));
  dust3r.set("norm_im2_in_dec", d.norm_im2_in_dec);
  dust3r.set("pos_embed", "RoPE" + number_text(d.rope_freq));
  dust3r.set("depth_mode", json::Value(json::Array{json::Value(depth_mode_name(d.depth_mode)),
                                                   json::Value("-inf"), json::Value("inf")}));
  if (d.conf_mode == ConfMode::kNone) {
    dust3r.set("conf_mode", json::Value());
  } else {
    dust3r.set("conf_mode",
               json::Value(json::Array{
                   json::Value(d.conf_mode == ConfMode::kExp ? "exp" : "sigmoid"),
                   number_or_inf_value(d.conf_vmin), number_or_inf_value(d.conf_vmax)}));
  }
  dust3r.set("landscape_only", d.landscape_only);
  dust3r.set("patch_embed_cls",
             d.patch_embed == PatchEmbedKind::kManyAR ? "ManyAR_PatchEmbed" : "PatchEmbedDust3R");
  json::Value dpt{json::Object{}};
  dpt.set("feature_dim", d.dpt.feature_dim);
  dpt.set("last_dim", d.dpt.last_dim);
  dpt.set("layer_dims", int_list(d.dpt.layer_dims));
  dpt.set("hooks", int_list(d.dpt.hooks));
  dpt.set("dim_tokens", int_list(d.dpt.dim_tokens));
  dpt.set("num_channels", d.dpt.num_channels);
  dust3r.set("dpt_head", std::move(dpt));

  json::Value root{json::Object{}};
  root.set("model", model_kind_name(config.kind));
  root.set("dust3r", std::move(dust3r));
  if (config.kind != ModelKind::kDust3r) {
    const Spann3rConfig& s = config.spann3r;
    const ValueEncoderConfig& e = s.value_encoder;
    json::Value ve{json::Object{}};
    ve.set("depth", e.depth);
    ve.set("embed_dim", e.embed_dim);
    ve.set("num_heads", e.num_heads);
    ve.set("mlp_ratio", e.mlp_ratio);
    ve.set("qkv_bias", e.qkv_bias);
    ve.set("norm_layer", layer_norm_text(e.norm_eps));
    ve.set("out_dim", e.out_dim);
    if (s.mem_pos_enc) ve.set("rope", "RoPE" + number_text(d.rope_freq));
    json::Value sp{json::Object{}};
    sp.set("use_feat", s.use_feat);
    sp.set("mem_pos_enc", s.mem_pos_enc);
    sp.set("norm_qkv", layer_norm_text(s.norm_qkv_eps));
    sp.set("value_encoder", std::move(ve));
    root.set("spann3r", std::move(sp));
  }
  if (config.kind == ModelKind::kSpann3r) {
    const SpatialMemoryConfig& m = config.spatial_memory;
    json::Value sm{json::Object{}};
    sm.set("long_mem_size", m.long_mem_size);
    sm.set("top_k", m.top_k);
    sm.set("work_mem_size", m.work_mem_size);
    sm.set("attn_thresh", m.attn_thresh);
    sm.set("sim_thresh", m.sim_thresh);
    sm.set("num_patches", m.num_patches);
    root.set("spatial_memory", std::move(sm));
  }
  if (config.kind == ModelKind::kLong3r) {
    const Long3rConfig& l = config.long3r;
    json::Value lm{json::Object{}};
    lm.set("short_term_frames", l.short_term_frames);
    lm.set("long_term_capacity", l.long_term_capacity);
    lm.set("tau", l.tau);
    lm.set("voxel_statistic", l.voxel_statistic);
    lm.set("voxel_percentile", l.voxel_percentile);
    lm.set("long_term_policy", l.long_term_policy);
    lm.set("sim_thresh", l.sim_thresh);
    root.set("long3r", std::move(lm));
  }
  return root.dump();
}

namespace {

ModelConfig long3r_config(int64_t enc_dim, int64_t enc_depth, int64_t enc_heads, int64_t dec_dim,
                          int64_t dec_depth, int64_t dec_heads, int64_t value_depth,
                          int64_t value_heads, int64_t feature_dim, int64_t last_dim,
                          const std::vector<int64_t>& layer_dims, int64_t K, int64_t L) {
  ModelConfig c;
  c.kind = ModelKind::kLong3r;
  Dust3rConfig& d = c.dust3r;
  d.img_size = {224, 224};
  d.enc_embed_dim = enc_dim;
  d.enc_depth = enc_depth;
  d.enc_num_heads = enc_heads;
  d.dec_embed_dim = dec_dim;
  d.dec_depth = dec_depth;
  d.dec_num_heads = dec_heads;
  d.dpt.feature_dim = feature_dim;
  d.dpt.last_dim = last_dim;
  d.dpt.layer_dims = layer_dims;
  d.dpt.hooks = {0, dec_depth * 2 / 4, dec_depth * 3 / 4, dec_depth};
  d.dpt.dim_tokens = {enc_dim, dec_dim, dec_dim, dec_dim};
  ValueEncoderConfig& v = c.spann3r.value_encoder;
  v.depth = value_depth;
  v.embed_dim = enc_dim;
  v.num_heads = value_heads;
  v.out_dim = enc_dim;  // C_m = C_e: the read-out is added to F^I
  c.long3r.short_term_frames = K;
  c.long3r.long_term_capacity = L;
  validate_model_config(c);
  return c;
}

}  // namespace

ModelConfig named_model_config(const std::string& name) {
  if (name == "long3r_paper") {
    return long3r_config(1024, 24, 16, 768, 12, 12, 6, 16, 256, 128, {96, 192, 384, 768}, 10, 3000);
  }
  if (name == "long3r_small") {
    return long3r_config(192, 6, 3, 128, 6, 4, 2, 3, 64, 32, {48, 96, 192, 384}, 10, 3000);
  }
  if (name == "long3r_ship") {
    // The model shipped in models/: sized for >= 5 FPS end to end at 224x224
    // on two CPU cores (docs/training.md), head width 32 throughout.
    return long3r_config(128, 4, 4, 96, 4, 3, 2, 4, 48, 24, {24, 48, 96, 192}, 10, 1000);
  }
  if (name == "long3r_tiny") {
    return long3r_config(32, 1, 2, 32, 4, 2, 1, 2, 16, 8, {8, 16, 32, 32}, 2, 64);
  }
  throw ModelConfigError("unknown model configuration \"" + name +
                         "\" (long3r_paper, long3r_small, long3r_ship, long3r_tiny)");
}

}  // namespace long3r

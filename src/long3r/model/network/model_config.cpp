// Reading, writing and validation of the model configuration; see
// include/long3r/model/network/model_config.hpp.
//
// Each section lists its fields once (the *_fields templates and the memory
// structs' visit_fields); config::Reader reads and config::Writer writes
// through the same lists. The official constructor-argument layout has a few
// encodings of its own (codecs below): "LayerNorm(eps=...)" strings, "RoPE100",
// depth/confidence mode tuples [mode, vmin, vmax] with "inf"/"-inf", and
// settings that are only type-checked (training-only or descriptive).
#include "long3r/model/network/model_config.hpp"

#include <cmath>
#include <cstdlib>

#include "long3r/config/config_json.hpp"

namespace long3r {

namespace {

using config::Json;
using config::Reader;

const Reader::Options kOptions{"model config", /*inf_strings=*/true, "note"};

[[noreturn]] void fail(const std::string& path, const std::string& what) {
  throw ConfigError("model config: " + path + ": " + what);
}

// Shortest text that reads back as the same double (Python's repr layout).
std::string number_text(double v) { return Json(v).dump(); }

// "LayerNorm(eps=1e-6)" -> 1e-6; "LayerNorm" -> 1e-5 (nn.LayerNorm's default).
// Descriptive strings such as "LayerNorm(32) eps=1e-5 (...)" work too.
template <class D>
struct LayerNormEps : config::Codec {
  D& eps;
  explicit LayerNormEps(D& e) : eps(e) {}
  void read(const Json& j, const Reader& r, const std::string& path) const {
    if (j.is_null()) return;
    std::string s;
    if (!j.is_string()) r.fail(path, "expected a string");
    s = j.get<std::string>();
    if (s.rfind("LayerNorm", 0) != 0)
      r.fail(path, "only LayerNorm is supported, found \"" + s + "\"");
    const std::size_t at = s.find("eps=");
    if (at == std::string::npos) {
      eps = 1e-5;
      return;
    }
    const char* begin = s.c_str() + at + 4;
    char* end = nullptr;
    const double e = std::strtod(begin, &end);
    if (end == begin || !(e > 0.0) || !std::isfinite(e)) {
      r.fail(path, "cannot read a positive eps from \"" + s + "\"");
    }
    eps = e;
  }
  Json write() const { return "LayerNorm(eps=" + number_text(eps) + ")"; }
};

// "RoPE100" -> 100.
template <class D>
struct RopeName : config::Codec {
  D& freq;
  explicit RopeName(D& f) : freq(f) {}
  void read(const Json& j, const Reader& r, const std::string& path) const {
    if (j.is_null()) return;
    std::string s;
    r.read(j, path, s);
    if (s.rfind("RoPE", 0) != 0) {
      r.fail(path, "only RoPE position embeddings are supported, found \"" + s + "\"");
    }
    const char* begin = s.c_str() + 4;
    char* end = nullptr;
    const double f = std::strtod(begin, &end);
    if (end == begin || *end != '\0' || !(f > 0.0)) {
      r.fail(path, "cannot read the RoPE base frequency from \"" + s + "\"");
    }
    freq = f;
  }
  Json write() const { return "RoPE" + number_text(freq); }
};

// "img_size": an integer (square) or [H, W].
template <class L>
struct ImgSize : config::Codec {
  L& size;
  explicit ImgSize(L& s) : size(s) {}
  void read(const Json& j, const Reader& r, const std::string& path) const {
    if (j.is_null()) return;
    if (j.is_number_integer()) {
      int64_t n = 0;
      r.read(j, path, n);
      size = {n, n};
      return;
    }
    if (!j.is_array()) r.fail(path, "expected a list of integers, found " + config::type_of(j));
    r.read(j, path, size);
    if (size.size() != 2) r.fail(path, "expected an integer or [H, W]");
  }
  Json write() const { return config::Writer::write(size); }
};

// [mode, vmin, vmax]; the official reg_dense_depth asserts unbounded ranges.
template <class M>
struct DepthModeTuple : config::Codec {
  M& mode;
  explicit DepthModeTuple(M& m) : mode(m) {}
  void read(const Json& j, const Reader& r, const std::string& path) const {
    if (j.is_null()) return;
    if (!j.is_array() || j.size() != 3 || !j[0].is_string()) {
      r.fail(path, "expected [mode, vmin, vmax]");
    }
    double vmin = 0, vmax = 0;
    r.read(j[1], path + "[1]", vmin);
    r.read(j[2], path + "[2]", vmax);
    if (!(std::isinf(vmin) && vmin < 0 && std::isinf(vmax) && vmax > 0)) {
      r.fail(path, "only unbounded ranges (-inf, inf) are supported");
    }
    const std::string name = j[0].get<std::string>();
    if (name == "exp") {
      mode = DepthMode::kExp;
    } else if (name == "linear") {
      mode = DepthMode::kLinear;
    } else if (name == "square") {
      mode = DepthMode::kSquare;
    } else {
      r.fail(path, "unknown mode \"" + name + "\" (exp, linear, square)");
    }
  }
  Json write() const {
    const char* name = mode == DepthMode::kLinear   ? "linear"
                       : mode == DepthMode::kSquare ? "square"
                                                    : "exp";
    return Json::array({name, "-inf", "inf"});
  }
};

// [mode, vmin, vmax], or null: the head has no confidence channel.
template <class C>
struct ConfModeTuple : config::Codec {
  C& d;  // Dust3rConfig
  explicit ConfModeTuple(C& c) : d(c) {}
  void read(const Json& j, const Reader& r, const std::string& path) const {
    if (j.is_null()) {
      d.conf_mode = ConfMode::kNone;
      return;
    }
    if (!j.is_array() || j.size() != 3 || !j[0].is_string()) {
      r.fail(path, "expected [mode, vmin, vmax] or null");
    }
    r.read(j[1], path + "[1]", d.conf_vmin);
    r.read(j[2], path + "[2]", d.conf_vmax);
    const std::string name = j[0].get<std::string>();
    if (name == "exp") {
      d.conf_mode = ConfMode::kExp;
    } else if (name == "sigmoid") {
      d.conf_mode = ConfMode::kSigmoid;
    } else {
      r.fail(path, "unknown mode \"" + name + "\" (exp, sigmoid)");
    }
  }
  Json write() const {
    if (d.conf_mode == ConfMode::kNone) return nullptr;
    return Json::array({d.conf_mode == ConfMode::kExp ? "exp" : "sigmoid",
                        config::Writer::write(d.conf_vmin), config::Writer::write(d.conf_vmax)});
  }
};

template <class P>
struct PatchEmbedClass : config::Codec {
  P& kind;
  explicit PatchEmbedClass(P& k) : kind(k) {}
  void read(const Json& j, const Reader& r, const std::string& path) const {
    if (j.is_null()) return;
    std::string s;
    r.read(j, path, s);
    if (s == "PatchEmbedDust3R") {
      kind = PatchEmbedKind::kDust3r;
    } else if (s == "ManyAR_PatchEmbed") {
      kind = PatchEmbedKind::kManyAR;
    } else {
      r.fail(path, "unknown class \"" + s + "\"");
    }
  }
  Json write() const {
    return kind == PatchEmbedKind::kManyAR ? "ManyAR_PatchEmbed" : "PatchEmbedDust3R";
  }
};

// "rope": what spann3r.mem_pos_enc implies (the DUSt3R RoPE, or null / absent).
struct ValueEncoderRope : config::Codec {
  static constexpr bool kSeesMissing = true;
  bool mem_pos_enc;
  double freq;
  ValueEncoderRope(bool m, double f) : mem_pos_enc(m), freq(f) {}
  void read(const Json& j, const Reader& r, const std::string& path) const {
    if (!j.is_null() != mem_pos_enc) {
      r.fail(path, "must be set exactly when spann3r.mem_pos_enc is true");
    }
  }
  Json write() const {
    return mem_pos_enc ? Json("RoPE" + number_text(freq)) : Json(Json::value_t::discarded);
  }
};

// Official PixelwiseTaskWithDPT arguments.
template <class S, class V>
void dpt_fields(S& h, V& v, int64_t patch_size) {
  v("feature_dim", h.feature_dim);
  v("last_dim", h.last_dim);
  v("layer_dims", h.layer_dims);
  v("hooks", h.hooks);
  v("dim_tokens", h.dim_tokens);
  v("num_channels", h.num_channels);
  v.fixed("head_type", std::string("regression"), "only \"regression\" is supported");
  v.fixed("output_width_ratio", 1.0, "only 1 is supported");
  v.fixed("stride_level", int64_t{1}, "only 1 is supported");
  v.fixed("patch_size", patch_size, "must equal dust3r.patch_size");
  v.fixed("use_bn", false, "batch-norm DPT heads are not supported");
}

// Official AsymmetricCroCo3DStereo arguments.
template <class S, class V>
void dust3r_fields(S& d, V& v) {
  v.fixed("output_mode", std::string("pts3d"), "only \"pts3d\" is supported");
  v("head_type", d.head_type);
  v.template ignored<double>("mask_ratio");   // pre-training only
  v.template ignored<std::string>("freeze");  // training only
  v("patch_size", d.patch_size);
  v("img_size", ImgSize(d.img_size));
  v("enc_embed_dim", d.enc_embed_dim);
  v("enc_depth", d.enc_depth);
  v("enc_num_heads", d.enc_num_heads);
  v("dec_embed_dim", d.dec_embed_dim);
  v("dec_depth", d.dec_depth);
  v("dec_num_heads", d.dec_num_heads);
  v("mlp_ratio", d.mlp_ratio);
  v("norm_layer", LayerNormEps(d.norm_eps));
  v("norm_im2_in_dec", d.norm_im2_in_dec);
  v("pos_embed", RopeName(d.rope_freq));
  v("depth_mode", DepthModeTuple(d.depth_mode));
  v("conf_mode", ConfModeTuple(d));
  v("landscape_only", d.landscape_only);
  v("patch_embed_cls", PatchEmbedClass(d.patch_embed));
  // Official create_dpt_head values, derived from the widths.
  v.derive(d.dpt.hooks,
           std::vector<int64_t>{0, d.dec_depth * 2 / 4, d.dec_depth * 3 / 4, d.dec_depth});
  v.derive(d.dpt.dim_tokens, std::vector<int64_t>{d.enc_embed_dim, d.dec_embed_dim, d.dec_embed_dim,
                                                  d.dec_embed_dim});
  v.derive(d.dpt.num_channels, d.conf_mode == ConfMode::kNone ? int64_t{3} : int64_t{4});
  // A linear head has no DPT arguments (the official LinearPts3d takes none).
  if (d.head_type == HeadType::kDpt) {
    v.section("dpt_head", [&](auto& sub) { dpt_fields(d.dpt, sub, d.patch_size); });
  }
}

// Spann3R's memory encoders; `d` gives the widths the defaults follow.
template <class S, class V>
void spann3r_fields(S& s, V& v, const Dust3rConfig& d) {
  v("use_feat", s.use_feat);
  v("mem_pos_enc", s.mem_pos_enc);
  // Official defaults: values encoded at the width of what they are made from.
  v.derive(s.value_encoder.embed_dim, s.use_feat ? d.dec_embed_dim : d.enc_embed_dim);
  v.template ignored<double>("memory_dropout");        // training only
  v.template ignored<std::string>("pos_patch_embed");  // descriptive
  v.template ignored<std::string>("attn_head");        // descriptive; widths follow from the model
  v("norm_qkv", LayerNormEps(s.norm_qkv_eps));
  v.section("value_encoder", [&](auto& sub) {
    auto& e = s.value_encoder;
    sub("depth", e.depth);
    sub("embed_dim", e.embed_dim);
    sub("num_heads", e.num_heads);
    sub("mlp_ratio", e.mlp_ratio);
    sub("qkv_bias", e.qkv_bias);
    sub("norm_layer", LayerNormEps(e.norm_eps));
    sub("out_dim", e.out_dim);
    sub("rope", ValueEncoderRope(s.mem_pos_enc, d.rope_freq));
  });
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

  if (d.head_type == HeadType::kDpt) {
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
  }

  const bool sized = config.input_width != 0 || config.input_height != 0;
  for (const auto& [v, name] : {std::pair{config.input_width, "input_width"},
                                std::pair{config.input_height, "input_height"}}) {
    require(!sized || (v > 0 && v % d.patch_size == 0), name,
            "must be a positive multiple of dust3r.patch_size (" + std::to_string(d.patch_size) +
                "), with both input_width and input_height given or neither, got " +
                std::to_string(v));
  }

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
    config.long3r.validate({"model config", "long3r"});
  } else {
    config.spatial_memory.validate({"model config", "spatial_memory"});
    // The model's JSON stores top_k resolved (0 would mean long_mem_size).
    require(config.spatial_memory.top_k >= 1, "spatial_memory.top_k", "must be positive");
  }
}

ModelConfig parse_model_config(const Json& root) {
  // Top-level keys other than the sections (e.g. "seed", "args") are allowed.
  if (!root.is_object()) {
    fail("(top level)", "expected an object, found " + config::type_of(root));
  }
  Reader top(root, "", kOptions);
  ModelConfig out;
  std::string model;
  top("model", model);
  if (model == "AsymmetricCroCo3DStereo") {
    out.kind = ModelKind::kDust3r;
  } else if (model == "Spann3R") {
    out.kind = ModelKind::kSpann3r;
  } else if (model == "LONG3R") {
    out.kind = ModelKind::kLong3r;
  } else if (model.empty()) {
    out.kind = top.take("spann3r") != nullptr ? ModelKind::kSpann3r : ModelKind::kDust3r;
  } else {
    fail("model", "unknown model \"" + model + "\" (AsymmetricCroCo3DStereo, Spann3R, LONG3R)");
  }
  top("input_width", out.input_width);
  top("input_height", out.input_height);
  if (top.take("dust3r") == nullptr) fail("dust3r", "missing");
  top.section("dust3r", [&](Reader& r) { dust3r_fields(out.dust3r, r); });
  if (out.kind != ModelKind::kDust3r) {
    // Official Spann3R defaults: the memory encoders follow the encoder width.
    out.spann3r.value_encoder.embed_dim = out.dust3r.enc_embed_dim;
    out.spann3r.value_encoder.out_dim = out.dust3r.enc_embed_dim;
    top.section("spann3r", [&](Reader& r) { spann3r_fields(out.spann3r, r, out.dust3r); });
    if (out.kind == ModelKind::kLong3r && top.take("spatial_memory") != nullptr) {
      fail("spatial_memory", "Spann3R memory settings; LONG3R reads the \"long3r\" section");
    }
    if (out.kind != ModelKind::kLong3r && top.take("long3r") != nullptr) {
      fail("long3r", "only for \"model\": \"LONG3R\"");
    }
    top.section("spatial_memory", [&](Reader& r) { visit_fields(out.spatial_memory, r); });
    top.section("long3r", [&](Reader& r) { visit_fields(out.long3r, r); });
  }
  validate_model_config(out);
  return out;
}

ModelConfig parse_model_config(const std::string& json_text) {
  return parse_model_config(config::parse(json_text, "model config"));
}

ModelConfig model_config_from_metadata(const std::map<std::string, std::string>& metadata,
                                       const std::string& source) {
  const auto it = metadata.find("config");
  if (it == metadata.end()) {
    throw ConfigError(source + ": no model configuration (metadata \"config\") in the file");
  }
  try {
    return parse_model_config(it->second);
  } catch (const ConfigError& e) {
    throw ConfigError(source + ": " + e.what());
  }
}

std::string model_config_to_json(const ModelConfig& c) {
  config::Writer w;
  w("model", model_kind_name(c.kind));
  if (c.input_width != 0 || c.input_height != 0) {  // only where recorded: other files unchanged
    w("input_width", c.input_width);
    w("input_height", c.input_height);
  }
  w.section("dust3r", [&](config::Writer& s) { dust3r_fields(c.dust3r, s); });
  if (c.kind != ModelKind::kDust3r) {
    w.section("spann3r", [&](config::Writer& s) { spann3r_fields(c.spann3r, s, c.dust3r); });
  }
  if (c.kind == ModelKind::kSpann3r) w("spatial_memory", c.spatial_memory);
  if (c.kind == ModelKind::kLong3r) w("long3r", c.long3r);
  return w.result().dump();
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

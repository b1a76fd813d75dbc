// DUSt3R / Spann3R modules; see modules.hpp.
#include "long3r/model/network/modules.hpp"

#include <ATen/ATen.h>
#include <c10/core/InferenceMode.h>
#include <torch/nn/modules/container/functional.h>
#include <torch/version.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "long3r/model/runtime/autocast.hpp"

namespace long3r {
namespace model {

namespace {

torch::nn::Conv2d conv(int64_t in, int64_t out, int64_t k, int64_t stride = 1, int64_t pad = 0,
                       bool bias = true) {
  return torch::nn::Conv2d(
      torch::nn::Conv2dOptions(in, out, k).stride(stride).padding(pad).bias(bias));
}

// 2x bilinear upsampling with align_corners=True (what the official
// Interpolate(scale_factor=2, "bilinear", align_corners=True) computes; with
// align_corners the scale factor only fixes the output size).
// On the CPU in float32 whatever the input: libtorch 1.13's bfloat16 CPU
// kernel misplaces samples (max relative error 5e-2 to 1.4e-1 against float32
// on the same inputs, scripts/bench_cpu_kernels.py); the result comes back in
// the input's precision.
at::Tensor upsample2x(const at::Tensor& x) {
  if (x.is_cpu() && x.scalar_type() != at::kFloat) {
    return upsample2x(x.to(at::kFloat)).to(x.scalar_type());
  }
  return at::upsample_bilinear2d(x, {x.size(2) * 2, x.size(3) * 2}, /*align_corners=*/true);
}

// A Sequential whose layers may hold different precisions (ModelShell::to:
// on the CPU a transposed convolution stays float32 beside bfloat16 ones):
// each layer with weights takes its input in theirs.
at::Tensor forward_in_layer_precisions(torch::nn::Sequential& seq, at::Tensor x) {
  for (auto& layer : *seq) {
    if (const at::Tensor* w = layer.ptr()->named_parameters(/*recurse=*/false).find("weight")) {
      if (x.scalar_type() != w->scalar_type()) x = x.to(w->scalar_type());
    }
    x = layer.forward(x);
  }
  return x;
}

}  // namespace

// ---------------------------------------------------------------------------
// RoPE

RopeTable Rope2D::table(int64_t head_dim, int64_t grid_h, int64_t grid_w, const at::Device& device,
                        at::ScalarType dtype) const {
  TORCH_CHECK(head_dim > 0 && head_dim % 4 == 0, "RoPE2D: head width must be a multiple of 4, got ",
              head_dim);
  TORCH_CHECK(grid_h > 0 && grid_w > 0, "RoPE2D: empty grid");
  const Key key{head_dim,       grid_h,
                grid_w,         static_cast<int>(device.type()),
                device.index(), static_cast<int>(dtype)};
  std::lock_guard<std::mutex> lock(mutex_);
  const auto it = cache_.find(key);
  if (it != cache_.end()) return it->second;

  // Built as normal tensors even under InferenceMode: the cache outlives the
  // mode, and an inference tensor cannot be saved for backward when the model
  // later trains.
  c10::InferenceMode normal_tensors(false);
  // Same operations as the official get_cos_sin (float32 frequencies, outer
  // product, cast, cos/sin), so the tables agree bit for bit.
  const int64_t D = head_dim / 2;  // channels per axis
  const auto f32 = at::TensorOptions().dtype(at::kFloat);
  const at::Tensor exponent = at::arange(0, D, 2, f32) / static_cast<double>(D);
  const at::Tensor inv_freq = at::reciprocal(at::pow(at::Scalar(base_), exponent));
  const int64_t seq_len = std::max(grid_h, grid_w);
  const at::Tensor t = at::arange(seq_len, f32);
  at::Tensor freqs = at::outer(t, inv_freq).to(dtype);
  freqs = at::cat({freqs, freqs}, -1);  // [seq, D]
  const at::Tensor cos = freqs.cos();
  // rotate_half(x) = [-x2, x1]: fold the minus into the first half of sin.
  at::Tensor sin = freqs.sin();
  sin.narrow(1, 0, D / 2).neg_();

  const at::Tensor pos = grid_positions(1, grid_h, grid_w, at::kCPU)[0];  // [N, 2]
  const at::Tensor py = pos.select(1, 0), px = pos.select(1, 1);
  RopeTable table;
  table.cos =
      at::cat({cos.index_select(0, py), cos.index_select(0, px)}, 1).to(device).contiguous();
  table.sin =
      at::cat({sin.index_select(0, py), sin.index_select(0, px)}, 1).to(device).contiguous();
  cache_.emplace(key, table);
  return table;
}

std::size_t Rope2D::cache_size() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return cache_.size();
}

void Rope2D::clear_cache() {
  std::lock_guard<std::mutex> lock(mutex_);
  cache_.clear();
}

at::Tensor Rope2D::apply(const at::Tensor& x, const RopeTable& table) {
  const int64_t dh = x.size(-1);
  std::vector<int64_t> split(x.sizes().begin(), x.sizes().end() - 1);
  split.insert(split.end(), {2, 2, dh / 4});
  // [..., axis, half, dh/4]: swapping the halves inside each axis is
  // rotate_half without its sign (which lives in table.sin).
  const at::Tensor swapped = x.view(split).flip(-2).view(x.sizes());
  return x * table.cos + swapped * table.sin;
}

at::Tensor grid_positions(int64_t batch, int64_t grid_h, int64_t grid_w, const at::Device& device) {
  const auto i64 = at::TensorOptions().dtype(at::kLong).device(device);
  const at::Tensor y = at::arange(grid_h, i64).view({grid_h, 1}).expand({grid_h, grid_w});
  const at::Tensor x = at::arange(grid_w, i64).view({1, grid_w}).expand({grid_h, grid_w});
  return at::stack({y.reshape({-1}), x.reshape({-1})}, 1)
      .unsqueeze(0)
      .expand({batch, grid_h * grid_w, 2})
      .contiguous();
}

at::Tensor attend(const at::Tensor& q, const at::Tensor& k, const at::Tensor& v) {
#if TORCH_VERSION_MAJOR >= 2
  // Its default scale is the official head_dim ** -0.5.
  return at::scaled_dot_product_attention(q, k, v);
#else
  at::Tensor a = at::matmul(q, k.transpose(-2, -1));
  a.mul_(std::pow(static_cast<double>(q.size(-1)), -0.5));
  // Softmax statistics in float32 whatever the precision (no-op in float32).
  return at::matmul(at::softmax(a, -1, at::kFloat).to(v.scalar_type()), v);
#endif
}

// ---------------------------------------------------------------------------
// Transformer parts

MlpImpl::MlpImpl(int64_t dim, int64_t hidden) {
  fc1 = register_module("fc1", torch::nn::Linear(dim, hidden));
  fc2 = register_module("fc2", torch::nn::Linear(hidden, dim));
}

at::Tensor MlpImpl::forward(const at::Tensor& x) { return fc2(at::gelu(fc1(x))); }

AttentionImpl::AttentionImpl(int64_t dim, int64_t heads, bool qkv_bias) : num_heads(heads) {
  qkv = register_module("qkv",
                        torch::nn::Linear(torch::nn::LinearOptions(dim, 3 * dim).bias(qkv_bias)));
  proj = register_module("proj", torch::nn::Linear(dim, dim));
}

at::Tensor AttentionImpl::forward(const at::Tensor& x, const RopeTable& rope) {
  const int64_t B = x.size(0), N = x.size(1), C = x.size(2);
  // [3, B, heads, N, head_dim]
  const at::Tensor t = qkv(x).view({B, N, 3, num_heads, C / num_heads}).permute({2, 0, 3, 1, 4});
  at::Tensor q, k;
  if (rope.defined()) {
    const at::Tensor qk = Rope2D::apply(t.narrow(0, 0, 2), rope);
    q = qk[0];
    k = qk[1];
  } else {
    q = t[0];
    k = t[1];
  }
  const at::Tensor out = attend(q, k, t[2]);  // [B, heads, N, head_dim]
  return proj(out.transpose(1, 2).reshape({B, N, C}));
}

CrossAttentionImpl::CrossAttentionImpl(int64_t dim, int64_t heads, bool qkv_bias)
    : num_heads(heads) {
  const auto opt = torch::nn::LinearOptions(dim, dim).bias(qkv_bias);
  projq = register_module("projq", torch::nn::Linear(opt));
  projk = register_module("projk", torch::nn::Linear(opt));
  projv = register_module("projv", torch::nn::Linear(opt));
  proj = register_module("proj", torch::nn::Linear(dim, dim));
}

at::Tensor CrossAttentionImpl::forward(const at::Tensor& query, const at::Tensor& key,
                                       const at::Tensor& value, const RopeTable& qrope,
                                       const RopeTable& krope) {
  const int64_t B = query.size(0), Nq = query.size(1), C = query.size(2);
  const int64_t Nk = key.size(1), Dh = C / num_heads;
  at::Tensor q = projq(query).view({B, Nq, num_heads, Dh}).permute({0, 2, 1, 3});
  at::Tensor k = projk(key).view({B, Nk, num_heads, Dh}).permute({0, 2, 1, 3});
  const at::Tensor v = projv(value).view({B, value.size(1), num_heads, Dh}).permute({0, 2, 1, 3});
  if (qrope.defined()) q = Rope2D::apply(q, qrope);
  if (krope.defined()) k = Rope2D::apply(k, krope);
  const at::Tensor out = attend(q, k, v);
  return proj(out.transpose(1, 2).reshape({B, Nq, C}));
}

BlockImpl::BlockImpl(int64_t dim, int64_t heads, int64_t mlp_hidden, bool qkv_bias, double eps) {
  norm1 = register_module("norm1", layer_norm(dim, eps));
  attn = register_module("attn", Attention(dim, heads, qkv_bias));
  norm2 = register_module("norm2", layer_norm(dim, eps));
  mlp = register_module("mlp", Mlp(dim, mlp_hidden));
}

at::Tensor BlockImpl::forward(const at::Tensor& x, const RopeTable& rope) {
  // Out of place: the LayerNorms keep their input for autograd (training).
  const at::Tensor out = x + attn(norm1(x), rope);
  return out + mlp(norm2(out));
}

int64_t decoder_block_init_draws(int64_t dim, int64_t mlp_hidden) {
  // Linear layers (weight and bias) of attn (qkv, proj), cross_attn (projq,
  // projk, projv, proj) and mlp (fc1, fc2); the LayerNorms draw nothing.
  auto linear = [](int64_t in, int64_t out) { return in * out + out; };
  return linear(dim, 3 * dim) + 5 * linear(dim, dim) + linear(dim, mlp_hidden) +
         linear(mlp_hidden, dim);
}

void skip_init_draws(int64_t n) {
  // One 32-bit draw per float32 element, as Linear's (kaiming_)uniform_ init.
  constexpr int64_t kChunk = int64_t{1} << 22;
  for (int64_t done = 0; done < n; done += kChunk) {
    at::empty({std::min(kChunk, n - done)}, at::kFloat).uniform_();
  }
}

DecoderBlockImpl::DecoderBlockImpl(int64_t dim, int64_t heads, int64_t mlp_hidden, double eps,
                                   bool norm_mem) {
  norm1 = register_module("norm1", layer_norm(dim, eps));
  attn = register_module("attn", Attention(dim, heads, /*qkv_bias=*/true));
  cross_attn = register_module("cross_attn", CrossAttention(dim, heads, /*qkv_bias=*/true));
  norm2 = register_module("norm2", layer_norm(dim, eps));
  norm3 = register_module("norm3", layer_norm(dim, eps));
  mlp = register_module("mlp", Mlp(dim, mlp_hidden));
  if (norm_mem) norm_y = register_module("norm_y", layer_norm(dim, eps));
}

at::Tensor DecoderBlockImpl::forward(const at::Tensor& x, const at::Tensor& y,
                                     const RopeTable& xrope, const RopeTable& yrope) {
  at::Tensor out = x + attn(norm1(x), xrope);
  const at::Tensor y_ = norm_y ? norm_y(y) : y;
  // Out of place: the LayerNorms keep their input for autograd (training).
  out = out + cross_attn(norm2(out), y_, y_, xrope, yrope);
  return out + mlp(norm3(out));
}

PatchEmbedImpl::PatchEmbedImpl(int64_t in_channels, int64_t dim, int64_t p) : patch(p) {
  proj = register_module("proj", conv(in_channels, dim, p, p));
}

at::Tensor PatchEmbedImpl::forward(const at::Tensor& image) {
  TORCH_CHECK(image.dim() == 4 && image.size(2) % patch == 0 && image.size(3) % patch == 0,
              "patch embedding: expected [B, C, H, W] with H and W multiples of ", patch, ", got ",
              image.sizes());
  // In the convolution's precision (float32 on the CPU, see ModelShell::to);
  // callers cast the tokens to theirs.
  return proj(image.to(proj->weight.scalar_type())).flatten(2).transpose(1, 2).contiguous();
}

// ---------------------------------------------------------------------------
// DPT head

ResidualConvUnitImpl::ResidualConvUnitImpl(int64_t features) {
  conv1 = register_module("conv1", conv(features, features, 3, 1, 1));
  conv2 = register_module("conv2", conv(features, features, 3, 1, 1));
}

at::Tensor ResidualConvUnitImpl::forward(const at::Tensor& x) {
  at::Tensor out = conv1(at::relu(x));
  out.relu_();
  out = conv2(out);
  return out.add_(x);
}

FeatureFusionBlockImpl::FeatureFusionBlockImpl(int64_t features) {
  out_conv = register_module("out_conv", conv(features, features, 1));
  resConfUnit1 = register_module("resConfUnit1", ResidualConvUnit(features));
  resConfUnit2 = register_module("resConfUnit2", ResidualConvUnit(features));
}

at::Tensor FeatureFusionBlockImpl::forward(const at::Tensor& x0, const at::Tensor& x1) {
  at::Tensor out = x1.defined() ? x0 + resConfUnit1(x1) : x0;
  out = resConfUnit2(out);
  return out_conv(upsample2x(out));
}

ScratchImpl::ScratchImpl(const std::vector<int64_t>& layer_dims, int64_t features) {
  for (int i = 0; i < 4; ++i) {
    layer_rn_convs.push_back(register_module("layer" + std::to_string(i + 1) + "_rn",
                                             conv(layer_dims[i], features, 3, 1, 1, false)));
  }
  // The same four convs again under layer_rn.{0..3}, as the official
  // make_scratch registers them (checkpoints hold both names).
  layer_rn = register_module("layer_rn", torch::nn::ModuleList());
  for (const auto& c : layer_rn_convs) layer_rn->push_back(c);
  for (int i = 0; i < 4; ++i) {
    refinenet.push_back(
        register_module("refinenet" + std::to_string(i + 1), FeatureFusionBlock(features)));
  }
}

DptAdapterImpl::DptAdapterImpl(const Dust3rConfig& c) : hooks(c.dpt.hooks), patch(c.patch_size) {
  const DptHeadConfig& h = c.dpt;
  const auto& ld = h.layer_dims;
  const auto& dt = h.dim_tokens;
  using torch::nn::ConvTranspose2d;
  using torch::nn::ConvTranspose2dOptions;
  using torch::nn::Sequential;
  act_postprocess_seq = {
      Sequential(conv(dt[0], ld[0], 1),
                 ConvTranspose2d(ConvTranspose2dOptions(ld[0], ld[0], 4).stride(4))),
      Sequential(conv(dt[1], ld[1], 1),
                 ConvTranspose2d(ConvTranspose2dOptions(ld[1], ld[1], 2).stride(2))),
      Sequential(conv(dt[2], ld[2], 1)),
      Sequential(conv(dt[3], ld[3], 1), conv(ld[3], ld[3], 3, 2, 1)),
  };
  scratch = register_module("scratch", Scratch(ld, h.feature_dim));
  head = register_module(
      "head",
      Sequential(conv(h.feature_dim, h.feature_dim / 2, 3, 1, 1), torch::nn::Functional(upsample2x),
                 conv(h.feature_dim / 2, h.last_dim, 3, 1, 1),
                 torch::nn::Functional([](const at::Tensor& x) { return at::relu(x); }),
                 conv(h.last_dim, h.num_channels, 1)));
  act_postprocess = register_module("act_postprocess", torch::nn::ModuleList());
  for (const auto& s : act_postprocess_seq) act_postprocess->push_back(s);
}

at::Tensor DptAdapterImpl::forward(const std::vector<at::Tensor>& decout, int64_t H, int64_t W,
                                   const Trace& trace) {
  const int64_t nh = H / patch, nw = W / patch;
  std::vector<at::Tensor> layers(4);
  for (int i = 0; i < 4; ++i) {
    const at::Tensor& tok = decout.at(static_cast<std::size_t>(hooks[i]));
    TORCH_CHECK(tok.size(1) == nh * nw, "DPT head: ", tok.size(1), " tokens for a ", nh, "x", nw,
                " patch grid");
    // 'b (nh nw) c -> b c nh nw'; each convolution takes it in its own
    // precision (see ModelShell::to).
    at::Tensor l = tok.transpose(1, 2).reshape({tok.size(0), tok.size(2), nh, nw});
    l = forward_in_layer_precisions(act_postprocess_seq[i], l);
    if (trace.enabled()) trace.put("act_postprocess" + std::to_string(i), l);
    l = scratch->layer_rn_convs[i](l.to(scratch->layer_rn_convs[i]->weight.scalar_type()));
    if (trace.enabled()) trace.put("layer_rn" + std::to_string(i), l);
    layers[i] = l;
  }
  auto& rn = scratch->refinenet;
  at::Tensor path = rn[3](layers[3]);
  if (trace.enabled()) trace.put("refinenet4", path);
  path = path.slice(2, 0, layers[2].size(2)).slice(3, 0, layers[2].size(3));
  path = rn[2](path, layers[2]);
  if (trace.enabled()) trace.put("refinenet3", path);
  path = rn[1](path, layers[1]);
  if (trace.enabled()) trace.put("refinenet2", path);
  path = rn[0](path, layers[0]);
  if (trace.enabled()) trace.put("refinenet1", path);
  at::Tensor out = forward_in_layer_precisions(head, path);
  if (trace.enabled()) trace.put("raw", out);
  return out;
}

HeadOutput postprocess(const at::Tensor& raw, const Dust3rConfig& c) {
  const at::Tensor fmap = raw.permute({0, 2, 3, 1});  // [B, H, W, channels]
  // Contiguous first: the norm over a last dimension of stride H * W is a
  // slow strided reduction, with the same bits either way
  // (scripts/bench_cpu_kernels.py; 9 ms of the shipped model's step in
  // long3r_bench --profile-frames, docs/model_card.md).
  const at::Tensor xyz = fmap.narrow(-1, 0, 3).contiguous();
  HeadOutput out;
  if (c.depth_mode == DepthMode::kLinear) {
    out.pts3d = xyz;
  } else {
    const at::Tensor d = at::linalg_vector_norm(xyz, 2, {-1}, /*keepdim=*/true);
    const at::Tensor dir = xyz / d.clamp_min(1e-8);
    out.pts3d = c.depth_mode == DepthMode::kExp ? dir * at::expm1(d) : dir * d.square();
  }
  if (c.conf_mode != ConfMode::kNone) {
    const at::Tensor logit = fmap.select(-1, 3);
    if (c.conf_mode == ConfMode::kExp) {
      // Out of place: exp and sigmoid keep their result for autograd.
      at::Tensor e = logit.exp();
      if (std::isfinite(c.conf_vmax)) e = e.clamp_max(c.conf_vmax - c.conf_vmin);
      out.conf = e + c.conf_vmin;
    } else {
      out.conf = at::sigmoid(logit) * (c.conf_vmax - c.conf_vmin) + c.conf_vmin;
    }
  }
  return out;
}

PixelHeadImpl::PixelHeadImpl(const Dust3rConfig& config) : patch(config.patch_size) {
  if (config.head_type == HeadType::kDpt) {
    dpt = register_module("dpt", DptAdapter(config));
  } else {
    const int64_t channels = config.conf_mode == ConfMode::kNone ? 3 : 4;
    proj =
        register_module("proj", torch::nn::Linear(config.dec_embed_dim, channels * patch * patch));
  }
}

at::Tensor PixelHeadImpl::forward(const std::vector<at::Tensor>& decout, int64_t H, int64_t W,
                                  const Trace& trace) {
  if (dpt) return dpt(decout, H, W, trace);
  const at::Tensor& tokens = decout.back();  // dec_norm of the last decoder layer
  const int64_t nh = H / patch, nw = W / patch;
  TORCH_CHECK(tokens.size(1) == nh * nw, "linear head: ", tokens.size(1), " tokens for a ", nh, "x",
              nw, " patch grid");
  // 'b (nh nw) (c p p) -> b c (nh p) (nw p)', as the official transpose, view
  // and pixel_shuffle.
  const at::Tensor feat = proj(tokens).transpose(1, 2).reshape({tokens.size(0), -1, nh, nw});
  at::Tensor out = at::pixel_shuffle(feat, patch);
  if (trace.enabled()) trace.put("raw", out);
  return out;
}

// ---------------------------------------------------------------------------
// AsymmetricCroCo3DStereo

Dust3rNetImpl::Dust3rNetImpl(const Dust3rConfig& c, bool refined_branch)
    : rope(c.rope_freq), config_(c) {
  mask_token = register_parameter("mask_token", at::zeros({1, 1, c.dec_embed_dim}), false);
  patch_embed = register_module("patch_embed", PatchEmbed(3, c.enc_embed_dim, c.patch_size));
  enc_blocks = register_module("enc_blocks", torch::nn::ModuleList());
  for (int64_t i = 0; i < c.enc_depth; ++i) {
    enc.emplace_back(c.enc_embed_dim, c.enc_num_heads, c.mlp_hidden(c.enc_embed_dim), true,
                     c.norm_eps);
    enc_blocks->push_back(enc.back());
  }
  enc_norm = register_module("enc_norm", layer_norm(c.enc_embed_dim, c.norm_eps));
  decoder_embed =
      register_module("decoder_embed", torch::nn::Linear(c.enc_embed_dim, c.dec_embed_dim));
  dec_blocks = register_module("dec_blocks", torch::nn::ModuleList());
  dec_blocks2 = register_module("dec_blocks2", torch::nn::ModuleList());
  for (int64_t i = 0; i < c.dec_depth; ++i) {
    if (refined_branch) {
      dec1.emplace_back(c.dec_embed_dim, c.dec_num_heads, c.mlp_hidden(c.dec_embed_dim), c.norm_eps,
                        c.norm_im2_in_dec);
      dec_blocks->push_back(dec1.back());
    } else {
      // A seeded initialisation draws what it drew when this branch was built
      // (and then replaced): the later modules get the same values.
      skip_init_draws(decoder_block_init_draws(c.dec_embed_dim, c.mlp_hidden(c.dec_embed_dim)));
    }
    dec2.emplace_back(c.dec_embed_dim, c.dec_num_heads, c.mlp_hidden(c.dec_embed_dim), c.norm_eps,
                      c.norm_im2_in_dec);
    dec_blocks2->push_back(dec2.back());
  }
  dec_norm = register_module("dec_norm", layer_norm(c.dec_embed_dim, c.norm_eps));
  downstream_head1 = register_module("downstream_head1", PixelHead(c));
  downstream_head2 = register_module("downstream_head2", PixelHead(c));
}

Grid Dust3rNetImpl::grid(int64_t H, int64_t W) const {
  const int64_t p = config_.patch_size;
  if (H <= 0 || W <= 0 || H % p != 0 || W % p != 0) {
    throw std::invalid_argument("image size " + std::to_string(H) + "x" + std::to_string(W) +
                                " is not a positive multiple of the patch size " +
                                std::to_string(p));
  }
  return {H / p, W / p};
}

RopeTable Dust3rNetImpl::enc_rope(int64_t gh, int64_t gw, const at::Tensor& like) const {
  return rope.table(config_.enc_embed_dim / config_.enc_num_heads, gh, gw, like.device(),
                    like.scalar_type());
}

RopeTable Dust3rNetImpl::dec_rope(int64_t gh, int64_t gw, const at::Tensor& like) const {
  return rope.table(config_.dec_embed_dim / config_.dec_num_heads, gh, gw, like.device(),
                    like.scalar_type());
}

at::Tensor Dust3rNetImpl::encode(const at::Tensor& images, const Trace& trace) {
  TORCH_CHECK(images.dim() == 4 && images.size(1) == 3, "encoder: expected [B, 3, H, W], got ",
              images.sizes());
  const int64_t H = images.size(2), W = images.size(3);
  const auto g = grid(H, W);
  if (config_.patch_embed == PatchEmbedKind::kManyAR && H > W) {
    throw std::invalid_argument(
        "ManyAR_PatchEmbed models take landscape images only (W >= H), got " + std::to_string(H) +
        "x" + std::to_string(W));
  }
  at::Tensor x = patch_embed(images).to(images.scalar_type());
  if (trace.enabled()) {
    trace.put("patch_embed", x);
    trace.put("pos", grid_positions(x.size(0), g.first, g.second, x.device()));
  }
  const RopeTable r = enc_rope(g.first, g.second, x);
  return encode_tokens(std::move(x), r, trace);
}

at::Tensor Dust3rNetImpl::encode_tokens(at::Tensor x, const RopeTable& rope, const Trace& trace) {
  for (std::size_t i = 0; i < enc.size(); ++i) {
    x = enc[i](x, rope);
    if (trace.enabled()) trace.put("enc_block" + std::to_string(i), x);
  }
  x = enc_norm(x);
  if (trace.enabled()) trace.put("enc_out", x);
  return x;
}

at::Tensor Dust3rNetImpl::complete_view(const at::Tensor& masked, const at::Tensor& reference,
                                        const at::Tensor& visible) {
  TORCH_CHECK(masked.dim() == 4 && masked.sizes() == reference.sizes(),
              "cross-view completion: expected two [B, 3, H, W] images of one size, got ",
              masked.sizes(), " and ", reference.sizes());
  const Grid g = grid(masked.size(2), masked.size(3));
  const int64_t n = g.first * g.second;
  TORCH_CHECK(visible.dim() == 1 && visible.scalar_type() == at::kLong && visible.numel() > 0 &&
                  visible.numel() <= n,
              "cross-view completion: visible must be a non-empty int64 [V] of patch indices");
  const at::Tensor vis = visible.to(masked.device());
  // The visible tokens keep their own grid positions: the RoPE rows of
  // theirs, so the encoder knows where each one lies.
  at::Tensor x = patch_embed(masked).to(masked.scalar_type()).index_select(1, vis);
  const RopeTable full = enc_rope(g.first, g.second, x);
  x = encode_tokens(std::move(x), {full.cos.index_select(0, vis), full.sin.index_select(0, vis)},
                    Trace());
  const at::Tensor f2 = encode(reference, Trace());
  // Every patch of the masked view: the decoder embedding of the visible
  // ones, mask_token elsewhere.
  const at::Tensor embedded = decoder_embed(x);
  const at::Tensor filler =
      mask_token.to(embedded.scalar_type()).expand({embedded.size(0), n, embedded.size(2)});
  at::Tensor x1 = filler.index_copy(1, vis, embedded);
  const at::Tensor y = decoder_embed(f2);
  const RopeTable r = dec_rope(g.first, g.second, x1);
  for (DecoderBlock& block : dec2) x1 = block(x1, y, r, r);
  return dec_norm(x1);
}

std::pair<DecoderOutputs, DecoderOutputs> Dust3rNetImpl::decode(const at::Tensor& f1, Grid grid1,
                                                                const at::Tensor& f2, Grid grid2,
                                                                const Trace& trace) {
  TORCH_CHECK(f1.dim() == 3 && f2.dim() == 3 && f1.size(0) == f2.size(0),
              "decoder: expected [B, N, C] tokens with one batch size, got ", f1.sizes(), " and ",
              f2.sizes());
  TORCH_CHECK(f1.size(1) == grid1.first * grid1.second && f2.size(1) == grid2.first * grid2.second,
              "decoder: token counts do not match the patch grids");
  const RopeTable r1 = dec_rope(grid1.first, grid1.second, f1);
  const RopeTable r2 = grid2 == grid1 ? r1 : dec_rope(grid2.first, grid2.second, f2);
  DecoderOutputs out1{f1}, out2{f2};
  out1.reserve(dec1.size() + 1);
  out2.reserve(dec2.size() + 1);
  at::Tensor x1 = decoder_embed(f1), x2 = decoder_embed(f2);
  if (trace.enabled()) {
    trace.put("dec1.embed", x1);
    trace.put("dec2.embed", x2);
  }
  for (std::size_t i = 0; i < dec1.size(); ++i) {
    at::Tensor n1 = dec1[i](x1, x2, r1, r2);
    at::Tensor n2 = dec2[i](x2, x1, r2, r1);
    if (trace.enabled()) {
      trace.put("dec1.block" + std::to_string(i), n1);
      trace.put("dec2.block" + std::to_string(i), n2);
    }
    x1 = std::move(n1);
    x2 = std::move(n2);
    if (i + 1 < dec1.size()) {
      out1.push_back(x1);
      out2.push_back(x2);
    }
  }
  out1.push_back(dec_norm(x1));
  out2.push_back(dec_norm(x2));
  if (trace.enabled()) {
    trace.put("dec1.final", out1.back());
    trace.put("dec2.final", out2.back());
  }
  return {std::move(out1), std::move(out2)};
}

HeadOutput Dust3rNetImpl::head(int which, const DecoderOutputs& dec, int64_t H, int64_t W,
                               const Trace& trace) {
  TORCH_CHECK(which == 1 || which == 2, "head: 1 or 2");
  PixelHead& h = which == 1 ? downstream_head1 : downstream_head2;
  // Under autocast (mixed-precision training) the head runs in float32 with
  // autocast off, as the official Spann3R runs its downstream heads
  // (autocast(enabled=False) on tokens made float); libtorch 1.13 also has no
  // bfloat16 CPU kernel for the head's transposed convolutions.
  const AutocastOff autocast_off;
  DecoderOutputs tokens = dec;
  if (autocast_off.was_on()) {
    for (at::Tensor& t : tokens) t = t.to(at::kFloat);
  }
  // The postprocess (exp / square of the depth, the confidence) in float32.
  HeadOutput out = postprocess(h->forward(tokens, H, W, trace).to(at::kFloat), config_);
  // transpose_to_landscape: with PatchEmbedDust3R the tokens of a portrait
  // image are in image order, the head runs at (H, W) and only its outputs are
  // transposed.
  const bool transpose = config_.landscape_only && H > W;
  if (transpose) {
    out.pts3d = out.pts3d.transpose(1, 2);
    if (out.conf.defined()) out.conf = out.conf.transpose(1, 2);
  }
  out.pts3d = out.pts3d.contiguous();
  if (out.conf.defined()) out.conf = out.conf.contiguous();
  return out;
}

// ---------------------------------------------------------------------------
// Spann3R

Spann3rNetImpl::Spann3rNetImpl(const ModelConfig& c, bool dust3r_refined_branch) : config_(c) {
  const Dust3rConfig& d = c.dust3r;
  const ValueEncoderConfig& v = c.spann3r.value_encoder;
  dust3r = register_module("dust3r", Dust3rNet(d, dust3r_refined_branch));
  value_encoder = register_module("value_encoder", torch::nn::ModuleList());
  for (int64_t i = 0; i < v.depth; ++i) {
    value_blocks.emplace_back(v.embed_dim, v.num_heads,
                              static_cast<int64_t>(v.embed_dim * v.mlp_ratio), v.qkv_bias,
                              v.norm_eps);
    value_encoder->push_back(value_blocks.back());
  }
  value_norm = register_module("value_norm", layer_norm(v.embed_dim, v.norm_eps));
  value_out = register_module("value_out", torch::nn::Linear(v.embed_dim, v.out_dim));
  if (!c.spann3r.use_feat) {
    pos_patch_embed =
        register_module("pos_patch_embed", PatchEmbed(3, d.enc_embed_dim, d.patch_size));
  }
  const int64_t cm = v.out_dim;
  norm_q = register_module("norm_q", layer_norm(cm, c.spann3r.norm_qkv_eps));
  norm_k = register_module("norm_k", layer_norm(cm, c.spann3r.norm_qkv_eps));
  norm_v = register_module("norm_v", layer_norm(cm, c.spann3r.norm_qkv_eps));
  const int64_t kin = d.enc_embed_dim + d.dec_embed_dim;
  auto make_head = [&]() {
    return torch::nn::Sequential(
        torch::nn::Linear(kin, kin),
        torch::nn::Functional([](const at::Tensor& x) { return at::gelu(x); }),
        torch::nn::Linear(kin, cm));
  };
  attn_head_1 = register_module("attn_head_1", make_head());
  attn_head_2 = register_module("attn_head_2", make_head());
}

at::Tensor Spann3rNetImpl::feat_key(int num, const at::Tensor& feat, const at::Tensor& dec_last) {
  const at::Tensor x = at::cat({feat, dec_last}, -1);
  return num == 1 ? attn_head_1->forward(x) : attn_head_2->forward(x);
}

at::Tensor Spann3rNetImpl::cur_value(const at::Tensor& pts3d, const at::Tensor& dec_last,
                                     int64_t gh, int64_t gw) {
  at::Tensor x;
  int64_t vh = gh, vw = gw;
  if (config_.spann3r.use_feat) {
    x = dec_last;
  } else {
    const int64_t p = config_.dust3r.patch_size;
    vh = pts3d.size(1) / p;
    vw = pts3d.size(2) / p;
    // The float32 pointmap goes to the convolution as it is; its tokens then
    // continue in the model's precision.
    x = pos_patch_embed(pts3d.permute({0, 3, 1, 2})).to(dec_last.scalar_type());
  }
  RopeTable r;
  if (config_.spann3r.mem_pos_enc) {
    const ValueEncoderConfig& v = config_.spann3r.value_encoder;
    r = dust3r->rope.table(v.embed_dim / v.num_heads, vh, vw, x.device(), x.scalar_type());
  }
  for (Block& b : value_blocks) x = b(x, r);
  return value_out(value_norm(x));
}

GatingNorms Spann3rNetImpl::gating_norms() const {
  auto params = [](const LayerNorm& n) {
    return LayerNormParams{n->weight, n->bias, n->options.eps()};
  };
  return {params(norm_q), params(norm_k), params(norm_v)};
}

// ---------------------------------------------------------------------------
// Streaming front-end helpers.

void StreamShape::check(const at::Tensor& image, bool first_frame, const Dust3rNetImpl& net,
                        const char* who) {
  if (image.dim() != 4 || image.size(1) != 3) {
    throw std::invalid_argument(std::string(who) + ": expected a [B, 3, H, W] image");
  }
  if (first_frame) {
    net.grid(image.size(2), image.size(3));  // validates the size
    H = image.size(2);
    W = image.size(3);
    batch = image.size(0);
  } else if (image.size(2) != H || image.size(3) != W || image.size(0) != batch) {
    throw std::invalid_argument(std::string(who) + ": all frames of a stream need one shape");
  }
}

void StreamShape::put(StateDict& state) const {
  put_int(state, "height", H);
  put_int(state, "width", W);
  put_int(state, "batch", batch);
}

int64_t StreamShape::read(const StateReader& state, const Dust3rNetImpl& net) {
  H = state.integer("height", 1, 1 << 15);
  W = state.integer("width", 1, 1 << 15);
  batch = state.integer("batch", 1, 1 << 10);
  try {
    const Grid g = net.grid(H, W);
    return g.first * g.second;
  } catch (const std::exception& e) {
    state.fail("height", e.what());
  }
}

void put_head_layers(StateDict& state, const std::string& prefix, const DecoderOutputs& layers) {
  put_int(state, prefix + ".layers", static_cast<int64_t>(layers.size()));
  for (std::size_t i = 0; i < layers.size(); ++i) {
    if (layers[i].defined()) state[prefix + "." + std::to_string(i)] = layers[i];
  }
}

DecoderOutputs read_head_layers(const StateReader& state, const std::string& prefix,
                                const Dust3rConfig& config, int64_t batch, int64_t tokens,
                                const at::TensorOptions& options) {
  const int64_t layers =
      state.integer(prefix + ".layers", config.dec_depth + 1, config.dec_depth + 1);
  DecoderOutputs out(static_cast<std::size_t>(layers), at::ones({1}));
  keep_head_layers(out, config);  // the layers the head reads must be there
  for (std::size_t i = 0; i < out.size(); ++i) {
    if (out[i].defined()) {
      out[i] = state.floating(prefix + "." + std::to_string(i), {batch, tokens, -1}).to(options);
    }
  }
  return out;
}

void keep_head_layers(DecoderOutputs& dec, const Dust3rConfig& config) {
  std::vector<bool> hooked(dec.size(), false);
  if (config.head_type == HeadType::kLinear) {
    hooked.back() = true;  // the linear head reads the last layer only
  } else {
    for (int64_t h : config.dpt.hooks) hooked.at(static_cast<std::size_t>(h)) = true;
  }
  for (std::size_t i = 0; i < hooked.size(); ++i) {
    if (!hooked[i]) dec[i] = at::Tensor();
  }
}

double ms_since(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

}  // namespace model
}  // namespace long3r

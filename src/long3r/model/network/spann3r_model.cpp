// Spann3R streaming inference; see include/long3r/model/network/spann3r_model.hpp.
#include "long3r/model/network/spann3r_model.hpp"

#include <ATen/ATen.h>
#include <c10/core/InferenceMode.h>

#include <stdexcept>

#include "long3r/model/network/modules.hpp"

namespace long3r {

using model::Clock;
using model::ms_since;

struct Spann3rModel::Impl {
  explicit Impl(const ModelConfig& c) : config(c), net(c) {
    for (auto& p : net->parameters()) p.set_requires_grad(false);
    net->eval();
    new_memory();
  }

  void new_memory() {
    memory = std::make_unique<Spann3rMemory>(net->gating_norms(), config.spatial_memory);
  }

  void reset() {
    frames = 0;
    first_image = at::Tensor();
    feat2 = feat_k2 = at::Tensor();
    last_dec2.clear();
    memory->reset();
  }

  const ModelConfig& config;
  model::Spann3rNet net;
  std::unique_ptr<Spann3rMemory> memory;
  Trace trace;

  // Stream state.
  int64_t frames = 0;
  model::StreamShape shape;
  at::Tensor first_image;           // frame 0 until frame 1 arrives
  at::Tensor feat2;                 // encoder features of the newest frame
  at::Tensor feat_k2;               // query of the next memory read
  model::DecoderOutputs last_dec2;  // coarse branch of the last step (for flush)
};

Spann3rModel::Spann3rModel(const ModelConfig& config)
    : ModelShell(config, ModelKind::kSpann3r, "Spann3rModel needs a Spann3R config"),
      impl_(std::make_unique<Impl>(ModelShell::config())) {
  set_module(impl_->net.ptr());
}

Spann3rModel::~Spann3rModel() = default;

std::unique_ptr<Spann3rModel> Spann3rModel::from_file(const std::string& path) {
  return model_from_checkpoint<Spann3rModel>(read_model_checkpoint(path), path);
}

// The memory references the norm parameters: a new one after a move.
void Spann3rModel::weights_changed() {
  impl_->new_memory();
  impl_->reset();
}

bool Spann3rModel::accepts_portrait() const { return !config().dust3r.landscape_only; }

const Spann3rMemory& Spann3rModel::memory() const { return *impl_->memory; }

void Spann3rModel::set_trace(const Trace& trace) { impl_->trace = trace; }

int64_t Spann3rModel::frames_pushed() const { return impl_->frames; }

void Spann3rModel::reset() { impl_->reset(); }

std::optional<StreamOutput> Spann3rModel::push(const at::Tensor& image) {
  Impl& s = *impl_;
  model::Dust3rNet& dust3r = s.net->dust3r;
  s.shape.check(image, s.frames == 0, *dust3r, "Spann3rModel::push");
  c10::InferenceMode guard;
  const auto t0 = Clock::now();
  const at::Tensor img = image.to(device(), dtype());
  if (s.frames == 0) {
    s.first_image = img;
    s.frames = 1;
    return std::nullopt;
  }

  const int64_t k = s.frames - 1;  // step k: pair (frame k, frame k+1)
  const Trace trace = s.trace.child("step" + std::to_string(k) + ".");
  const int64_t B = img.size(0);
  const int64_t H = s.shape.H, W = s.shape.W;
  const auto g = dust3r->grid(H, W);

  at::Tensor feat1, feat2;
  if (k == 0) {
    // Official encode_image_pairs: both frames in one batch.
    TensorMap records;
    const at::Tensor f =
        dust3r->encode(at::cat({s.first_image, img}), trace.enabled() ? Trace(&records) : Trace());
    for (const auto& kv : records) {
      trace.put("img1." + kv.first, kv.second.narrow(0, 0, B));
      trace.put("img2." + kv.first, kv.second.narrow(0, B, B));
    }
    feat1 = f.narrow(0, 0, B);
    feat2 = f.narrow(0, B, B);
    s.first_image = at::Tensor();
  } else {
    feat1 = s.feat2;
    feat2 = dust3r->encode(img, trace.child("img2."));
  }
  StreamOutput out;
  out.frame_index = k;
  out.stats.encode_ms = ms_since(t0);

  const auto t1 = Clock::now();
  at::Tensor feat_fuse = feat1;
  if (k > 0) {
    feat_fuse = s.memory->read(s.feat_k2, /*residual=*/true, /*keep_attention=*/trace.enabled());
    trace.put("feat_fuse", feat_fuse);
  }
  auto dec = dust3r->decode(feat_fuse, g, feat2, g, trace);
  const at::Tensor feat_k1 = s.net->feat_key(1, feat1, dec.first.back());
  s.feat_k2 = s.net->feat_key(2, feat2, dec.second.back());
  model::HeadOutput res1 = dust3r->head(1, dec.first, H, W, trace.child("head1."));
  out.stats.decode_ms = ms_since(t1);

  const auto t2 = Clock::now();
  const at::Tensor cur_v = s.net->cur_value(res1.pts3d, dec.first.back(), g.first, g.second);
  s.memory->add_mem_check(feat_k1, cur_v + feat_k1);
  out.stats.memory_ms = ms_since(t2);
  if (trace.enabled()) {
    trace.put("feat_k1", feat_k1);
    trace.put("feat_k2", s.feat_k2);
    trace.put("cur_v", cur_v);
    trace.put("pts3d", res1.pts3d);
    if (res1.conf.defined()) trace.put("conf", res1.conf);
  }

  s.feat2 = feat2;
  // Only the layers head 2 reads are needed for flush().
  s.last_dec2 = std::move(dec.second);
  model::keep_head_layers(s.last_dec2, config().dust3r);
  s.frames += 1;

  const Spann3rMemory& m = *s.memory;
  const int64_t working = m.working_frames() * m.num_patches();
  out.stats.mem_short_tokens = std::min(working, m.size());
  out.stats.mem_long_tokens = m.size() - out.stats.mem_short_tokens;
  out.stats.memory_write_skipped = m.last_add().skipped;
  out.pts3d = std::move(res1.pts3d);
  out.conf = std::move(res1.conf);
  return out;
}

StateDict Spann3rModel::stream_state() const {
  const Impl& s = *impl_;
  StateDict out;
  put_int(out, "frames", s.frames);
  if (s.frames == 0) return out;
  s.shape.put(out);
  if (s.frames == 1) {
    out["first_image"] = s.first_image;
    return out;
  }
  out["feat2"] = s.feat2;
  out["feat_k2"] = s.feat_k2;
  model::put_head_layers(out, "last_dec2", s.last_dec2);
  const Spann3rMemoryState m = s.memory->state();
  put_int(out, "memory.working_frames", m.working_frames);
  put_int(out, "memory.long_mem_counter", m.long_mem_counter);
  put_int(out, "memory.num_patches", m.num_patches);
  if (m.keys.defined()) {
    out["memory.keys"] = m.keys;
    out["memory.values"] = m.values;
    out["memory.mem_attn"] = m.mem_attn;
    out["memory.mem_count"] = m.mem_count;
  }
  return out;
}

void Spann3rModel::restore_stream_state(const StateDict& state) {
  Impl& s = *impl_;
  c10::InferenceMode guard;
  const StateReader r(state, "spann3r stream state");
  constexpr int64_t kMax = int64_t{1} << 53;
  const int64_t frames = r.integer("frames", 0, kMax);
  if (frames == 0) {
    s.reset();
    return;
  }
  const Dust3rConfig& dc = config().dust3r;
  model::StreamShape shape;
  const int64_t P = shape.read(r, *s.net->dust3r), B = shape.batch, C = config().memory_dim();
  const at::TensorOptions opts = at::TensorOptions().device(device()).dtype(dtype());
  if (frames == 1) {
    const at::Tensor first = r.floating("first_image", {B, 3, shape.H, shape.W}).to(opts);
    s.reset();
    s.frames = 1;
    s.shape = shape;
    s.first_image = first;
    return;
  }
  const at::Tensor feat2 = r.floating("feat2", {B, P, dc.enc_embed_dim}).to(opts);
  const at::Tensor feat_k2 = r.floating("feat_k2", {B, P, C}).to(opts);
  model::DecoderOutputs last_dec2 = model::read_head_layers(r, "last_dec2", dc, B, P, opts);
  Spann3rMemoryState m;
  m.working_frames = r.integer("memory.working_frames", 0, kMax);
  m.long_mem_counter = r.integer("memory.long_mem_counter", 0, kMax);
  m.num_patches = r.integer("memory.num_patches", 0, kMax);
  if (r.has("memory.keys")) {
    m.keys = r.floating("memory.keys", {B, -1, C}).to(opts);
    const int64_t M = m.keys.size(1);
    m.values = r.floating("memory.values", {B, M, C}).to(opts);
    m.mem_attn = r.floating("memory.mem_attn", {B, M}).to(opts);
    m.mem_count = r.floating("memory.mem_count", {B, M}).to(opts);
  }
  s.reset();
  s.memory->set_state(m);
  s.frames = frames;
  s.shape = shape;
  s.feat2 = feat2;
  s.feat_k2 = feat_k2;
  s.last_dec2 = std::move(last_dec2);
}

ModelIdentity Spann3rModel::identity() const {
  return {variant(), model_config_to_json(config()), weights_fingerprint()};
}

std::optional<StreamOutput> Spann3rModel::peek_last() {
  Impl& s = *impl_;
  if (s.frames < 2) return std::nullopt;
  c10::InferenceMode guard;
  const auto t0 = Clock::now();
  const Trace trace = s.trace.child("flush.");
  model::HeadOutput res2 =
      s.net->dust3r->head(2, s.last_dec2, s.shape.H, s.shape.W, trace.child("head2."));
  StreamOutput out;
  out.frame_index = s.frames - 1;
  out.from_coarse_head = true;
  out.stats.decode_ms = ms_since(t0);
  const Spann3rMemory& m = *s.memory;
  out.stats.mem_short_tokens = std::min(m.working_frames() * m.num_patches(), m.size());
  out.stats.mem_long_tokens = m.size() - out.stats.mem_short_tokens;
  if (trace.enabled()) {
    trace.put("pts3d", res2.pts3d);
    if (res2.conf.defined()) trace.put("conf", res2.conf);
  }
  out.pts3d = std::move(res2.pts3d);
  out.conf = std::move(res2.conf);
  return out;
}

}  // namespace long3r

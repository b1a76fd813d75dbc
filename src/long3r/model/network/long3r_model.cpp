// LONG3R streaming inference and training forward; see
// include/long3r/model/network/long3r_model.hpp.
#include "long3r/model/network/long3r_model.hpp"

#include <ATen/ATen.h>
#include <c10/core/InferenceMode.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "long3r/model/network/long3r_modules.hpp"

namespace long3r {

using model::Clock;
using model::ms_since;

struct Long3rModel::Impl {
  explicit Impl(const ModelConfig& c) : config(c), net(c), memory(c.long3r) { apply_mode(); }

  void apply_mode() {
    for (auto& p : net->parameters()) p.set_requires_grad(training);
    net->train(training);
    memory.set_training(training);
  }

  void reset() {
    frames = 0;
    feat = coarse_final = at::Tensor();
    last_coarse.clear();
    coarse_head = model::HeadOutput();
    memory.reset();
  }

  const ModelConfig& config;
  model::Long3rNet net;
  SpatioTemporalMemory memory;
  bool training = false;
  bool projection_cache = true;  // set_memory_projection_cache()
  bool collect_coarse = false;   // run head2 at every step (training targets)
  // forward_sequence's last push: its memory write would never be read (the
  // stream ends with flush(), which empties the memory), so it is skipped.
  bool write_memory = true;

  // Stream state.
  int64_t frames = 0;
  model::StreamShape shape;
  at::Tensor feat;                    // F^I of the newest frame
  at::Tensor coarse_final;            // F^c of the newest frame (y_B of the last step)
  model::DecoderOutputs last_coarse;  // coarse branch of the last step (for flush)
  model::HeadOutput coarse_head;      // head2 of the last step, when computed eagerly
};

Long3rModel::Long3rModel(const ModelConfig& config)
    : ModelShell(config, ModelKind::kLong3r, "Long3rModel needs a LONG3R config"),
      impl_(std::make_unique<Impl>(ModelShell::config())) {
  set_module(impl_->net.ptr());
}

Long3rModel::~Long3rModel() = default;

std::unique_ptr<Long3rModel> Long3rModel::from_file(const std::string& path) {
  return model_from_checkpoint<Long3rModel>(read_model_checkpoint(path), path);
}

void Long3rModel::weights_changed() { impl_->reset(); }

void Long3rModel::set_training(bool training) {
  impl_->training = training;
  impl_->apply_mode();
  impl_->reset();
}

bool Long3rModel::training() const { return impl_->training; }

void Long3rModel::set_memory_projection_cache(bool on) {
  impl_->projection_cache = on;
  impl_->reset();
}

bool Long3rModel::memory_projection_cache() const { return impl_->projection_cache; }

const SpatioTemporalMemory& Long3rModel::memory() const { return impl_->memory; }

int64_t Long3rModel::frames_pushed() const { return impl_->frames; }

void Long3rModel::reset() { impl_->reset(); }

std::optional<StreamOutput> Long3rModel::push(const at::Tensor& image) {
  Impl& s = *impl_;
  model::Dust3rNet& dust3r = s.net->dust3r;
  s.shape.check(image, s.frames == 0, *dust3r, "Long3rModel::push");
  std::optional<c10::InferenceMode> guard;
  if (!s.training) guard.emplace();
  const auto t0 = Clock::now();
  const at::Tensor img = image.to(device(), dtype());
  const at::Tensor next = dust3r->encode(img, Trace());
  const bool cached = s.projection_cache && !s.training;
  if (s.frames == 0) {
    s.feat = next;
    s.frames = 1;
    return std::nullopt;
  }

  const int64_t t = s.frames - 1;  // step t: frame t refined, frame t+1 coarse
  const int64_t H = s.shape.H, W = s.shape.W;
  const auto g = dust3r->grid(H, W);
  StreamOutput out;
  out.frame_index = t;
  out.stats.encode_ms = ms_since(t0);

  // Steps 2-3: query, gating, relevant set.
  const auto t1 = Clock::now();
  at::Tensor fused = s.feat;
  model::RelevantMemory relevant;
  if (!s.memory.empty()) {
    const at::Tensor query = s.net->feat_key(2, s.feat, s.coarse_final);
    const GatingResult gate = s.memory.read(query, s.feat, s.net->gating_norms());
    fused = gate.fused;
    if (cached) {
      relevant.projected = s.memory.gather_payload(gate.relevant_index);
    } else {
      relevant.keys = gather_tokens(s.memory.keys(), gate.relevant_index);
      relevant.values = gather_tokens(s.memory.values(), gate.relevant_index);
    }
    // B = 1 has no padding; the unmasked attention path is then exact.
    if (s.shape.batch > 1) relevant.valid = gate.relevant_valid;
    // The largest relevant set of the batch: the width of the padded index
    // (no second read of the count from the device).
    out.stats.relevant_tokens = gate.relevant_index.size(1);
  } else {
    out.stats.relevant_tokens = 0;
  }

  // Steps 4-5: joint decoding and heads.
  model::JointDecoderOutputs dec = s.net->decode_joint(fused, next, g, relevant);
  model::HeadOutput res1 = dust3r->head(1, dec.refined, H, W, Trace());
  if (s.training || s.collect_coarse) {
    s.coarse_head = dust3r->head(2, dec.coarse, H, W, Trace());
  }
  out.stats.decode_ms = ms_since(t1);

  // Step 6: memory write of frame t, on the image's token grid.
  const auto t2 = Clock::now();
  if (s.write_memory) {
    at::Tensor pts = res1.pts3d, conf = res1.conf;
    if (pts.size(1) != H) {  // landscape_only transposed a portrait map
      pts = pts.transpose(1, 2).contiguous();
      if (conf.defined()) conf = conf.transpose(1, 2).contiguous();
    }
    if (!conf.defined()) conf = at::ones(pts.sizes().slice(0, 3), pts.options());
    const at::Tensor key = s.net->feat_key(1, s.feat, dec.refined.back());
    const at::Tensor value = s.net->cur_value(pts, dec.refined.back(), g.first, g.second) + key;
    const at::Tensor positions = token_positions(pts, conf, s.config.dust3r.patch_size);
    s.memory.add_frame(key, value, positions, t, {g.first, g.second},
                       cached ? s.net->project_memory(key, value) : at::Tensor());
  }
  out.stats.memory_ms = ms_since(t2);

  s.feat = next;
  s.coarse_final = dec.coarse.back();
  // Only the layers head 2 reads are needed for flush().
  s.last_coarse = std::move(dec.coarse);
  model::keep_head_layers(s.last_coarse, s.config.dust3r);
  s.frames += 1;

  out.stats.mem_short_tokens = s.memory.short_size();
  const std::vector<int64_t> longs = s.memory.long_sizes();
  out.stats.mem_long_tokens = longs.empty() ? 0 : *std::max_element(longs.begin(), longs.end());
  const std::vector<double> v_scene = s.memory.v_scene();
  out.stats.voxel_size = !v_scene.empty() && std::isfinite(v_scene[0]) ? v_scene[0] : 0.0;
  out.pts3d = std::move(res1.pts3d);
  out.conf = std::move(res1.conf);
  return out;
}

StateDict Long3rModel::stream_state() const {
  const Impl& s = *impl_;
  if (s.training) throw std::logic_error("Long3rModel: no stream state in training mode");
  StateDict out;
  put_int(out, "frames", s.frames);
  if (s.frames == 0) return out;
  s.shape.put(out);
  out["feat"] = s.feat;
  if (s.frames >= 2) {
    out["coarse_final"] = s.coarse_final;
    model::put_head_layers(out, "last_coarse", s.last_coarse);
  }
  put_state(out, "memory.", s.memory.state());
  return out;
}

void Long3rModel::restore_stream_state(const StateDict& state) {
  Impl& s = *impl_;
  if (s.training) throw std::logic_error("Long3rModel: no stream state in training mode");
  c10::InferenceMode guard;
  const StateReader r(state, "long3r stream state");
  const int64_t frames = r.integer("frames", 0, int64_t{1} << 53);
  if (frames == 0) {
    s.reset();
    return;
  }
  const Dust3rConfig& dc = config().dust3r;
  model::StreamShape shape;
  const int64_t P = shape.read(r, *s.net->dust3r), B = shape.batch;
  const at::TensorOptions opts = at::TensorOptions().device(device()).dtype(dtype());
  const at::Tensor feat = r.floating("feat", {B, P, dc.enc_embed_dim}).to(opts);
  at::Tensor coarse_final;
  model::DecoderOutputs last_coarse;
  if (frames >= 2) {
    coarse_final = r.floating("coarse_final", {B, P, dc.dec_embed_dim}).to(opts);
    last_coarse = model::read_head_layers(r, "last_coarse", dc, B, P, opts);
  }
  SpatioTemporalMemory memory(s.memory.config());
  SpatioTemporalMemory::PayloadFn payload;
  if (s.projection_cache) {
    payload = [&s](const at::Tensor& k, const at::Tensor& v) {
      return s.net->project_memory(k, v);
    };
  }
  try {
    memory.restore(r.child("memory."), opts, payload);
  } catch (const c10::Error& e) {  // the projections refused the tokens' width
    r.fail("memory", std::string("does not fit this model: ") + e.what_without_backtrace());
  }
  if (memory.batch_size() != 0 && memory.batch_size() != B) {
    r.fail("memory.batch", "memory of " + std::to_string(memory.batch_size()) +
                               " streams, frames of " + std::to_string(B));
  }
  s.reset();
  s.frames = frames;
  s.shape = shape;
  s.feat = feat;
  s.coarse_final = coarse_final;
  s.last_coarse = std::move(last_coarse);
  s.memory = std::move(memory);
}

ModelIdentity Long3rModel::identity() const {
  return {variant(), model_config_to_json(config()), weights_fingerprint()};
}

std::optional<StreamOutput> Long3rModel::peek_last() {
  Impl& s = *impl_;
  if (s.frames < 2) return std::nullopt;
  std::optional<c10::InferenceMode> guard;
  if (!s.training) guard.emplace();
  const auto t0 = Clock::now();
  model::HeadOutput res2 =
      s.coarse_head.pts3d.defined()
          ? s.coarse_head
          : s.net->dust3r->head(2, s.last_coarse, s.shape.H, s.shape.W, Trace());
  StreamOutput out;
  out.frame_index = s.frames - 1;
  out.from_coarse_head = true;
  out.stats.decode_ms = ms_since(t0);
  out.stats.mem_short_tokens = s.memory.short_size();
  const std::vector<int64_t> longs = s.memory.long_sizes();
  out.stats.mem_long_tokens = longs.empty() ? 0 : *std::max_element(longs.begin(), longs.end());
  out.pts3d = std::move(res2.pts3d);
  out.conf = std::move(res2.conf);
  return out;
}

at::Tensor Long3rModel::complete_view(const at::Tensor& masked, const at::Tensor& reference,
                                      const at::Tensor& visible) {
  std::optional<c10::InferenceMode> guard;
  if (!impl_->training) guard.emplace();
  return impl_->net->dust3r->complete_view(masked.to(device(), dtype()),
                                           reference.to(device(), dtype()), visible);
}

std::vector<StreamOutput> Long3rModel::forward_sequence(const std::vector<at::Tensor>& frames,
                                                        std::vector<StreamOutput>* coarse) {
  if (frames.size() < 2) {
    throw std::invalid_argument("Long3rModel::forward_sequence: needs at least 2 frames");
  }
  Impl& s = *impl_;
  s.reset();
  s.collect_coarse = coarse != nullptr;
  if (coarse != nullptr) coarse->clear();
  std::vector<StreamOutput> outs;
  try {
    for (std::size_t i = 0; i < frames.size(); ++i) {
      s.write_memory = i + 1 < frames.size();
      std::optional<StreamOutput> o = push(frames[i]);
      if (!o) continue;
      if (coarse != nullptr) {
        StreamOutput c;
        c.frame_index = o->frame_index + 1;
        c.from_coarse_head = true;
        c.pts3d = s.coarse_head.pts3d;
        c.conf = s.coarse_head.conf;
        coarse->push_back(std::move(c));
      }
      outs.push_back(std::move(*o));
    }
    s.write_memory = true;
    outs.push_back(*flush());
  } catch (...) {
    s.collect_coarse = false;
    s.write_memory = true;
    s.reset();
    throw;
  }
  s.collect_coarse = false;
  return outs;
}

}  // namespace long3r

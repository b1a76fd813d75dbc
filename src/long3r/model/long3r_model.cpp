// LONG3R streaming inference and training forward; see
// include/long3r/model/long3r_model.hpp.
#include "long3r/model/long3r_model.hpp"

#include <ATen/ATen.h>
#include <c10/core/InferenceMode.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <stdexcept>

#include "long3r/model/checkpoint.hpp"
#include "long3r/model/long3r_modules.hpp"
#include "long3r/model/safetensors.hpp"

namespace long3r {

namespace {

using Clock = std::chrono::steady_clock;

double ms_since(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

LayerNormParams norm_params(const torch::nn::LayerNorm& n) {
  return {n->weight, n->bias, n->options.eps()};
}

}  // namespace

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

  at::Device device() const { return net->value_out->weight.device(); }

  GatingNorms norms() const {
    return {norm_params(net->norm_q), norm_params(net->norm_k), norm_params(net->norm_v)};
  }

  ModelConfig config;
  model::Long3rNet net;
  SpatioTemporalMemory memory;
  bool training = false;
  bool projection_cache = true;  // set_memory_projection_cache()
  bool collect_coarse = false;   // run head2 at every step (training targets)

  // Stream state.
  int64_t frames = 0;
  int64_t H = 0, W = 0, batch = 0;
  at::Tensor feat;                    // F^I of the newest frame
  at::Tensor coarse_final;            // F^c of the newest frame (y_B of the last step)
  model::DecoderOutputs last_coarse;  // coarse branch of the last step (for flush)
  model::HeadOutput coarse_head;      // head2 of the last step, when computed eagerly
};

Long3rModel::Long3rModel(const ModelConfig& config) {
  if (config.kind != ModelKind::kLong3r) {
    throw ModelConfigError(std::string("Long3rModel needs a LONG3R config, got ") +
                           model_kind_name(config.kind));
  }
  validate_model_config(config);
  impl_ = std::make_unique<Impl>(config);
}

Long3rModel::~Long3rModel() = default;

std::unique_ptr<Long3rModel> Long3rModel::from_file(const std::string& path) {
  const TensorFile file = load_safetensors(path);
  auto model = std::make_unique<Long3rModel>(model_config_from_metadata(file.metadata, path));
  model->load_weights(file.tensors, path);
  return model;
}

void Long3rModel::load_weights(const TensorMap& tensors, const std::string& source_name,
                               const std::string& strip_prefix) {
  load_module_strict(*impl_->net, tensors, source_name, strip_prefix);
  impl_->reset();
}

void Long3rModel::save(const std::string& path) const {
  TensorMap tensors;
  for (const auto& kv : impl_->net->named_parameters()) {
    tensors[kv.key()] = kv.value().detach().to(at::kCPU).contiguous();
  }
  for (const auto& kv : impl_->net->named_buffers()) {
    tensors[kv.key()] = kv.value().detach().to(at::kCPU).contiguous();
  }
  save_safetensors(path, tensors, {{"config", model_config_to_json(impl_->config)}});
}

const ModelConfig& Long3rModel::config() const { return impl_->config; }

void Long3rModel::to(const at::Device& device) {
  impl_->net->to(device);
  impl_->reset();
}

at::Device Long3rModel::device() const { return impl_->device(); }

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

torch::nn::Module& Long3rModel::module() { return *impl_->net; }

const SpatioTemporalMemory& Long3rModel::memory() const { return impl_->memory; }

int64_t Long3rModel::frames_pushed() const { return impl_->frames; }

void Long3rModel::reset() { impl_->reset(); }

std::optional<StreamOutput> Long3rModel::push(const at::Tensor& image) {
  Impl& s = *impl_;
  if (image.dim() != 4 || image.size(1) != 3) {
    throw std::invalid_argument("Long3rModel::push: expected a [B, 3, H, W] image");
  }
  model::Dust3rNet& dust3r = s.net->dust3r;
  if (s.frames == 0) {
    dust3r->grid(image.size(2), image.size(3));  // validates the size
    s.H = image.size(2);
    s.W = image.size(3);
    s.batch = image.size(0);
  } else if (image.size(2) != s.H || image.size(3) != s.W || image.size(0) != s.batch) {
    throw std::invalid_argument("Long3rModel::push: all frames of a stream need one shape");
  }
  std::optional<c10::InferenceMode> guard;
  if (!s.training) guard.emplace();
  const auto t0 = Clock::now();
  const at::Tensor img = image.to(s.device(), at::kFloat);
  const at::Tensor next = dust3r->encode(img, Trace());
  const bool cached = s.projection_cache && !s.training;
  if (s.frames == 0) {
    s.feat = next;
    s.frames = 1;
    return std::nullopt;
  }

  const int64_t t = s.frames - 1;  // step t: frame t refined, frame t+1 coarse
  const auto g = dust3r->grid(s.H, s.W);
  StreamOutput out;
  out.frame_index = t;
  out.stats.encode_ms = ms_since(t0);

  // Steps 2-3: query, gating, relevant set.
  const auto t1 = Clock::now();
  at::Tensor fused = s.feat;
  model::RelevantMemory relevant;
  if (!s.memory.empty()) {
    const at::Tensor query = s.net->feat_key(2, s.feat, s.coarse_final);
    const GatingResult gate = s.memory.read(query, s.feat, s.norms());
    fused = gate.fused;
    if (cached) {
      relevant.projected = s.memory.gather_payload(gate.relevant_index);
    } else {
      relevant.keys = gather_tokens(s.memory.keys(), gate.relevant_index);
      relevant.values = gather_tokens(s.memory.values(), gate.relevant_index);
    }
    // B = 1 has no padding; the unmasked attention path is then exact.
    if (s.batch > 1) relevant.valid = gate.relevant_valid;
    out.stats.relevant_tokens = gate.relevant_count.max().item<int64_t>();
  } else {
    out.stats.relevant_tokens = 0;
  }

  // Steps 4-5: joint decoding and heads.
  model::JointDecoderOutputs dec = s.net->decode_joint(fused, next, g, relevant);
  model::HeadOutput res1 = dust3r->head(1, dec.refined, s.H, s.W, Trace());
  if (s.training || s.collect_coarse) {
    s.coarse_head = dust3r->head(2, dec.coarse, s.H, s.W, Trace());
  }
  out.stats.decode_ms = ms_since(t1);

  // Step 6: memory write of frame t, on the image's token grid.
  const auto t2 = Clock::now();
  at::Tensor pts = res1.pts3d, conf = res1.conf;
  if (pts.size(1) != s.H) {  // landscape_only transposed a portrait map
    pts = pts.transpose(1, 2).contiguous();
    if (conf.defined()) conf = conf.transpose(1, 2).contiguous();
  }
  if (!conf.defined()) conf = at::ones(pts.sizes().slice(0, 3), pts.options());
  const at::Tensor key = s.net->feat_key(1, s.feat, dec.refined.back());
  const at::Tensor value = s.net->cur_value(pts, dec.refined.back(), g.first, g.second) + key;
  const at::Tensor positions = token_positions(pts, conf, s.config.dust3r.patch_size);
  s.memory.add_frame(key, value, positions, t, {g.first, g.second},
                     cached ? s.net->project_memory(key, value) : at::Tensor());
  out.stats.memory_ms = ms_since(t2);

  s.feat = next;
  s.coarse_final = dec.coarse.back();
  // Only the layers head 2 reads are needed for flush().
  s.last_coarse = std::move(dec.coarse);
  std::vector<bool> hooked(s.last_coarse.size(), false);
  for (int64_t h : s.config.dust3r.dpt.hooks) hooked.at(static_cast<std::size_t>(h)) = true;
  for (std::size_t i = 0; i < hooked.size(); ++i) {
    if (!hooked[i]) s.last_coarse[i] = at::Tensor();
  }
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

std::optional<StreamOutput> Long3rModel::flush() {
  Impl& s = *impl_;
  if (s.frames < 2) {
    s.reset();
    return std::nullopt;
  }
  std::optional<c10::InferenceMode> guard;
  if (!s.training) guard.emplace();
  const auto t0 = Clock::now();
  model::HeadOutput res2 = s.coarse_head.pts3d.defined()
                               ? s.coarse_head
                               : s.net->dust3r->head(2, s.last_coarse, s.H, s.W, Trace());
  StreamOutput out;
  out.frame_index = s.frames - 1;
  out.from_coarse_head = true;
  out.stats.decode_ms = ms_since(t0);
  out.stats.mem_short_tokens = s.memory.short_size();
  const std::vector<int64_t> longs = s.memory.long_sizes();
  out.stats.mem_long_tokens = longs.empty() ? 0 : *std::max_element(longs.begin(), longs.end());
  out.pts3d = std::move(res2.pts3d);
  out.conf = std::move(res2.conf);
  s.reset();
  return out;
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
    for (const at::Tensor& f : frames) {
      std::optional<StreamOutput> o = push(f);
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
    outs.push_back(*flush());
  } catch (...) {
    s.collect_coarse = false;
    s.reset();
    throw;
  }
  s.collect_coarse = false;
  return outs;
}

}  // namespace long3r

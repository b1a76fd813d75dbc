// Training configuration file (docs/training.md) and the learning-rate schedule.
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>

#include "long3r/config/config_json.hpp"
#include "long3r/model/network/model_config.hpp"
#include "long3r/train/train_config.hpp"

namespace long3r {

int64_t TrainConfig::total_steps() const {
  int64_t n = 0;
  for (const TrainStage& s : stages) n += s.steps;
  return n;
}

TrainConfig parse_train_config(const std::string& json_text) {
  return parse_train_config(config::parse(json_text, "training config"));
}

TrainConfig parse_train_config(const nlohmann::ordered_json& root) {
  TrainConfig c;
  config::read_object(root, c, {"training config", /*inf_strings=*/false, "comment"});
  validate_train_config(c);
  return c;
}

void validate_train_config(const TrainConfig& c) {
  auto fail = [](const std::string& m) { throw ConfigError("training config: " + m); };
  if (c.stages.empty()) fail("stages: at least one stage is needed");
  for (std::size_t i = 0; i < c.stages.size(); ++i) {
    const TrainStage& s = c.stages[i];
    const std::string w = "stages[" + std::to_string(i) + "] (" + s.name + "): ";
    if (s.steps < 0) fail(w + "steps must be >= 0");
    if (s.frames < 2) fail(w + "frames must be >= 2 (the model needs pairs)");
    if (s.batch_size < 1) fail(w + "batch_size must be >= 1");
    if (!(s.lr > 0.0) || !std::isfinite(s.lr)) fail(w + "lr must be > 0");
    if (s.warmup_steps < 0) fail(w + "warmup_steps must be >= 0");
    if (s.min_lr_ratio < 0.0 || s.min_lr_ratio > 1.0) fail(w + "min_lr_ratio must be in [0, 1]");
    if (s.task != kTaskSequence && s.task != kTaskCrossViewCompletion) {
      fail(w + "task must be \"" + kTaskSequence + "\" or \"" + kTaskCrossViewCompletion + "\"");
    }
    if (s.task == kTaskCrossViewCompletion) {
      if (s.frames != 2) fail(w + "cross_view_completion takes pairs: frames must be 2");
      if (!(s.mask_ratio > 0.0 && s.mask_ratio < 1.0)) fail(w + "mask_ratio must be in (0, 1)");
    }
  }
  if (c.image_size < 16 || c.image_size % 16 != 0) fail("image_size must be a multiple of 16");
  if (c.amp != "auto" && c.amp != "bf16" && c.amp != "native" && c.amp != "off") {
    fail("amp must be \"auto\", \"bf16\", \"native\" or \"off\"");
  }
  if (c.weight_init != "torch" && c.weight_init != "croco") {
    fail("weight_init must be \"torch\" or \"croco\"");
  }
  if (!(c.loss.alpha > 0.0)) fail("loss.alpha must be > 0");
  if (c.loss.scale_weight < 0.0) fail("loss.scale_weight must be >= 0");
  if (c.weight_decay < 0.0) fail("optimizer.weight_decay must be >= 0");
  if (c.beta1 < 0.0 || c.beta1 >= 1.0 || c.beta2 < 0.0 || c.beta2 >= 1.0) {
    fail("optimizer.beta1/beta2 must be in [0, 1)");
  }
  const DataConfig& d = c.data;
  if (!d.synth.enabled && d.tum_dirs.empty() && d.datasets.empty()) {
    fail("data: no source (synth disabled, no tum_dirs, no datasets)");
  }
  if (!d.datasets.empty() && (d.synth.enabled || !d.tum_dirs.empty())) {
    fail(
        "data.datasets: the mixture is the datasets alone; set data.synth.enabled to false and "
        "leave data.tum_dirs empty");
  }
  for (std::size_t i = 0; i < d.datasets.size(); ++i) {
    const DatasetSource& ds = d.datasets[i];
    const std::string at = "data.datasets[" + std::to_string(i) + "]";
    if (std::find_if(std::begin(kDatasetLayouts), std::end(kDatasetLayouts),
                     [&](const char* l) { return ds.layout == l; }) == std::end(kDatasetLayouts)) {
      std::string known;
      for (const char* l : kDatasetLayouts) known += std::string(known.empty() ? "" : ", ") + l;
      fail(at + ".layout \"" + ds.layout + "\" is not one of " + known);
    }
    if (ds.root.empty()) fail(at + ".root is empty");
    if (ds.split.empty()) fail(at + ".split is empty");
    if (!(ds.weight > 0.0) || !std::isfinite(ds.weight)) fail(at + ".weight must be > 0");
    if (ds.min_stride < 1 || ds.max_stride < ds.min_stride) {
      fail(at + ": need 1 <= min_stride <= max_stride");
    }
  }
  if (d.min_stride < 1 || d.max_stride < d.min_stride)
    fail("data: need 1 <= min_stride <= max_stride");
  if (d.tum_fraction < 0.0 || d.tum_fraction > 1.0) fail("data.tum_fraction must be in [0, 1]");
  if (d.reverse_fraction < 0.0 || d.reverse_fraction > 1.0) {
    fail("data.reverse_fraction must be in [0, 1]");
  }
  if (d.augment.color_jitter < 0.0 || d.augment.color_jitter >= 1.0) {
    fail("data.augment.color_jitter must be in [0, 1)");
  }
  if (d.augment.max_crop < 0.0 || d.augment.max_crop >= 0.5)
    fail("data.augment.max_crop must be in [0, 0.5)");
  const SynthDataConfig& s = d.synth;
  if (s.train_scenes < 1 || s.val_scenes < 0)
    fail("data.synth: train_scenes >= 1, val_scenes >= 0");
  // Disjoint seed ranges: validation scenes are never trained on.
  const uint64_t t0 = s.train_seed_begin, t1 = t0 + static_cast<uint64_t>(s.train_scenes);
  const uint64_t v0 = s.val_seed_begin, v1 = v0 + static_cast<uint64_t>(s.val_scenes);
  if (s.val_scenes > 0 && v0 < t1 && t0 < v1) {
    fail("data.synth: validation seeds [" + std::to_string(v0) + ", " + std::to_string(v1) +
         ") overlap the training seeds [" + std::to_string(t0) + ", " + std::to_string(t1) + ")");
  }
  if (s.trajectory_frames < 2) fail("data.synth.trajectory_frames must be >= 2");
  if (!(s.speed > 0.0)) fail("data.synth.speed must be > 0");
  if (!(s.hfov_min_deg > 10.0) || s.hfov_max_deg < s.hfov_min_deg || s.hfov_max_deg >= 150.0) {
    fail("data.synth: need 10 < hfov_min_deg <= hfov_max_deg < 150");
  }
  if (s.render_size != 0 && s.render_size < c.image_size)
    fail("data.synth.render_size must be 0 or >= image_size");
  for (const TrainStage& st : c.stages) {
    if (s.enabled && d.tum_dirs.empty() &&
        (st.frames - 1) * d.min_stride + 1 > s.trajectory_frames) {
      fail("data.synth.trajectory_frames is too short for " + std::to_string(st.frames) +
           " frames at min_stride " + std::to_string(d.min_stride));
    }
  }
  const ValidationConfig& v = c.validation;
  if (v.every < 0 || v.sequences < 0) fail("validation: every and sequences must be >= 0");
  if (v.sequences > 0) {
    if (v.frames < 3) fail("validation.frames must be >= 3 (ATE needs 3 poses)");
    if (v.stride < 1) fail("validation.stride must be >= 1");
    if (v.pixel_step < 1) fail("validation.pixel_step must be >= 1");
    if ((!s.enabled && d.datasets.empty()) || v.sequences > s.val_scenes) {
      fail("validation.sequences needs synth data with at least that many val_scenes");
    }
    if ((v.frames - 1) * v.stride + 1 > s.trajectory_frames) {
      fail("validation: frames x stride exceeds data.synth.trajectory_frames");
    }
  }
  if (v.blind_scenes < 0) fail("validation.blind_scenes must be >= 0");
  if (v.blind_scenes > 0) {
    if (v.sequences < 1)
      fail("validation.blind_scenes runs with validation: sequences must be >= 1");
    if (v.blind_starts < 1) fail("validation.blind_starts must be >= 1");
    if (v.blind_frames < 2) fail("validation.blind_frames must be >= 2");
    if (v.blind_strides.empty()) fail("validation.blind_strides: at least one stride");
    if (!s.enabled || v.blind_scenes > s.val_scenes) {
      fail("validation.blind_scenes needs synth data with at least that many val_scenes");
    }
    for (const int64_t stride : v.blind_strides) {
      if (stride < 1 || (v.blind_frames - 1) * stride + 1 > s.trajectory_frames) {
        fail(
            "validation.blind_strides: each stride must be >= 1 and fit blind_frames into "
            "data.synth.trajectory_frames");
      }
    }
  }
  if (c.checkpoint_every < 0 || c.log_every < 1 || c.keep_checkpoints < 1) {
    fail("checkpoint_every >= 0, log_every >= 1, keep_checkpoints >= 1");
  }
}

std::string train_config_to_json(const TrainConfig& c) { return config::to_json(c).dump(2); }

ModelConfig resolve_model_config(const std::string& name_or_path) {
  if (std::filesystem::is_regular_file(name_or_path)) {
    std::ifstream in(name_or_path);
    std::stringstream ss;
    ss << in.rdbuf();
    return parse_model_config(ss.str());
  }
  return named_model_config(name_or_path);
}

TrainConfig load_train_config(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error("cannot read " + path);
  std::stringstream ss;
  ss << in.rdbuf();
  TrainConfig c = parse_train_config(ss.str());
  c.model = locate_model_config(c.model, std::filesystem::path(path).parent_path().string());
  return c;
}

std::string locate_model_config(const std::string& model, const std::string& config_dir) {
  namespace fs = std::filesystem;
  if (config_dir.empty() || fs::path(model).is_absolute() || fs::is_regular_file(model)) {
    return model;
  }
  const fs::path beside = fs::path(config_dir) / model;
  return fs::is_regular_file(beside) ? beside.string() : model;
}

StagePosition stage_at(const TrainConfig& config, int64_t step) {
  StagePosition p;
  int64_t begin = 0;
  for (std::size_t i = 0; i < config.stages.size(); ++i) {
    const int64_t n = config.stages[i].steps;
    if (step < begin + n) {
      p.index = static_cast<int64_t>(i);
      p.local_step = step - begin;
      return p;
    }
    begin += n;
  }
  p.index = static_cast<int64_t>(config.stages.size());
  p.local_step = step - begin;
  return p;
}

double learning_rate_at(const TrainConfig& config, int64_t step) {
  if (config.stages.empty()) return 0.0;
  StagePosition p = stage_at(config, step);
  if (p.index >= static_cast<int64_t>(config.stages.size())) {
    // Past the schedule (only with a longer max_steps): the last stage's floor.
    const TrainStage& s = config.stages.back();
    return s.lr * s.min_lr_ratio;
  }
  const TrainStage& s = config.stages[static_cast<std::size_t>(p.index)];
  if (p.local_step < s.warmup_steps) {
    return s.lr * static_cast<double>(p.local_step + 1) / static_cast<double>(s.warmup_steps);
  }
  const int64_t decay = s.steps - s.warmup_steps;
  if (decay <= 1) return s.lr;
  const double progress =
      static_cast<double>(p.local_step - s.warmup_steps) / static_cast<double>(decay - 1);
  const double floor = s.lr * s.min_lr_ratio;
  return floor + 0.5 * (s.lr - floor) * (1.0 + std::cos(M_PI * std::min(1.0, progress)));
}

}  // namespace long3r

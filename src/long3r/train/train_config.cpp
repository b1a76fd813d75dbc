// Training configuration file (docs/training.md) and the learning-rate schedule.
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <initializer_list>
#include <sstream>
#include <stdexcept>

#include "long3r/io/json.hpp"
#include "long3r/model/model_config.hpp"
#include "long3r/train/train.hpp"

namespace long3r {

namespace {

// Unknown keys are errors: a misspelt field would otherwise be defaulted.
void check_keys(const json::Value& obj, const std::string& where,
                std::initializer_list<const char*> allowed) {
  if (!obj.is_object()) throw std::invalid_argument(where + ": expected an object");
  for (const auto& member : obj.as_object()) {
    bool ok = false;
    for (const char* a : allowed) ok = ok || member.first == a;
    if (!ok) {
      std::string list;
      for (const char* a : allowed) list += std::string(list.empty() ? "" : ", ") + a;
      throw std::invalid_argument(where + ": unknown key \"" + member.first + "\" (known: " + list +
                                  ")");
    }
  }
}

uint64_t get_u64_or(const json::Value& obj, const std::string& key, uint64_t def) {
  const int64_t v = obj.get_int_or(key, static_cast<int64_t>(def));
  if (v < 0) throw std::invalid_argument(key + " must be >= 0");
  return static_cast<uint64_t>(v);
}

TrainStage parse_stage(const json::Value& v, const std::string& where) {
  check_keys(v, where,
             {"name", "steps", "frames", "batch_size", "lr", "warmup_steps", "min_lr_ratio",
              "freeze_encoder"});
  TrainStage s;
  s.name = v.get_string_or("name", where);
  s.steps = v.get_int_or("steps", s.steps);
  s.frames = v.get_int_or("frames", s.frames);
  s.batch_size = v.get_int_or("batch_size", s.batch_size);
  s.lr = v.get_double_or("lr", s.lr);
  s.warmup_steps = v.get_int_or("warmup_steps", s.warmup_steps);
  s.min_lr_ratio = v.get_double_or("min_lr_ratio", s.min_lr_ratio);
  s.freeze_encoder = v.get_bool_or("freeze_encoder", s.freeze_encoder);
  return s;
}

}  // namespace

int64_t TrainConfig::total_steps() const {
  int64_t n = 0;
  for (const TrainStage& s : stages) n += s.steps;
  return n;
}

TrainConfig parse_train_config(const std::string& json_text) {
  return parse_train_config(json::parse(json_text));
}

TrainConfig parse_train_config(const json::Value& root) {
  TrainConfig c;
  try {
    check_keys(root, "config",
               {"model", "image_size", "stages", "loss", "optimizer", "amp", "data", "validation",
                "checkpoint_every", "keep_checkpoints", "log_every", "comment"});
    c.model = root.get_string_or("model", c.model);
    c.image_size = root.get_int_or("image_size", c.image_size);
    c.amp = root.get_string_or("amp", c.amp);
    c.checkpoint_every = root.get_int_or("checkpoint_every", c.checkpoint_every);
    c.keep_checkpoints = root.get_int_or("keep_checkpoints", c.keep_checkpoints);
    c.log_every = root.get_int_or("log_every", c.log_every);
    if (const json::Value* st = root.find("stages")) {
      for (std::size_t i = 0; i < st->size(); ++i) {
        c.stages.push_back(parse_stage(st->at(i), "stages[" + std::to_string(i) + "]"));
      }
    }
    if (const json::Value* l = root.find("loss")) {
      check_keys(*l, "loss", {"alpha", "scale_weight", "coarse"});
      c.loss.alpha = l->get_double_or("alpha", c.loss.alpha);
      c.loss.scale_weight = l->get_double_or("scale_weight", c.loss.scale_weight);
      c.loss.coarse = l->get_bool_or("coarse", c.loss.coarse);
    }
    if (const json::Value* o = root.find("optimizer")) {
      check_keys(*o, "optimizer", {"weight_decay", "beta1", "beta2", "grad_clip"});
      c.weight_decay = o->get_double_or("weight_decay", c.weight_decay);
      c.beta1 = o->get_double_or("beta1", c.beta1);
      c.beta2 = o->get_double_or("beta2", c.beta2);
      c.grad_clip = o->get_double_or("grad_clip", c.grad_clip);
    }
    if (const json::Value* d = root.find("data")) {
      check_keys(*d, "data",
                 {"synth", "tum_dirs", "tum_fraction", "min_stride", "max_stride", "augment"});
      DataConfig& dc = c.data;
      if (const json::Value* s = d->find("synth")) {
        check_keys(*s, "data.synth",
                   {"enabled", "train_seed_begin", "train_scenes", "val_seed_begin", "val_scenes",
                    "trajectory_frames", "speed", "hfov_min_deg", "hfov_max_deg", "render_size"});
        SynthDataConfig& sc = dc.synth;
        sc.enabled = s->get_bool_or("enabled", sc.enabled);
        sc.train_seed_begin = get_u64_or(*s, "train_seed_begin", sc.train_seed_begin);
        sc.train_scenes = s->get_int_or("train_scenes", sc.train_scenes);
        sc.val_seed_begin = get_u64_or(*s, "val_seed_begin", sc.val_seed_begin);
        sc.val_scenes = s->get_int_or("val_scenes", sc.val_scenes);
        sc.trajectory_frames = s->get_int_or("trajectory_frames", sc.trajectory_frames);
        sc.speed = s->get_double_or("speed", sc.speed);
        sc.hfov_min_deg = s->get_double_or("hfov_min_deg", sc.hfov_min_deg);
        sc.hfov_max_deg = s->get_double_or("hfov_max_deg", sc.hfov_max_deg);
        sc.render_size = static_cast<int>(s->get_int_or("render_size", sc.render_size));
      }
      if (const json::Value* t = d->find("tum_dirs")) {
        for (std::size_t i = 0; i < t->size(); ++i) dc.tum_dirs.push_back(t->at(i).as_string());
      }
      dc.tum_fraction = d->get_double_or("tum_fraction", dc.tum_fraction);
      dc.min_stride = d->get_int_or("min_stride", dc.min_stride);
      dc.max_stride = d->get_int_or("max_stride", dc.max_stride);
      if (const json::Value* a = d->find("augment")) {
        check_keys(*a, "data.augment", {"color_jitter", "max_crop"});
        dc.augment.color_jitter = a->get_double_or("color_jitter", dc.augment.color_jitter);
        dc.augment.max_crop = a->get_double_or("max_crop", dc.augment.max_crop);
      }
    }
    if (const json::Value* v = root.find("validation")) {
      check_keys(*v, "validation",
                 {"every", "sequences", "frames", "stride", "pixel_step", "normals"});
      ValidationConfig& vc = c.validation;
      vc.every = v->get_int_or("every", vc.every);
      vc.sequences = v->get_int_or("sequences", vc.sequences);
      vc.frames = v->get_int_or("frames", vc.frames);
      vc.stride = v->get_int_or("stride", vc.stride);
      vc.pixel_step = static_cast<int>(v->get_int_or("pixel_step", vc.pixel_step));
      vc.normals = v->get_bool_or("normals", vc.normals);
    }
  } catch (const json::Error& e) {
    throw std::invalid_argument(std::string("training config: ") + e.what());
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument(std::string("training config: ") + e.what());
  }
  validate_train_config(c);
  return c;
}

void validate_train_config(const TrainConfig& c) {
  auto fail = [](const std::string& m) { throw std::invalid_argument("training config: " + m); };
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
  }
  if (c.image_size < 16 || c.image_size % 16 != 0) fail("image_size must be a multiple of 16");
  if (c.amp != "bf16" && c.amp != "off") fail("amp must be \"bf16\" or \"off\"");
  if (!(c.loss.alpha > 0.0)) fail("loss.alpha must be > 0");
  if (c.loss.scale_weight < 0.0) fail("loss.scale_weight must be >= 0");
  if (c.weight_decay < 0.0) fail("optimizer.weight_decay must be >= 0");
  if (c.beta1 < 0.0 || c.beta1 >= 1.0 || c.beta2 < 0.0 || c.beta2 >= 1.0) {
    fail("optimizer.beta1/beta2 must be in [0, 1)");
  }
  const DataConfig& d = c.data;
  if (!d.synth.enabled && d.tum_dirs.empty()) fail("data: no source (synth disabled, no tum_dirs)");
  if (d.min_stride < 1 || d.max_stride < d.min_stride)
    fail("data: need 1 <= min_stride <= max_stride");
  if (d.tum_fraction < 0.0 || d.tum_fraction > 1.0) fail("data.tum_fraction must be in [0, 1]");
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
    if (!s.enabled || v.sequences > s.val_scenes) {
      fail("validation.sequences needs synth data with at least that many val_scenes");
    }
    if ((v.frames - 1) * v.stride + 1 > s.trajectory_frames) {
      fail("validation: frames x stride exceeds data.synth.trajectory_frames");
    }
  }
  if (c.checkpoint_every < 0 || c.log_every < 1 || c.keep_checkpoints < 1) {
    fail("checkpoint_every >= 0, log_every >= 1, keep_checkpoints >= 1");
  }
}

std::string train_config_to_json(const TrainConfig& c) {
  json::Value root{json::Object{}};
  root.set("model", c.model);
  root.set("image_size", c.image_size);
  json::Value stages{json::Array{}};
  for (const TrainStage& s : c.stages) {
    json::Value v{json::Object{}};
    v.set("name", s.name);
    v.set("steps", s.steps);
    v.set("frames", s.frames);
    v.set("batch_size", s.batch_size);
    v.set("lr", s.lr);
    v.set("warmup_steps", s.warmup_steps);
    v.set("min_lr_ratio", s.min_lr_ratio);
    v.set("freeze_encoder", s.freeze_encoder);
    stages.push_back(std::move(v));
  }
  root.set("stages", std::move(stages));
  json::Value loss{json::Object{}};
  loss.set("alpha", c.loss.alpha);
  loss.set("scale_weight", c.loss.scale_weight);
  loss.set("coarse", c.loss.coarse);
  root.set("loss", std::move(loss));
  json::Value opt{json::Object{}};
  opt.set("weight_decay", c.weight_decay);
  opt.set("beta1", c.beta1);
  opt.set("beta2", c.beta2);
  opt.set("grad_clip", c.grad_clip);
  root.set("optimizer", std::move(opt));
  root.set("amp", c.amp);
  json::Value data{json::Object{}};
  json::Value synth{json::Object{}};
  const SynthDataConfig& s = c.data.synth;
  synth.set("enabled", s.enabled);
  synth.set("train_seed_begin", s.train_seed_begin);
  synth.set("train_scenes", s.train_scenes);
  synth.set("val_seed_begin", s.val_seed_begin);
  synth.set("val_scenes", s.val_scenes);
  synth.set("trajectory_frames", s.trajectory_frames);
  synth.set("speed", s.speed);
  synth.set("hfov_min_deg", s.hfov_min_deg);
  synth.set("hfov_max_deg", s.hfov_max_deg);
  synth.set("render_size", s.render_size);
  data.set("synth", std::move(synth));
  json::Value dirs{json::Array{}};
  for (const std::string& d : c.data.tum_dirs) dirs.push_back(d);
  data.set("tum_dirs", std::move(dirs));
  data.set("tum_fraction", c.data.tum_fraction);
  data.set("min_stride", c.data.min_stride);
  data.set("max_stride", c.data.max_stride);
  json::Value aug{json::Object{}};
  aug.set("color_jitter", c.data.augment.color_jitter);
  aug.set("max_crop", c.data.augment.max_crop);
  data.set("augment", std::move(aug));
  root.set("data", std::move(data));
  json::Value val{json::Object{}};
  val.set("every", c.validation.every);
  val.set("sequences", c.validation.sequences);
  val.set("frames", c.validation.frames);
  val.set("stride", c.validation.stride);
  val.set("pixel_step", c.validation.pixel_step);
  val.set("normals", c.validation.normals);
  root.set("validation", std::move(val));
  root.set("checkpoint_every", c.checkpoint_every);
  root.set("keep_checkpoints", c.keep_checkpoints);
  root.set("log_every", c.log_every);
  return root.dump(2);
}

ModelConfig resolve_model_config(const std::string& name_or_path) {
  if (std::filesystem::is_regular_file(name_or_path)) {
    std::ifstream in(name_or_path);
    std::stringstream ss;
    ss << in.rdbuf();
    return parse_model_config(ss.str());
  }
  return named_model_config(name_or_path);
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

// Training configuration (docs/training.md), torch-free: the curriculum
// stages, loss weights, optimiser, data sources, validation and checkpointing,
// each struct with its defaults and its field list for the JSON file, and the
// learning-rate schedule of the stages (train/train_config.cpp).
#pragma once

#include <cstdint>
#include <nlohmann/json_fwd.hpp>
#include <string>
#include <vector>

#include "long3r/config/config_fields.hpp"
#include "long3r/model/network/model_config.hpp"

namespace long3r {

// TrainStage::task values.
inline constexpr const char* kTaskSequence = "sequence";
inline constexpr const char* kTaskCrossViewCompletion = "cross_view_completion";

struct TrainStage {
  std::string name;
  int64_t steps = 0;            // optimiser steps in this stage
  int64_t frames = 5;           // sequence length N (>= 2)
  int64_t batch_size = 1;       // sequences per step
  double lr = 1e-4;             // peak learning rate of the stage
  int64_t warmup_steps = 0;     // linear warm-up from 0 to lr
  double min_lr_ratio = 0.01;   // cosine decay ends at lr * min_lr_ratio
  bool freeze_encoder = false;  // dust3r.patch_embed / enc_blocks / enc_norm
  // What the stage trains: "sequence" (the LONG3R losses on sequences) or
  // "cross_view_completion" (CroCo's pretext task on pairs, frames = 2: the
  // encoder and the coarse decoder branch learn to fill in the hidden
  // patches of one view from the other; docs/training.md).
  std::string task = kTaskSequence;
  double mask_ratio = 0.9;  // cross_view_completion: share of the patches hidden
};

struct LossConfig {
  double alpha = 0.2;         // DUSt3R's confidence regulariser weight
  double scale_weight = 1.0;  // weight of L_scale (the paper sums them: 1)
  bool coarse = true;         // also supervise head 2's next-frame pointmaps
};

struct AugmentConfig {
  double color_jitter = 0.1;  // brightness / contrast / saturation factors in [1-j, 1+j]
  double max_crop = 0.1;      // crop side shrinks by a factor in [1 - max_crop, 1]
  // Where the crop sits: false, anywhere in the image (a random position);
  // true, centred on the principal point (as DUSt3R's crops are), so that the
  // model input's principal point stays at its centre whatever the crop.
  bool crop_at_principal_point = false;
};

struct SynthDataConfig {
  bool enabled = true;
  uint64_t train_seed_begin = 1000;  // scenes [begin, begin + train_scenes)
  int64_t train_scenes = 1000;
  uint64_t val_seed_begin = 1000000;  // held out: must not overlap the training range
  int64_t val_scenes = 4;
  int64_t trajectory_frames = 240;  // length of each scene's camera path
  double speed = 0.02;              // metres per frame of the path
  double hfov_min_deg = 60.0, hfov_max_deg = 80.0;
  int render_size = 0;  // square render side before cropping; 0 = image_size

  int render_side(int64_t image_size) const {
    return render_size > 0 ? render_size : static_cast<int>(image_size);
  }
};

// The public datasets' layouts that data.datasets reads (docs/training.md,
// "Datasets"; train/cv/datasets/dataset_io.hpp).
inline const char* const kDatasetLayouts[] = {"scannet", "scannetpp",  "arkitscenes",
                                              "co3d",    "blendedmvs", "habitat"};

// One dataset of the training mixture.
struct DatasetSource {
  std::string layout;  // one of kDatasetLayouts
  std::string root;    // its folder, as the official preparation leaves it
  std::string split = "train";
  // Share of the samples drawn from it, relative to the other datasets' (the
  // N of the official "N @ Dataset(...)" mixtures).
  double weight = 1.0;
  // Gaps between a sample's frames, in the sequence's frames: each drawn in
  // [min_stride, max_stride] (Spann3R's frame gaps up to a threshold per
  // dataset), smaller where the sequence is too short.
  int64_t min_stride = 1, max_stride = 4;
  // co3d: depth only on the object (its foreground masks), as Spann3R's
  // mask_bg.
  bool mask_background = true;
  std::string name;  // in messages and sample sources; empty: the layout

  const std::string& label() const { return name.empty() ? layout : name; }
};

struct DataConfig {
  SynthDataConfig synth;
  std::vector<std::string> tum_dirs;  // TUM-layout folders (depth, groundtruth, calibration)
  double tum_fraction = 0.5;          // share of TUM sequences when both sources exist
  int64_t min_stride = 1, max_stride = 4;
  // Share of the sequences played backwards (last frame first), so that every
  // motion is also seen reversed, as DUSt3R's pairs come in both orders.
  double reverse_fraction = 0.0;
  AugmentConfig augment;
  // The public datasets (their layouts above), mixed by weight. With any,
  // every training sample comes from them (synth.enabled false, no
  // tum_dirs); the validation sequences stay generated ones.
  std::vector<DatasetSource> datasets;
};

struct ValidationConfig {
  int64_t every = 100;    // steps; 0 = only at the end
  int64_t sequences = 2;  // from the held-out scene seeds
  int64_t frames = 16;
  int64_t stride = 3;
  int pixel_step = 2;   // subsampling of the clouds for Acc / Comp / NC
  bool normals = true;  // NC (costs a k-NN normal estimate)
  // The blind control (blind_control in blind_control.hpp): how much better the model
  // places a frame given its true reference than given the frame itself as
  // its own reference. Held-out scenes val_seed_begin + i for i <
  // blind_scenes, blind_starts evenly spaced start frames per scene, each
  // stride of blind_strides (path frames), sequences of blind_frames frames
  // (2: pairs). blind_scenes 0: not run.
  int64_t blind_scenes = 0;
  int64_t blind_starts = 4;
  std::vector<int64_t> blind_strides = {8};
  int64_t blind_frames = 2;
};

struct TrainConfig {
  std::string model = "long3r_ship";  // named_model_config name or a JSON file
  int64_t image_size = 224;           // square model input, multiple of the patch size
  std::vector<TrainStage> stages;
  LossConfig loss;
  double weight_decay = 0.05;
  double beta1 = 0.9, beta2 = 0.95;
  double grad_clip = 1.0;  // max global L2 norm; <= 0 disables clipping
  // Mixed precision: the forward pass under bfloat16 autocast, the weights,
  // optimizer state, gradients and losses float32. "bf16": on any device (a
  // CPU without native bfloat16 needs allow_emulated_precision); "auto": on
  // CUDA only; "native": on CUDA and on a CPU with native bfloat16
  // arithmetic (AVX512-BF16, AMX), float32 on other CPUs; "off": float32
  // throughout.
  std::string amp = "auto";
  // Initial weights of a model trained from scratch: "torch" (libtorch's
  // module defaults) or "croco" (CroCo's / DUSt3R's: xavier-uniform linear
  // layers and patch embedding with zero biases, unit LayerNorms, mask_token
  // normal with std 0.02). An --init-dust3r checkpoint overrides both.
  std::string weight_init = "torch";
  bool allow_emulated_precision = false;  // "bf16" on a CPU that only emulates it (slow)
  DataConfig data;
  ValidationConfig validation;
  int64_t checkpoint_every = 100;  // steps; 0 = only at the end
  int64_t keep_checkpoints = 2;
  int64_t log_every = 1;

  int64_t total_steps() const;
};

// Field lists (JSON keys in docs/training.md; see include/long3r/config/config_json.hpp).
template <class S, class V>
config::FieldsOf<S, TrainStage> visit_fields(S& s, V& v) {
  v.derive(s.name, v.path());  // unnamed stages are called by their place
  v("name", s.name);
  v("steps", s.steps);
  v("frames", s.frames);
  v("batch_size", s.batch_size);
  v("lr", s.lr);
  v("warmup_steps", s.warmup_steps);
  v("min_lr_ratio", s.min_lr_ratio);
  v("freeze_encoder", s.freeze_encoder);
  v("task", s.task);
  v("mask_ratio", s.mask_ratio);
}
template <class S, class V>
config::FieldsOf<S, LossConfig> visit_fields(S& s, V& v) {
  v("alpha", s.alpha);
  v("scale_weight", s.scale_weight);
  v("coarse", s.coarse);
}
template <class S, class V>
config::FieldsOf<S, AugmentConfig> visit_fields(S& s, V& v) {
  v("color_jitter", s.color_jitter);
  v("max_crop", s.max_crop);
  v("crop_at_principal_point", s.crop_at_principal_point);
}
template <class S, class V>
config::FieldsOf<S, SynthDataConfig> visit_fields(S& s, V& v) {
  v("enabled", s.enabled);
  v("train_seed_begin", s.train_seed_begin);
  v("train_scenes", s.train_scenes);
  v("val_seed_begin", s.val_seed_begin);
  v("val_scenes", s.val_scenes);
  v("trajectory_frames", s.trajectory_frames);
  v("speed", s.speed);
  v("hfov_min_deg", s.hfov_min_deg);
  v("hfov_max_deg", s.hfov_max_deg);
  v("render_size", s.render_size);
}
template <class S, class V>
config::FieldsOf<S, DatasetSource> visit_fields(S& s, V& v) {
  v("layout", s.layout);
  v("root", s.root);
  v("split", s.split);
  v("weight", s.weight);
  v("min_stride", s.min_stride);
  v("max_stride", s.max_stride);
  v("mask_background", s.mask_background);
  v("name", s.name);
}
template <class S, class V>
config::FieldsOf<S, DataConfig> visit_fields(S& s, V& v) {
  v("synth", s.synth);
  v("tum_dirs", s.tum_dirs);
  v("tum_fraction", s.tum_fraction);
  v("min_stride", s.min_stride);
  v("max_stride", s.max_stride);
  v("reverse_fraction", s.reverse_fraction);
  v("augment", s.augment);
  v("datasets", s.datasets);
}
template <class S, class V>
config::FieldsOf<S, ValidationConfig> visit_fields(S& s, V& v) {
  v("every", s.every);
  v("sequences", s.sequences);
  v("frames", s.frames);
  v("stride", s.stride);
  v("pixel_step", s.pixel_step);
  v("normals", s.normals);
  v("blind_scenes", s.blind_scenes);
  v("blind_starts", s.blind_starts);
  v("blind_strides", s.blind_strides);
  v("blind_frames", s.blind_frames);
}
template <class S, class V>
config::FieldsOf<S, TrainConfig> visit_fields(S& s, V& v) {
  v("model", s.model);
  v("image_size", s.image_size);
  v("stages", s.stages);
  v("loss", s.loss);
  v.section("optimizer", [&](auto& o) {
    o("weight_decay", s.weight_decay);
    o("beta1", s.beta1);
    o("beta2", s.beta2);
    o("grad_clip", s.grad_clip);
  });
  v("amp", s.amp);
  v("weight_init", s.weight_init);
  v("allow_emulated_precision", s.allow_emulated_precision);
  v("data", s.data);
  v("validation", s.validation);
  v("checkpoint_every", s.checkpoint_every);
  v("keep_checkpoints", s.keep_checkpoints);
  v("log_every", s.log_every);
}

// Parses the training configuration (docs/training.md); unknown keys are
// errors (the key "comment" is free text) so that a misspelt field is not
// silently defaulted. Throws ConfigError ("training config: <field>: ...").
TrainConfig parse_train_config(const std::string& json_text);
TrainConfig parse_train_config(const nlohmann::ordered_json& root);
void validate_train_config(const TrainConfig& config);
std::string train_config_to_json(const TrainConfig& config);
// A model configuration by name (named_model_config) or from a JSON file path.
ModelConfig resolve_model_config(const std::string& name_or_path);
// The `model` of a training configuration read from a file in `config_dir`:
// a JSON path that is not a file as given (relative to the working
// directory) but is one relative to config_dir is returned joined to it, so
// that a configuration names the model file beside it wherever it is run
// from; anything else is returned unchanged.
std::string locate_model_config(const std::string& model, const std::string& config_dir);
// The training configuration of a JSON file, parsed, with its `model`
// located relative to the file's folder (locate_model_config). Throws
// std::runtime_error naming a file it cannot read, ConfigError as above.
TrainConfig load_train_config(const std::string& path);

// The learning-rate schedule over the stages.
struct StagePosition {
  int64_t index = 0;       // stage index; stages.size() when past the end
  int64_t local_step = 0;  // step within the stage
};
StagePosition stage_at(const TrainConfig& config, int64_t step);
// Learning rate of global step `step` (0-based): per stage, linear warm-up
// lr * (s + 1) / warmup for s < warmup, then cosine from lr to lr * min_ratio
// over the remaining steps of the stage.
double learning_rate_at(const TrainConfig& config, int64_t step);

}  // namespace long3r

// Training of LONG3R (paper section 3.5, spec "Training"): data sampling with
// exact ground-truth pointmaps, the confidence-aware regression + scale loss,
// AdamW with warm-up and cosine decay, the two-stage curriculum, checkpoints
// that resume bit-exactly, validation with the evaluation metrics, and logs.
// See docs/training.md for the configuration file and the recipe.
//
// Frames: ground-truth pointmaps are in the optical frame of camera 0 of each
// sampled sequence (x right, y down, z forward), metres, like the model's.
//
// This is the trainer's core (library long3r_train: libtorch, Eigen and the
// generator's core only), so that it builds and trains on a machine with
// nothing but a libtorch, e.g. a CUDA one. What needs OpenCV, PCL or the
// pipeline (TUM folders as data, PnP poses and the point-cloud metrics in
// validation, the loss-curve PNG) is in cv/train_cv.hpp and reaches the trainer
// through TrainerExtensions.
#pragma once

#include <ATen/core/Tensor.h>
#include <torch/nn/modules/linear.h>

#include <Eigen/Geometry>

#include <cstdint>
#include <functional>
#include <limits>
#include <map>
#include <memory>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include "long3r/geometry/pinhole_intrinsics.hpp"
#include "long3r/model/long3r_model.hpp"
#include "long3r/model/streaming.hpp"
#include "long3r/synth/synth.hpp"
#include "long3r/train/data_parallel.hpp"
#include "long3r/train/train_config.hpp"

namespace long3r {

// ================================================================== schedule

struct StagePosition {
  int64_t index = 0;       // stage index; stages.size() when past the end
  int64_t local_step = 0;  // step within the stage
};
StagePosition stage_at(const TrainConfig& config, int64_t step);
// Learning rate of global step `step` (0-based): per stage, linear warm-up
// lr * (s + 1) / warmup for s < warmup, then cosine from lr to lr * min_ratio
// over the remaining steps of the stage.
double learning_rate_at(const TrainConfig& config, int64_t step);

// ====================================================================== data

// One source frame with ground truth (CPU tensors).
struct RawFrame {
  at::Tensor bgr;    // [H, W, 3] uint8, BGR order
  at::Tensor depth;  // [H, W] float32 z-depth, metres; 0 / non-finite = invalid
  PinholeIntrinsics intrinsics;
  Eigen::Isometry3d T_W_C = Eigen::Isometry3d::Identity();
};

// A recorded sequence used as training data: frames with depth, pose and
// calibration (TUM folders: open_tum_training_source in cv/train_cv.hpp).
class RecordedSource {
 public:
  virtual ~RecordedSource() = default;
  virtual int64_t size() const = 0;
  virtual RawFrame frame(int64_t index) const = 0;
  virtual std::string name() const = 0;  // in the samples' source strings
};
// Opens the folder of a data.tum_dirs entry, or throws naming the problem.
using RecordedSourceOpener = std::function<std::unique_ptr<RecordedSource>(const std::string&)>;

// A recorded frame that cannot be read: a missing, truncated or inconsistent
// file, named in the message. The sampler skips such a sample, counts it and
// draws another.
class RecordedFrameError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// The sequences of one dataset of data.datasets (train/cv/datasets/dataset_io.hpp).
struct OpenedDataset {
  std::vector<std::unique_ptr<RecordedSource>> sequences;
  std::vector<std::string> skipped;  // "<path>: <why>" of each sequence left out
};
using DatasetOpener = std::function<OpenedDataset(const DatasetSource&)>;

// Intrinsics after cropping the rectangle (x0, y0, w, h) out of an image and
// resizing it to out_w x out_h with pixel-centre alignment (as cv::resize and
// torch's interpolation without align_corners):
// f' = f * out / crop, c' = (c - x0 + 0.5) * out / crop - 0.5.
PinholeIntrinsics crop_resize_intrinsics(const PinholeIntrinsics& k, int x0, int y0, int w, int h,
                                         int out_w, int out_h);

// Ground-truth pointmap of one frame: depth unprojected with `k` and mapped by
// T_C0_C into camera 0's frame. Returns [H, W, 3] float32 (zeros where
// invalid) and sets *valid ([H, W] bool: depth > 0 and finite).
// depth: [H, W] float32.
at::Tensor depth_to_pointmap(const at::Tensor& depth, const PinholeIntrinsics& k,
                             const Eigen::Isometry3d& T_C0_C, at::Tensor* valid);

// [3, H, W] float32 model input, (rgb - 0.5) / 0.5, from a BGR image
// ([H, W, 3] uint8).
at::Tensor bgr_to_model_input(const at::Tensor& bgr);

// A sequence ready for the model.
struct SequenceSample {
  std::vector<at::Tensor> images;             // N x [3, H, W]
  at::Tensor pts;                             // [N, H, W, 3], camera-0 frame
  at::Tensor valid;                           // [N, H, W] bool
  std::vector<Eigen::Isometry3d> T_C0_C;      // GT poses relative to camera 0
  std::vector<PinholeIntrinsics> intrinsics;  // at model resolution
  std::string source;                         // e.g. "synth:1234@17+3"
};

// Crop + resize every frame to size x size (one crop for the whole sequence:
// a random square of side (1 - u * max_crop) times the largest centred
// square, at a random position, u uniform), optional colour jitter per frame,
// and ground truth in camera 0's frame. rng == nullptr: centred full crop and
// no jitter (validation). Images shrink by area averaging and grow
// bilinearly; depth is resized by nearest neighbour (no depth mixed across
// object boundaries); a crop of the output size is copied as it is.
SequenceSample prepare_sequence(const std::vector<RawFrame>& frames, int size,
                                const AugmentConfig& augment, std::mt19937_64* rng,
                                const std::string& source = "");

// A batch: frames[i] = [B, 3, H, W]; pts [B, N, H, W, 3]; valid [B, N, H, W].
struct Batch {
  std::vector<at::Tensor> frames;
  at::Tensor pts, valid;
  std::vector<std::string> sources;
  Batch to(const at::Device& device) const;
};
Batch collate(const std::vector<SequenceSample>& samples);

// Draws training sequences (random source, scene, start and stride) and
// builds the fixed validation sequences. Deterministic given its RNG state,
// which checkpoints save and restore.
// Thread-compatible: one thread uses a sampler at a time (the trainer's data
// thread while it prefetches).
class SequenceSampler {
 public:
  // open_recorded opens data.tum_dirs; without it a config naming any is
  // refused (std::runtime_error).
  // open_dataset likewise opens data.datasets (a dataset without any
  // sequence is refused; the sequences left out are reported on stderr).
  SequenceSampler(const DataConfig& config, int image_size, uint64_t seed, int render_threads = 2,
                  const RecordedSourceOpener& open_recorded = {},
                  const DatasetOpener& open_dataset = {});

  // Every sample draws from a generator of its own, seeded in turn from the
  // sampler's: a sample is then the same whichever process makes it, and the
  // sampler's state after a batch does not depend on who made which part.
  SequenceSample sample(int64_t frames);
  // The samples [first, first + count) of a batch of batch_size (count < 0:
  // to its end), in their places: the shard one data-parallel rank makes of
  // the batch that all ranks draw together. The sampler moves past the whole
  // batch.
  Batch sample_batch(int64_t batch_size, int64_t frames, int64_t first = 0, int64_t count = -1);

  // Held-out scenes val_seed_begin + i, frames from 0 with a fixed stride, no
  // augmentation.
  SequenceSample validation_sequence(int64_t index, int64_t frames, int64_t stride,
                                     int64_t start = 0);
  // The blind control's sequences of a validation configuration (scenes x
  // evenly spaced starts x strides), in that order.
  std::vector<SequenceSample> blind_sequences(const ValidationConfig& config);

  // Raw frames of a generated scene (start, stride) without preprocessing.
  std::vector<RawFrame> synth_frames(uint64_t scene_seed, int64_t start, int64_t stride,
                                     int64_t frames);

  std::string rng_state() const;
  void set_rng_state(const std::string& state);
  // Samples skipped so far for an unreadable frame (RecordedFrameError).
  int64_t skipped_samples() const { return skipped_samples_; }

 private:
  const synth::Sequence& scene(uint64_t seed);
  // One sample, all of its draws from rng.
  SequenceSample sample_from(int64_t frames, std::mt19937_64& rng);
  SequenceSample dataset_sample(int64_t frames, std::mt19937_64& rng);
  // The drawn frames played backwards for data.reverse_fraction, then
  // prepared (crop, resize, augmentation) with the sample's generator.
  SequenceSample finish_sample(std::vector<RawFrame> raw, std::string source,
                               std::mt19937_64& rng) const;

  DataConfig config_;
  int image_size_;
  int render_threads_;
  std::mt19937_64 rng_;
  std::map<uint64_t, synth::Sequence> scenes_;
  std::vector<std::unique_ptr<RecordedSource>> recorded_;
  struct Dataset {
    DatasetSource source;
    std::vector<std::unique_ptr<RecordedSource>> sequences;
  };
  std::vector<Dataset> datasets_;
  double dataset_weight_ = 0.0;  // sum of the datasets' weights
  int64_t skipped_samples_ = 0;
};

// ====================================================================== loss

// Loss of one sequence batch, all in float32:
//   L = L_conf + scale_weight * L_scale                      (paper Eq. 9)
// L_conf (DUSt3R / Spann3R): for every supervised pointmap (the N refined /
// final outputs except the last, and the N-1 coarse next-frame pointmaps, or
// just the N outputs when coarse supervision is off) the mean over valid
// pixels of  conf * || x_hat / z_hat - x / z || - alpha * log(conf),  averaged
// over the pointmaps; z_hat (z) is the average distance to the origin of the
// prediction's (GT's) valid points over the whole sequence (the N outputs),
// per batch item, camera-0 frame.
// L_scale: the paper states it only in words ("encourages the predicted point
// cloud to have an average distance smaller than that of the ground truth");
// this is Spann3R's form, which the paper follows: the mean of z_hat - z over
// the batch items whose z_hat > z (0 when there are none).
struct LossTerms {
  at::Tensor total;                     // scalar, differentiable
  at::Tensor conf_loss;                 // L_conf
  at::Tensor scale_loss;                // L_scale
  double regression = 0;                // mean || x_hat / z_hat - x / z || (no confidence)
  double pred_scale = 0, gt_scale = 0;  // mean z_hat, z over the batch
};

// Average distance to the origin of the valid points of [B, N, H, W, 3]
// pointmaps, per batch item: [B].
at::Tensor average_distance(const at::Tensor& pts, const at::Tensor& valid);

// One pointmap's confidence-weighted term: pred_n, gt_n [B, H, W, 3] (already
// normalised), conf [B, H, W], valid [B, H, W]. Returns (mean of
// conf * err - alpha * log conf, mean err) over valid pixels; `count`, when
// given, is the number the sums are divided by instead of valid's count.
std::pair<at::Tensor, at::Tensor> confidence_regression(const at::Tensor& pred_n,
                                                        const at::Tensor& gt_n,
                                                        const at::Tensor& conf,
                                                        const at::Tensor& valid, double alpha,
                                                        const at::Tensor& count = {});

// The ranks that each hold a shard of one batch (data-parallel training),
// for the loss's normalisers: a rank's loss is then its part of the whole
// batch's loss (its sums over the whole batch's valid-pixel and item counts)
// times the number of ranks, so that the ranks' mean loss is the whole
// batch's and averaging their gradients gives the whole batch's gradient,
// however the valid pixels fall between the shards.
struct BatchShards {
  int64_t ranks = 1;
  std::function<void(const at::Tensor&)> sum;  // sums a CPU tensor over the ranks, in place
};

// outputs: N model outputs (forward_sequence); coarse: N-1 next-frame
// predictions (may be empty when config.coarse is false); gt_pts
// [B, N, H, W, 3] and gt_valid [B, N, H, W] on the outputs' device.
LossTerms sequence_loss(const std::vector<StreamOutput>& outputs,
                        const std::vector<StreamOutput>& coarse, const at::Tensor& gt_pts,
                        const at::Tensor& gt_valid, const LossConfig& config,
                        const BatchShards* shards = nullptr);

// Cross-view completion (CroCo, Weinzaepfel et al. 2022), the pretext task of
// a "cross_view_completion" stage.
//
// The patches of images [B, 3, H, W] as [B, N, p * p * 3]: patches in
// row-major grid order, each one's pixels row by row, channels last.
at::Tensor patchify(const at::Tensor& images, int64_t patch);
// Which patches of n the encoder sees: int64 [V] of sorted indices, V =
// max(1, round(n * (1 - mask_ratio))), drawn with torch's CPU generator; the
// rest are hidden.
at::Tensor draw_visible_patches(int64_t n, double mask_ratio);
// CroCo's loss: the mean squared error over the hidden patches (those not in
// `visible`) between `pred` [B, N, p * p * 3] and the target patches, each
// normalised by its own mean and variance (norm_pix_loss). Float32.
at::Tensor completion_loss(const at::Tensor& pred, const at::Tensor& target_patches,
                           const at::Tensor& visible);
// The completion stage's blind control: completion_loss of frame 1 of each
// pair completed from its true reference (frame 0), and from the reference of
// another pair of the batch (the batch rolled by one), same hidden patches
// (drawn from their own generator seeded with `seed`, torch's default
// generator untouched). A true / shuffled ratio near 1: the other view is not
// used. Inference; `head` is the stage's pixel head. Pairs: sequences of 2
// frames, at least 2 of them.
struct CompletionControl {
  double loss_true = std::numeric_limits<double>::quiet_NaN();
  double loss_shuffled = std::numeric_limits<double>::quiet_NaN();
};

CompletionControl completion_control(Long3rModel& model, torch::nn::Linear& head,
                                     const std::vector<SequenceSample>& pairs, double mask_ratio,
                                     uint64_t seed = 0);

// ============================================================ initialisation

struct InitReport {
  int64_t loaded = 0;          // model tensors copied from the file
  int64_t shape_mismatch = 0;  // same name, different shape: kept fresh
  int64_t unused = 0;          // file tensors with no counterpart in the model
  int64_t fresh = 0;           // model tensors not in the file (new modules)
  std::vector<std::string> mismatched_names;
};
// Copies every tensor of a DUSt3R (names without prefix), Spann3R or LONG3R
// checkpoint whose name (as is, or with "dust3r." prepended) and shape match a
// parameter or buffer of the model; the rest of the model keeps its values.
InitReport init_from_checkpoint(Long3rModel& model, const std::string& path);

// CroCo's initialisation (CroCoNet.initialize_weights, which DUSt3R
// inherits) for a model trained from scratch: every linear layer outside the
// downstream heads xavier-uniform with zero bias, the patch embedding's kernel
// xavier-uniform as a linear map of its patch, LayerNorms 1 / 0, mask_token
// normal with std 0.02. The DPT heads keep libtorch's defaults, as DUSt3R's
// (attached after CroCo's initialisation) keep PyTorch's. Draws from torch's
// default generator.
void init_croco_weights(Long3rModel& model);

// True for the encoder's parameters (dust3r.patch_embed, dust3r.enc_blocks,
// dust3r.enc_norm), which stage 2 freezes.
bool is_encoder_parameter(const std::string& name);

// ================================================================ validation

// Scores of one predicted sequence against its ground truth
// (evaluate_prediction below).
struct PredictionMetrics {
  double pointmap_error = 0;  // mean || aligned pred - gt ||, metres
  double acc_mean = 0, acc_median = 0, comp_mean = 0, comp_median = 0;
  double nc_mean = 0, nc_median = 0;
  double ate_rmse = 0;        // m; NaN when fewer than 3 frames were posed
  double rpe_trans_rmse = 0;  // m per frame step (after the Sim(3) of the ATE)
  double rpe_rot_rmse_deg = 0;
  int64_t frames = 0, posed = 0;
};

// What blind_control (below) measures.
struct BlindControl {
  static constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
  double reg_true = kNaN, reg_blind = kNaN;  // means over the frames scored
  double blind_ratio = kNaN;                 // reg_true / reg_blind
  double rot_err_deg = kNaN;   // mean angle between applied and true relative rotation
  double rot_true_deg = kNaN;  // mean true relative rotation (a model that never turns scores this)
  double motion_px = kNaN;  // mean over frames of the median image motion of their points, pixels
  int64_t frames = 0;       // frames scored
  int64_t unplaced = 0;     // frames left out: a non-finite or collapsed prediction
};

struct ValidationMetrics {
  double loss = 0, regression = 0;  // sequence_loss over the sequences, averaged
  // probe_loss's `registered` (shape error left once every frame is placed
  // by its own Sim(3)), averaged: regression - registered is what
  // registration costs.
  double registered = 0;
  // evaluate_prediction's figures averaged over the sequences; ate_rmse and
  // the RPE over those where they are finite (NaN when there is none);
  // frames and posed are totals.
  PredictionMetrics prediction;
  int64_t sequences = 0;
  // The blind control over validation.blind_* (NaN figures when not run).
  BlindControl blind;
  // In a cross_view_completion stage, its control on the same pairs.
  CompletionControl completion;
};

// Switches a model to training or inference for a scope and restores the
// previous mode when the scope ends, also by an exception. Both switches
// reset the model's stream (set_training).
class TrainingModeGuard {
 public:
  TrainingModeGuard(Long3rModel& model, bool training)
      : model_(model), was_training_(model.training()) {
    model_.set_training(training);
  }
  ~TrainingModeGuard() { model_.set_training(was_training_); }
  TrainingModeGuard(const TrainingModeGuard&) = delete;
  TrainingModeGuard& operator=(const TrainingModeGuard&) = delete;

 private:
  Long3rModel& model_;
  bool was_training_;
};

// A model's (or a baseline's) pointmaps for one sequence, CPU float32.
struct SequencePrediction {
  std::vector<at::Tensor> pts;   // N x [H, W, 3], camera-0 frame
  std::vector<at::Tensor> conf;  // N x [H, W]
  double seconds = 0;            // wall time of the prediction
};

// Scores one predicted validation sequence against its ground truth.
using PredictionScorer = std::function<PredictionMetrics(
    const SequencePrediction&, const SequenceSample&, const ValidationConfig&)>;

// What needs no OpenCV: pointmap_error (mean || aligned pred - gt || after
// one Sim(3), Umeyama on the valid pixels every config.pixel_step-th row and
// column); the point-cloud and trajectory figures NaN. frames = N, posed = 0.
PredictionMetrics pointmap_metrics(const SequencePrediction& prediction,
                                   const SequenceSample& sample, const ValidationConfig& config);

// Inference-mode run of `model` (switched to inference and back) over the
// sequences: the loss, probe_loss's registered share, and `score`'s figures
// (pointmap_metrics when empty; cv/train_cv.hpp's full_validation_scorer adds
// Acc / Comp / NC and the ATE of PnP poses). Averages over sequences.
ValidationMetrics validate(Long3rModel& model, const std::vector<SequenceSample>& sequences,
                           const LossConfig& loss, const ValidationConfig& config,
                           const PredictionScorer& score = {});

// ======================================================= held-out evaluation

// Streams the sequence through `model` in inference mode (one push per
// frame, the last frame from flush(), as the pipeline does).
SequencePrediction predict_sequence(Long3rModel& model, const SequenceSample& sample);
// The constant-depth baseline: every pixel of every frame at depth `depth_m`
// in its own camera, all cameras at camera 0 (no motion), confidence 1.
SequencePrediction constant_depth_prediction(const SequenceSample& sample, double depth_m);
// Oracle of the loss probe (docs/model_card.md, "Why the model does not
// register"), from the ground truth, confidence 1: frame 0's exact pointmap
// for every frame (ignores the images after the first). The other oracle,
// true_depth_no_motion_prediction, is in cv/train_cv.hpp.
SequencePrediction first_frame_prediction(const SequenceSample& sample);

// What a prediction costs in the training loss, and how much of that is
// registration: `regression` is sequence_loss's mean || x_hat / z_hat - x / z ||
// over the N outputs (coarse supervision off, no confidence); `registered` is
// the same after each frame's normalised prediction is moved by its own best
// similarity transform (Umeyama Sim(3) on the valid pixels: pose and scale)
// onto the normalised GT, so what remains is shape error; regression -
// registered is the share that placing every frame correctly in camera 0's
// frame (registration, and a scale consistent over the sequence) would remove.
// `registered` is NaN when a frame cannot be placed: non-finite predicted
// points, or a frame collapsed onto a line.
struct LossProbe {
  double regression = 0;
  double registered = 0;
};
LossProbe probe_loss(const SequencePrediction& prediction, const SequenceSample& sample);

// The blind control: does the model place a frame using its reference view?
// For every frame k >= 1 of each sequence, the placement error of frame k in
// the reference's (camera 0's) coordinates (frame_placement_error) when the
// model runs on the true sequence (reg_true), and when it is given frame k
// itself as its reference, i.e. the pair (frame k, frame k), whose second
// view is placed by the head that places a pair's second view (reg_blind).
// blind_ratio = reg_true / reg_blind: about 1 for a model that does not
// register (it predicts each frame in its own camera, wherever the reference
// was), 0 for perfect registration. Also the rotation the true run applies to
// each frame (Umeyama of the frame's ground-truth points in its own camera
// onto its prediction) against the true relative rotation, and the median image
// motion of the frames' points relative to camera 0 (ground truth).
//
// Sequences of one length >= 2 (e.g. validation_sequence); runs in inference
// mode (switched and switched back), batched.
BlindControl blind_control(Long3rModel& model, const std::vector<SequenceSample>& sequences);
// The scoring half of blind_control, for any predictor: truth[s] and blind[s]
// hold the N pointmaps of sequence s in camera 0's frame, from the true
// sequence and from each frame given itself as its reference (frame 0's
// blind entry is not read).
BlindControl score_blind_control(const std::vector<SequenceSample>& sequences,
                                 const std::vector<SequencePrediction>& truth,
                                 const std::vector<SequencePrediction>& blind);
// mean over valid pixels of || p / z_p - g / z_g ||, p the predicted and g the
// true pointmap of one frame ([H, W, 3], same coordinates), each divided by
// the mean distance of its own valid points to the origin, so that only where
// the frame is placed and shaped counts, not its scale. NaN when either has
// no extent or the prediction is not finite.
double frame_placement_error(const at::Tensor& pred, const at::Tensor& gt, const at::Tensor& valid);

// =================================================================== trainer

struct LogRow;

// What the trainer takes from the OpenCV side when it is built
// (cv/train_cv.hpp: opencv_trainer_extensions()). Each part may be empty, as on
// a machine with nothing but a libtorch.
struct TrainerExtensions {
  PredictionScorer score;              // validation figures; empty: pointmap_metrics
  RecordedSourceOpener open_recorded;  // data.tum_dirs; empty: such configs are refused
  DatasetOpener open_dataset;          // data.datasets; empty: such configs are refused
  // Writes loss_curve.png; empty: no picture (train_log.csv holds the curves).
  std::function<void(const std::vector<LogRow>&, const std::string& path)> write_plot;
};

struct TrainOptions {
  std::string out_dir;
  std::string device = "cpu";  // "cpu" or "cuda" (or any torch device string)
  uint64_t seed = 0;
  int64_t max_steps = -1;       // stop after this many global steps (< 0: the schedule's end)
  bool resume = false;          // continue from out_dir/checkpoint/latest
  std::string init_checkpoint;  // DUSt3R / Spann3R / LONG3R weights to start from
  std::string model_override;   // replaces config.model when set
  bool quiet = false;
  // Threads rendering training scenes; 0: torch's intra-op thread count.
  int render_threads = 0;
  // Batches prepared ahead on a data thread while the model trains (renders
  // on the CPU while a GPU computes); 0: each batch when its step needs it.
  // Any value trains on the same batches, in the same order.
  int prefetch_batches = 0;
  // Wall-clock budget of this run in seconds (0: none): no step starts that
  // would, at the mean step time so far, end past it; the run then validates
  // and writes its outputs as at the schedule's end, learning-rate schedule
  // unchanged.
  double time_budget_s = 0;
  // Data-parallel training (docs/training.md): this process's place in the
  // job (distributed_env(): torchrun, srun) and how the ranks talk. Each
  // stage's batch_size is the global batch, split evenly over the ranks.
  DistributedEnv distributed;
  DataParallelConfig data_parallel;
  // After every step, check that all ranks hold bit-identical weights (a
  // fingerprint each) and say so; a difference ends the run.
  bool verify_replicas = false;
  TrainerExtensions extensions;
};

// One CSV row (train_log.csv); validation columns are NaN where not run.
struct LogRow {
  int64_t step = 0;  // 1-based count of optimiser steps done
  int64_t stage = 0;
  double loss = 0, conf_loss = 0, scale_loss = 0, regression = 0;
  double lr = 0, grad_norm = 0;
  double step_s = 0, data_s = 0, wall_s = 0;  // step time, its data part, run time
  std::optional<ValidationMetrics> val;
};

class Trainer {
 public:
  Trainer(const TrainConfig& config, const TrainOptions& options);
  ~Trainer();

  // Runs until the schedule's end, max_steps or the time budget; writes
  // model.safetensors, train_log.csv, validation.json (the last validation),
  // loss_curve.png (with extensions.write_plot) and checkpoints.
  void run();
  // One optimiser step (sampling, forward, loss, backward, clip, update).
  LogRow step();

  // One file, checkpoint/step_NNNNNNNN.pt (a libtorch archive written
  // atomically): weights, AdamW state, step, sampler and torch RNG states,
  // wall time, configurations and the log so far, so that a run resumes
  // bit-exactly from it; checkpoint/latest names the newest.
  void save_checkpoint();
  // Restores all of the above from such a file.
  void load_checkpoint(const std::string& path);
  ValidationMetrics run_validation();
  void write_outputs();  // model.safetensors, CSV, validation.json, PNG
  // Why the last run() ended: "schedule", "max_steps" or "time_budget".
  const std::string& stop_reason() const { return stop_reason_; }

  int64_t global_step() const { return step_; }
  Long3rModel& model() { return *model_; }
  const TrainConfig& config() const { return config_; }
  const std::vector<LogRow>& log() const { return log_; }
  const std::optional<InitReport>& init_report() const { return init_report_; }

 private:
  void apply_stage(int64_t stage);
  void set_lr(double lr);
  const TrainStage& stage_of_step(int64_t step) const;
  // The batch of step step_: drawn now, or taken from the data thread.
  Batch next_batch(int64_t batch_size, int64_t frames);
  // This rank's share of a global batch, and drawing it (the whole batch's
  // draws, this rank's samples).
  int64_t shard_size(int64_t batch_size) const;
  Batch draw_shard(int64_t batch_size, int64_t frames);
  void stop_prefetch();
  // The forward pass and backward of one step's task; return its loss terms.
  LossTerms sequence_step(const Batch& batch);
  LossTerms completion_step(const Batch& batch, double mask_ratio);
  bool is_root() const { return !dp_ || dp_->rank() == 0; }
  // Throws unless every rank holds the same weights (verify_replicas).
  void verify_replicas();

  TrainConfig config_;
  TrainOptions options_;
  at::Device device_;
  bool mixed_precision_ = false;  // forward pass under bfloat16 autocast (config amp)
  std::unique_ptr<Long3rModel> model_;
  // Pixel head of cross_view_completion stages (null without one).
  torch::nn::Linear completion_head_{nullptr};
  struct Optim;
  std::unique_ptr<Optim> optim_;
  std::unique_ptr<SequenceSampler> sampler_;
  // The sampler's RNG state after the last batch a step used (what a
  // checkpoint saves: batches prefetched beyond it are drawn again on resume).
  std::string sampler_state_;
  struct Prefetch;
  std::unique_ptr<Prefetch> prefetch_;
  std::string stop_reason_;
  std::vector<SequenceSample> val_sequences_;
  std::vector<SequenceSample> blind_sequences_;  // validation.blind_*
  std::vector<LogRow> log_;
  std::optional<InitReport> init_report_;
  int64_t step_ = 0;
  int64_t applied_stage_ = -1;
  double wall_offset_s_ = 0;  // wall time of the runs before a resume
  double start_time_ = 0;
  // The process group of a data-parallel run (null in a single process);
  // last, so that it goes (and unhooks the parameters) before the model.
  std::unique_ptr<DataParallel> dp_;
};

// CSV text of the rows (header included).
std::string log_rows_to_csv(const std::vector<LogRow>& rows);
// The rows of such a text, each column found by its header name; a line with
// fewer cells than the header (cut short by a crash) is skipped. Throws
// std::runtime_error when a column is missing.
std::vector<LogRow> log_rows_from_csv(const std::string& csv);

}  // namespace long3r

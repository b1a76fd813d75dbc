// Training of LONG3R (paper section 3.5, spec "Training"): data sampling with
// exact ground-truth pointmaps, the confidence-aware regression + scale loss,
// AdamW with warm-up and cosine decay, the two-stage curriculum, checkpoints
// that resume bit-exactly, validation with the evaluation metrics, and logs.
// See docs/training.md for the configuration file and the recipe. This
// header holds the trainer itself (train/trainer.cpp), its options and its
// log; the parts it is made of are in the headers beside it.
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

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "long3r/model/network/long3r_model.hpp"
#include "long3r/train/data_parallel.hpp"
#include "long3r/train/prediction.hpp"
#include "long3r/train/train_config.hpp"
#include "long3r/train/train_data.hpp"
#include "long3r/train/train_loss.hpp"

namespace long3r {

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
  // A frame cache of the configuration's training scenes (FrameCache, made
  // by long3r_train --write-frame-cache): their frames are read from it
  // instead of rendered, the same bytes; empty: every frame rendered.
  std::string frame_cache;
  // Wall-clock budget of this run in seconds (0: none): no step starts that
  // would, at the mean step time so far, end past it; the run then validates
  // and writes its outputs as at the schedule's end, learning-rate schedule
  // unchanged.
  double time_budget_s = 0;
  // Asked before each step (long3r_train: SIGINT or SIGTERM arrived): true
  // ends the run there, on every rank at the same step, with the checkpoint
  // and the outputs of the last step finished, without the end-of-run
  // validation, so that a stopped sitting loses no step. Empty: never.
  std::function<bool()> stop_requested;
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
  // wall time, configurations and the number of log rows so far, so that a
  // run resumes bit-exactly from it; checkpoint/latest names the newest. The
  // log's rows are appended to train_log.csv first (the log of a resumed run
  // is that file up to the checkpoint's step).
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
  // Appends the rows not yet in train_log.csv (or writes it whole after a
  // resume or a changed row).
  void write_log();
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
  // validation.blind_*: the held-out sequences of each stride, in order.
  std::vector<std::pair<int64_t, std::vector<SequenceSample>>> blind_sets_;
  std::vector<LogRow> log_;
  std::size_t log_rows_written_ = 0;  // rows of log_ in train_log.csv
  bool log_rewrite_ = false;          // the file needs writing whole
  int64_t blind_step_written_ = 0;    // the last step in blind_control.csv
  bool blind_file_fresh_ = true;      // a new run writes blind_control.csv anew
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

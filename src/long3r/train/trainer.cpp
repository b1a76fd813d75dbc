// The training loop: curriculum stages, AdamW with the schedule, clipping,
// autocast on CUDA, checkpoints (atomic, resumable), validation and logs.
#include <ATen/ATen.h>
#include <ATen/CPUGeneratorImpl.h>
#include <ATen/Parallel.h>
#include <ATen/core/Generator.h>
#include <torch/nn/module.h>
#include <torch/nn/utils/clip_grad.h>
#include <torch/optim/adamw.h>
#include <torch/serialize.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <deque>
#include <exception>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <set>
#include <sstream>
#include <stdexcept>
#include <thread>

#include "long3r/io/atomic_file.hpp"
#include "long3r/model/network/model_config.hpp"
#include "long3r/model/runtime/autocast.hpp"
#include "long3r/model/runtime/inference.hpp"
#include "long3r/train/blind_control.hpp"
#include "long3r/train/cross_view_completion.hpp"
#include "long3r/train/data_parallel.hpp"
#include "long3r/train/frame_cache.hpp"
#include "long3r/train/prediction.hpp"
#include "long3r/train/train_config.hpp"
#include "long3r/train/train_data.hpp"
#include "long3r/train/train_loss.hpp"
#include "long3r/train/trainer.hpp"
#include "long3r/train/weight_init.hpp"

namespace long3r {

namespace fs = std::filesystem;

namespace {

double now_s() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

std::string read_text(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  if (!in) throw std::runtime_error("cannot read " + p.string());
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

std::string fmt(double v) {
  if (!std::isfinite(v)) return "nan";
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%.8g", v);
  return buf;
}

double parse_num(const std::string& s) {
  if (s == "nan" || s.empty()) return std::numeric_limits<double>::quiet_NaN();
  return std::stod(s);
}

// train_log.csv: step, stage, then these columns in this order, written and
// read back by name.
struct TrainColumn {
  const char* name;
  double LogRow::*field;
};
const TrainColumn kTrainColumns[] = {
    {"loss", &LogRow::loss},
    {"conf_loss", &LogRow::conf_loss},
    {"scale_loss", &LogRow::scale_loss},
    {"regression", &LogRow::regression},
    {"lr", &LogRow::lr},
    {"grad_norm", &LogRow::grad_norm},
    {"step_s", &LogRow::step_s},
    {"data_s", &LogRow::data_s},
    {"wall_s", &LogRow::wall_s},
};
// Validation columns: "nan" on the rows without validation. Columns added
// after the first version go last and are optional when reading (logs and
// checkpoints written before them read as NaN there).
struct ValColumn {
  const char* name;
  double& (*field)(ValidationMetrics&);
  bool optional = false;
};
const ValColumn kValColumns[] = {
    {"val_loss", [](ValidationMetrics& v) -> double& { return v.loss; }},
    {"val_regression", [](ValidationMetrics& v) -> double& { return v.regression; }},
    {"val_pointmap_err_m",
     [](ValidationMetrics& v) -> double& { return v.prediction.pointmap_error; }},
    {"val_acc_mean_m", [](ValidationMetrics& v) -> double& { return v.prediction.acc_mean; }},
    {"val_acc_median_m", [](ValidationMetrics& v) -> double& { return v.prediction.acc_median; }},
    {"val_comp_mean_m", [](ValidationMetrics& v) -> double& { return v.prediction.comp_mean; }},
    {"val_comp_median_m", [](ValidationMetrics& v) -> double& { return v.prediction.comp_median; }},
    {"val_nc_mean", [](ValidationMetrics& v) -> double& { return v.prediction.nc_mean; }},
    {"val_nc_median", [](ValidationMetrics& v) -> double& { return v.prediction.nc_median; }},
    {"val_ate_rmse_m", [](ValidationMetrics& v) -> double& { return v.prediction.ate_rmse; }},
    {"val_registered", [](ValidationMetrics& v) -> double& { return v.registered; }, true},
    {"val_blind_ratio", [](ValidationMetrics& v) -> double& { return v.blind.blind_ratio; }, true},
    {"val_reg_true", [](ValidationMetrics& v) -> double& { return v.blind.reg_true; }, true},
    {"val_reg_blind", [](ValidationMetrics& v) -> double& { return v.blind.reg_blind; }, true},
    {"val_rot_err_deg", [](ValidationMetrics& v) -> double& { return v.blind.rot_err_deg; }, true},
    {"val_rot_true_deg", [](ValidationMetrics& v) -> double& { return v.blind.rot_true_deg; },
     true},
    {"val_completion_true", [](ValidationMetrics& v) -> double& { return v.completion.loss_true; },
     true},
    {"val_completion_shuffled",
     [](ValidationMetrics& v) -> double& { return v.completion.loss_shuffled; }, true},
    {"val_shape_err", [](ValidationMetrics& v) -> double& { return v.blind.shape_err; }, true},
    {"val_depth_slope", [](ValidationMetrics& v) -> double& { return v.prediction.depth_slope; },
     true},
};

// Appends `text` to the file at `path` (creating it), or throws naming it.
// Not atomic: the logs' readers skip a line cut short by a crash.
void append_to_file(const fs::path& path, const std::string& text) {
  std::ofstream out(path, std::ios::app | std::ios::binary);
  out << text;
  out.flush();
  if (!out) throw std::runtime_error("cannot append to " + path.string());
}

// blind_control.csv: a row per validation and stride of validation.blind_*.
constexpr const char* kBlindHeader =
    "step,frames,stride,scored,motion_px,reg_true,reg_blind,blind_ratio,shape_err,rot_err_deg,"
    "rot_true_deg";

std::vector<std::string> split_csv_line(const std::string& line) {
  std::vector<std::string> cells;
  std::stringstream ss(line);
  std::string cell;
  while (std::getline(ss, cell, ',')) cells.push_back(cell);
  return cells;
}

// The training device, checked as inference checks it (a CUDA device that
// this libtorch or machine lacks is named); "cuda" in a data-parallel job is
// the device of this process's local rank.
at::Device training_device(const std::string& name, const DistributedEnv& env) {
  InferenceConfig inference;
  inference.device = name;
  if (env.distributed() && name == "cuda") inference.device += ":" + std::to_string(env.local_rank);
  return resolve_inference_target(inference).device;
}

}  // namespace

std::string log_rows_to_csv(const std::vector<LogRow>& rows) {
  std::ostringstream o;
  o << "step,stage";
  for (const TrainColumn& c : kTrainColumns) o << "," << c.name;
  for (const ValColumn& c : kValColumns) o << "," << c.name;
  o << "\n";
  for (const LogRow& r : rows) {
    o << r.step << "," << r.stage;
    for (const TrainColumn& c : kTrainColumns) o << "," << fmt(r.*c.field);
    ValidationMetrics v = r.val.value_or(ValidationMetrics{});
    for (const ValColumn& c : kValColumns) o << "," << (r.val ? fmt(c.field(v)) : "nan");
    o << "\n";
  }
  return o.str();
}

std::vector<LogRow> log_rows_from_csv(const std::string& csv) {
  std::istringstream in(csv);
  std::string line;
  std::vector<LogRow> rows;
  if (!std::getline(in, line)) return rows;
  const std::vector<std::string> header = split_csv_line(line);
  constexpr std::size_t kAbsent = static_cast<std::size_t>(-1);
  auto column = [&](const std::string& name, bool optional = false) {
    const auto it = std::find(header.begin(), header.end(), name);
    if (it != header.end()) return static_cast<std::size_t>(it - header.begin());
    if (optional) return kAbsent;
    throw std::runtime_error("train log: no column \"" + name + "\"");
  };
  const std::size_t step = column("step"), stage = column("stage"), val_loss = column("val_loss");
  std::vector<std::size_t> train_at, val_at;
  for (const TrainColumn& c : kTrainColumns) train_at.push_back(column(c.name));
  for (const ValColumn& c : kValColumns) val_at.push_back(column(c.name, c.optional));
  while (std::getline(in, line)) {
    const std::vector<std::string> f = split_csv_line(line);
    if (f.size() < header.size()) continue;
    LogRow r;
    r.step = std::stoll(f[step]);
    r.stage = std::stoll(f[stage]);
    for (std::size_t i = 0; i < train_at.size(); ++i) {
      r.*kTrainColumns[i].field = parse_num(f[train_at[i]]);
    }
    if (std::isfinite(parse_num(f[val_loss]))) {
      ValidationMetrics v;
      for (std::size_t i = 0; i < val_at.size(); ++i) {
        kValColumns[i].field(v) = val_at[i] == kAbsent ? parse_num("nan") : parse_num(f[val_at[i]]);
      }
      r.val = v;
    }
    rows.push_back(r);
  }
  return rows;
}

struct Trainer::Optim {
  std::unique_ptr<torch::optim::AdamW> adamw;
  std::vector<at::Tensor> params;
};

// The data thread: draws the batches of the coming steps, in step order, with
// the trainer's sampler (which nothing else touches while it runs), and keeps
// up to `capacity` of them ready.
struct Trainer::Prefetch {
  struct Item {
    Batch batch;
    std::string sampler_state;  // the sampler's RNG state after drawing it
    std::exception_ptr error;   // set instead when drawing failed
  };
  std::mutex mutex;
  std::condition_variable changed;
  std::deque<Item> ready;
  std::size_t capacity = 1;
  bool stop = false;
  std::thread thread;
};

Trainer::Trainer(const TrainConfig& config, const TrainOptions& options)
    : config_(config),
      options_(options),
      device_(training_device(options.device, options.distributed)) {
  validate_train_config(config_);
  if (options_.out_dir.empty()) throw std::invalid_argument("Trainer: out_dir is empty");
  const DistributedEnv& env = options_.distributed;
  if (env.distributed()) {
    for (const TrainStage& s : config_.stages) {
      if (s.batch_size % env.world_size != 0) {
        throw ConfigError("training config: stage \"" + s.name + "\": batch_size " +
                          std::to_string(s.batch_size) +
                          " (the global batch) does not split evenly over " +
                          std::to_string(env.world_size) + " ranks");
      }
    }
    dp_ = std::make_unique<DataParallel>(env, options_.data_parallel, device_);
    if (env.rank != 0) options_.quiet = true;  // rank 0 speaks for the job
  }
  mixed_precision_ = config_.amp == "bf16" || (config_.amp == "auto" && device_.is_cuda()) ||
                     (config_.amp == "native" && (device_.is_cuda() || cpu_has_native_bfloat16()));
  if (mixed_precision_ && device_.is_cpu() && !cpu_has_native_bfloat16() &&
      !config_.allow_emulated_precision) {
    throw ConfigError(
        "training config: amp \"bf16\" on the CPU: this CPU has no native bfloat16 arithmetic "
        "(AVX512-BF16 or AMX-BF16), so bfloat16 would run emulated, slower than float32; set amp "
        "to \"native\" (bfloat16 where the CPU has it), \"auto\" or \"off\" (float32 on the "
        "CPU), or allow_emulated_precision to true to measure it anyway");
  }
  if (!options_.model_override.empty()) config_.model = options_.model_override;
  if (is_root()) fs::create_directories(fs::path(options_.out_dir) / "checkpoint");
  at::manual_seed(options_.seed);
  ModelConfig model_config = resolve_model_config(config_.model);
  if (config_.image_size % model_config.dust3r.patch_size != 0) {
    throw std::invalid_argument("image_size must be a multiple of the model's patch size");
  }
  // The weights run well only at the size they are trained at: the files
  // written record it, and the pipeline follows it by default.
  model_config.input_width = model_config.input_height = config_.image_size;
  model_ = std::make_unique<Long3rModel>(model_config);
  if (config_.weight_init == "croco") init_croco_weights(*model_);
  if (!options_.init_checkpoint.empty()) {
    init_report_ = init_from_checkpoint(*model_, options_.init_checkpoint);
  }
  model_->to(device_);
  model_->set_training(true);

  // Weight decay on matrices only (DUSt3R / timm's param_groups_weight_decay):
  // not on biases and LayerNorm gains.
  optim_ = std::make_unique<Optim>();
  std::vector<at::Tensor> decay, no_decay;
  // The DPT head registers some tensors under two names (the official
  // scratch.layer_rn.N / scratch.layerN_rn alias): each tensor goes into the
  // optimiser once, or AdamW would update it twice per step and its saved
  // state would not map back onto the parameters on resume.
  std::set<const void*> seen;
  for (const auto& kv : model_->module().named_parameters()) {
    if (!seen.insert(kv.value().unsafeGetTensorImpl()).second) continue;
    optim_->params.push_back(kv.value());
    (kv.value().dim() >= 2 ? decay : no_decay).push_back(kv.value());
  }
  // The pixel head of a cross-view completion stage: trained with the model,
  // kept in the checkpoints, never in the exported model (CroCo's
  // prediction_head, which DUSt3R does not carry either). Made after the
  // model, so a config without such a stage initialises as before.
  const bool completes_views =
      std::any_of(config_.stages.begin(), config_.stages.end(),
                  [](const TrainStage& s) { return s.task == kTaskCrossViewCompletion; });
  if (completes_views) {
    const Dust3rConfig& d = model_->config().dust3r;
    completion_head_ = torch::nn::Linear(d.dec_embed_dim, d.patch_size * d.patch_size * 3);
    completion_head_->to(device_);
    optim_->params.push_back(completion_head_->weight);
    optim_->params.push_back(completion_head_->bias);
    decay.push_back(completion_head_->weight);
    no_decay.push_back(completion_head_->bias);
  }
  torch::optim::AdamWOptions defaults(config_.stages[0].lr);
  defaults.betas({config_.beta1, config_.beta2}).weight_decay(config_.weight_decay);
  std::vector<torch::optim::OptimizerParamGroup> groups;
  groups.emplace_back(decay, std::make_unique<torch::optim::AdamWOptions>(defaults));
  auto nd = std::make_unique<torch::optim::AdamWOptions>(defaults);
  nd->weight_decay(0.0);
  groups.emplace_back(no_decay, std::move(nd));
  optim_->adamw = std::make_unique<torch::optim::AdamW>(std::move(groups), defaults);

  if (options_.render_threads < 0 || options_.prefetch_batches < 0 ||
      !(options_.time_budget_s >= 0.0)) {
    throw std::invalid_argument(
        "Trainer: render_threads, prefetch_batches and time_budget_s "
        "must be >= 0");
  }
  const int render_threads =
      options_.render_threads > 0 ? options_.render_threads : at::get_num_threads();
  sampler_ = std::make_unique<SequenceSampler>(
      config_.data, static_cast<int>(config_.image_size), options_.seed, render_threads,
      options_.extensions.open_recorded, options_.extensions.open_dataset);
  if (!options_.frame_cache.empty()) {
    auto cache =
        std::make_shared<const FrameCache>(options_.frame_cache, config_.data.synth,
                                           config_.data.synth.render_side(config_.image_size));
    if (!options_.quiet) {
      std::printf("frame cache %s: %lld scenes x %lld frames at %d px (%.2f GB), mapped\n",
                  cache->path().c_str(), static_cast<long long>(cache->scenes()),
                  static_cast<long long>(cache->frames_per_scene()), cache->render_size(),
                  static_cast<double>(cache->file_bytes()) / 1e9);
    }
    sampler_->set_frame_cache(std::move(cache));
  }
  // Rank 0 validates for the job.
  for (int64_t i = 0; is_root() && i < config_.validation.sequences; ++i) {
    val_sequences_.push_back(
        sampler_->validation_sequence(i, config_.validation.frames, config_.validation.stride));
  }
  if (is_root() && config_.validation.blind_scenes > 0) {
    for (const int64_t stride : config_.validation.blind_strides) {
      ValidationConfig one = config_.validation;
      one.blind_strides = {stride};
      blind_sets_.emplace_back(stride, sampler_->blind_sequences(one));
    }
  }
  sampler_state_ = sampler_->rng_state();
  if (options_.resume) {
    const fs::path latest = fs::path(options_.out_dir) / "checkpoint" / "latest";
    if (!fs::exists(latest)) {
      throw std::runtime_error("--resume: no checkpoint in " + latest.parent_path().string());
    }
    std::string name = read_text(latest);
    while (!name.empty() && (name.back() == '\n' || name.back() == ' ')) name.pop_back();
    load_checkpoint((latest.parent_path() / name).string());
  }
  if (dp_) {
    // Every rank starts from rank 0's weights (as DistributedDataParallel
    // does), and hooks its gradients into the buckets.
    std::vector<at::Tensor> state = optim_->params;
    for (const auto& kv : model_->module().named_buffers()) state.push_back(kv.value());
    {
      torch::NoGradGuard no_grad;
      dp_->broadcast(state);
    }
    dp_->attach(optim_->params);
  }
  start_time_ = now_s();
}

Trainer::~Trainer() { stop_prefetch(); }

void Trainer::stop_prefetch() {
  if (!prefetch_) return;
  {
    std::lock_guard<std::mutex> lock(prefetch_->mutex);
    prefetch_->stop = true;
  }
  prefetch_->changed.notify_all();
  prefetch_->thread.join();
  prefetch_.reset();
  // Batches drawn ahead and not used: the sampler goes back to where the
  // steps left it, so that they are drawn again, identically.
  sampler_->set_rng_state(sampler_state_);
}

int64_t Trainer::shard_size(int64_t batch_size) const {
  return batch_size / (dp_ ? dp_->world_size() : 1);
}

Batch Trainer::draw_shard(int64_t batch_size, int64_t frames) {
  const int64_t shard = shard_size(batch_size), rank = dp_ ? dp_->rank() : 0;
  return sampler_->sample_batch(batch_size, frames, rank * shard, shard);
}

Batch Trainer::next_batch(int64_t batch_size, int64_t frames) {
  if (options_.prefetch_batches == 0) {
    Batch b = draw_shard(batch_size, frames);
    sampler_state_ = sampler_->rng_state();
    return b;
  }
  if (!prefetch_) {
    prefetch_ = std::make_unique<Prefetch>();
    prefetch_->capacity = static_cast<std::size_t>(options_.prefetch_batches);
    Prefetch* q = prefetch_.get();
    const int64_t first_step = step_;
    q->thread = std::thread([this, q, first_step] {
      for (int64_t k = first_step;; ++k) {
        {
          std::unique_lock<std::mutex> lock(q->mutex);
          q->changed.wait(lock, [q] { return q->stop || q->ready.size() < q->capacity; });
          if (q->stop) return;
        }
        Prefetch::Item item;
        try {
          const TrainStage& stage = stage_of_step(k);
          item.batch = draw_shard(stage.batch_size, stage.frames);
          item.sampler_state = sampler_->rng_state();
        } catch (...) {
          item.error = std::current_exception();
        }
        const bool failed = static_cast<bool>(item.error);
        {
          std::lock_guard<std::mutex> lock(q->mutex);
          q->ready.push_back(std::move(item));
        }
        q->changed.notify_all();
        if (failed) return;
      }
    });
  }
  Prefetch::Item item;
  {
    std::unique_lock<std::mutex> lock(prefetch_->mutex);
    prefetch_->changed.wait(lock, [this] { return !prefetch_->ready.empty(); });
    item = std::move(prefetch_->ready.front());
    prefetch_->ready.pop_front();
  }
  prefetch_->changed.notify_all();
  if (item.error) {
    prefetch_->thread.join();
    prefetch_.reset();
    sampler_->set_rng_state(sampler_state_);
    std::rethrow_exception(item.error);
  }
  if (item.batch.frames.size() != static_cast<std::size_t>(frames) ||
      item.batch.pts.size(0) != shard_size(batch_size)) {
    throw std::logic_error("Trainer: a prefetched batch does not fit its step");
  }
  sampler_state_ = std::move(item.sampler_state);
  return std::move(item.batch);
}

const TrainStage& Trainer::stage_of_step(int64_t step) const {
  const int64_t index = std::min<int64_t>(stage_at(config_, step).index,
                                          static_cast<int64_t>(config_.stages.size()) - 1);
  return config_.stages[static_cast<std::size_t>(index)];
}

void Trainer::apply_stage(int64_t stage) {
  if (stage == applied_stage_) return;
  const bool freeze = config_.stages[static_cast<std::size_t>(stage)].freeze_encoder;
  for (const auto& kv : model_->module().named_parameters()) {
    at::Tensor p = kv.value();
    const bool train = !(freeze && is_encoder_parameter(kv.key()));
    p.set_requires_grad(train);
    if (!train) p.mutable_grad() = at::Tensor();  // AdamW then skips it entirely
  }
  applied_stage_ = stage;
}

void Trainer::set_lr(double lr) {
  for (auto& g : optim_->adamw->param_groups()) {
    static_cast<torch::optim::AdamWOptions&>(g.options()).lr(lr);
  }
}

LogRow Trainer::step() {
  const double t0 = now_s();
  const StagePosition pos = stage_at(config_, step_);
  const int64_t stage_index =
      std::min<int64_t>(pos.index, static_cast<int64_t>(config_.stages.size()) - 1);
  const TrainStage& stage = config_.stages[static_cast<std::size_t>(stage_index)];
  apply_stage(stage_index);
  const double lr = learning_rate_at(config_, step_);
  set_lr(lr);

  const Batch batch = next_batch(stage.batch_size, stage.frames).to(device_);
  const double data_s = now_s() - t0;
  for (at::Tensor& p : optim_->params) p.mutable_grad() = at::Tensor();
  if (dp_) dp_->begin_backward();
  const LossTerms loss = stage.task == kTaskCrossViewCompletion
                             ? completion_step(batch, stage.mask_ratio)
                             : sequence_step(batch);
  // The logged figures: the ranks' mean (each rank's loss is its share of
  // the global batch's, times the ranks), the same on every rank.
  at::Tensor figures = at::tensor({loss.total.item<double>(), loss.conf_loss.item<double>(),
                                   loss.scale_loss.item<double>(), loss.regression},
                                  at::kDouble);
  if (dp_) {
    dp_->finish_backward();
    dp_->sum(figures);
    figures /= static_cast<double>(dp_->world_size());
  }
  const double* fig = figures.data_ptr<double>();

  // Clipping to a global L2 norm of grad_clip; none is an infinite bound,
  // which scales by exactly 1. The norm is logged either way.
  const double max_norm =
      config_.grad_clip > 0.0 ? config_.grad_clip : std::numeric_limits<double>::infinity();
  const double grad_norm = torch::nn::utils::clip_grad_norm_(optim_->params, max_norm);
  const double loss_value = fig[0];
  if (std::isfinite(loss_value) && std::isfinite(grad_norm)) {
    optim_->adamw->step();
  } else if (!options_.quiet) {
    // A non-finite step would poison the weights and Adam's moments: skip it.
    std::fprintf(stderr, "long3r_train: step %lld: non-finite loss/gradient, update skipped\n",
                 static_cast<long long>(step_ + 1));
  }
  for (at::Tensor& p : optim_->params) p.mutable_grad() = at::Tensor();
  ++step_;
  if (dp_ && options_.verify_replicas) verify_replicas();

  LogRow row;
  row.step = step_;
  row.stage = stage_index + 1;
  row.loss = loss_value;
  row.conf_loss = fig[1];
  row.scale_loss = fig[2];
  row.regression = fig[3];
  row.lr = lr;
  row.grad_norm = grad_norm;
  row.step_s = now_s() - t0;
  row.data_s = data_s;
  row.wall_s = wall_offset_s_ + now_s() - start_time_;
  log_.push_back(row);
  return row;
}

ValidationMetrics Trainer::run_validation() {
  ValidationMetrics v = validate(*model_, val_sequences_, config_.loss, config_.validation,
                                 options_.extensions.score);
  for (const auto& [stride, sequences] : blind_sets_) {
    v.blind_per_stride.emplace_back(stride, blind_control(*model_, sequences));
  }
  if (!blind_sets_.empty()) {
    v.blind = v.blind_per_stride.front().second;
    const std::vector<SequenceSample>& pairs = blind_sets_.front().second;
    const TrainStage& stage = stage_of_step(std::max<int64_t>(0, step_ - 1));
    if (stage.task == kTaskCrossViewCompletion && config_.validation.blind_frames == 2 &&
        pairs.size() >= 2) {
      v.completion = completion_control(*model_, completion_head_, pairs, stage.mask_ratio);
    }
  }
  // set_training() re-enabled every parameter: re-apply the stage's freeze.
  applied_stage_ = -1;
  return v;
}

void Trainer::write_log() {
  if (!is_root()) return;
  const fs::path path = fs::path(options_.out_dir) / "train_log.csv";
  if (log_rewrite_ || log_rows_written_ == 0 || !fs::exists(path)) {
    write_file_atomically(path.string(), log_rows_to_csv(log_));
  } else if (log_rows_written_ < log_.size()) {
    // Only the new rows, so that a long run's log costs what its new rows
    // do. A line cut short by a crash is skipped by the reader, and a resume
    // writes the file anew up to its checkpoint.
    const std::vector<LogRow> rows(log_.begin() + static_cast<std::ptrdiff_t>(log_rows_written_),
                                   log_.end());
    std::string text = log_rows_to_csv(rows);
    text.erase(0, text.find('\n') + 1);  // the header is in the file
    append_to_file(path, text);
  }
  log_rows_written_ = log_.size();
  log_rewrite_ = false;
  // The blind control at each stride: appended only (a resume cuts it back).
  std::string text;
  auto first = log_.end();
  while (first != log_.begin() && std::prev(first)->step > blind_step_written_) --first;
  for (auto r = first; r != log_.end(); ++r) {
    if (!r->val) continue;
    for (const auto& [stride, b] : r->val->blind_per_stride) {
      text += std::to_string(r->step) + "," + std::to_string(config_.validation.blind_frames) +
              "," + std::to_string(stride) + "," + std::to_string(b.frames) + "," +
              fmt(b.motion_px) + "," + fmt(b.reg_true) + "," + fmt(b.reg_blind) + "," +
              fmt(b.blind_ratio) + "," + fmt(b.shape_err) + "," + fmt(b.rot_err_deg) + "," +
              fmt(b.rot_true_deg) + "\n";
    }
    blind_step_written_ = r->step;
  }
  if (!text.empty()) {
    const fs::path blind = fs::path(options_.out_dir) / "blind_control.csv";
    if (blind_file_fresh_ || !fs::exists(blind)) {  // a new run: no rows of another
      write_file_atomically(blind.string(), std::string(kBlindHeader) + "\n" + text);
      blind_file_fresh_ = false;
    } else {
      append_to_file(blind, text);
    }
  }
}

void Trainer::save_checkpoint() {
  if (!is_root()) return;  // rank 0 writes for the job
  // The log first: a checkpoint's rows are in train_log.csv before the
  // checkpoint exists (a crash between them leaves rows past the newest
  // checkpoint, which a resume drops).
  write_log();
  const fs::path root = fs::path(options_.out_dir) / "checkpoint";
  char name[32];
  std::snprintf(name, sizeof(name), "step_%08lld.pt", static_cast<long long>(step_));
  torch::serialize::OutputArchive bundle, weights, optimizer;
  model_->module().save(weights);
  bundle.write("weights", weights);
  if (completion_head_) {
    torch::serialize::OutputArchive head;
    completion_head_->save(head);
    bundle.write("completion_head", head);
  }
  optim_->adamw->save(optimizer);
  bundle.write("optimizer", optimizer);
  bundle.write("step", step_);
  bundle.write("seed", static_cast<int64_t>(options_.seed));  // for the record only
  // For the record too: a run resumes at any world size (the batches are
  // global, drawn alike by every rank).
  bundle.write("world_size", static_cast<int64_t>(dp_ ? dp_->world_size() : 1));
  bundle.write("sampler_rng", sampler_state_);
  {
    at::Generator gen = at::detail::getDefaultCPUGenerator();
    std::lock_guard<std::mutex> lock(gen.mutex());
    bundle.write("torch_cpu_rng", gen.get_state(), /*is_buffer=*/true);
  }
  bundle.write("wall_s", wall_offset_s_ + now_s() - start_time_);
  bundle.write("model_config", model_config_to_json(model_->config()));
  bundle.write("train_config", train_config_to_json(config_));
  // The log itself is train_log.csv beside the checkpoints, appended to.
  bundle.write("train_log_rows", static_cast<int64_t>(log_.size()));
  std::ostringstream bytes;
  bundle.save_to(bytes);
  // The file appears complete or not at all; "latest" moves only then.
  write_file_atomically((root / name).string(), bytes.str());
  write_file_atomically((root / "latest").string(), std::string(name) + "\n");
  std::vector<fs::path> old;
  for (const auto& e : fs::directory_iterator(root)) {
    const std::string n = e.path().filename().string();
    if (e.is_regular_file() && n.rfind("step_", 0) == 0 && e.path().extension() == ".pt") {
      old.push_back(e.path());
    }
  }
  std::sort(old.begin(), old.end());
  while (static_cast<int64_t>(old.size()) > config_.keep_checkpoints) {
    fs::remove(old.front());
    old.erase(old.begin());
  }
}

void Trainer::load_checkpoint(const std::string& path) {
  stop_prefetch();  // its batches belong to the steps being replaced
  if (fs::is_directory(path)) {
    throw std::runtime_error("checkpoint " + path +
                             " is a folder of separate files, which this version does not read");
  }
  torch::serialize::InputArchive bundle;
  bundle.load_from(path, device_);
  c10::IValue value;
  bundle.read("model_config", value);
  // Compared as configurations, not as text. Checkpoints written before the
  // input size was recorded hold none: theirs is this run's image_size.
  ModelConfig stored = parse_model_config(value.toStringRef());
  if (stored.input_width == 0 && stored.input_height == 0) {
    stored.input_width = model_->config().input_width;
    stored.input_height = model_->config().input_height;
  }
  if (model_config_to_json(stored) != model_config_to_json(model_->config())) {
    throw std::runtime_error("checkpoint " + path +
                             " holds a different model configuration than --model-config/config");
  }
  torch::serialize::InputArchive weights, optimizer;
  bundle.read("weights", weights);
  model_->module().load(weights);
  model_->set_training(true);
  applied_stage_ = -1;
  if (completion_head_) {
    torch::serialize::InputArchive head;
    if (!bundle.try_read("completion_head", head)) {
      throw std::runtime_error("checkpoint " + path +
                               " has no cross-view completion head, which this configuration's "
                               "cross_view_completion stage needs");
    }
    completion_head_->load(head);
  }
  bundle.read("optimizer", optimizer);
  optim_->adamw->load(optimizer);
  bundle.read("step", value);
  step_ = value.toInt();
  bundle.read("sampler_rng", value);
  sampler_->set_rng_state(value.toStringRef());
  sampler_state_ = value.toStringRef();
  {
    at::Tensor state;
    bundle.read("torch_cpu_rng", state, /*is_buffer=*/true);
    at::Generator gen = at::detail::getDefaultCPUGenerator();
    std::lock_guard<std::mutex> lock(gen.mutex());
    gen.set_state(state.to(at::kCPU));
  }
  bundle.read("wall_s", value);
  wall_offset_s_ = value.toDouble();
  start_time_ = now_s();
  // The log up to the checkpoint (a crash may have logged further steps):
  // in the checkpoint itself in files written before the log was appended
  // to, else the rows of train_log.csv up to the checkpoint's step.
  if (bundle.try_read("train_log_csv", value)) {
    log_ = log_rows_from_csv(value.toStringRef());
  } else if (is_root()) {
    bundle.read("train_log_rows", value);
    const int64_t rows = value.toInt();
    const fs::path csv = fs::path(options_.out_dir) / "train_log.csv";
    std::vector<LogRow> logged =
        fs::exists(csv) ? log_rows_from_csv(read_text(csv)) : std::vector<LogRow>{};
    logged.erase(std::remove_if(logged.begin(), logged.end(),
                                [this](const LogRow& r) { return r.step > step_; }),
                 logged.end());
    if (static_cast<int64_t>(logged.size()) != rows) {
      throw std::runtime_error("checkpoint " + path + " (step " + std::to_string(step_) +
                               ") continues a log of " + std::to_string(rows) + " rows, but " +
                               csv.string() + " holds " + std::to_string(logged.size()) +
                               " up to that step: copy the run's train_log.csv beside its "
                               "checkpoint folder");
    }
    log_ = std::move(logged);
  } else {
    log_.clear();  // rank 0 keeps the job's log
  }
  // The file is written anew, up to the checkpoint, at the next write.
  log_rows_written_ = log_.size();
  log_rewrite_ = true;
  // The blind control's rows past the checkpoint go now (they are appended
  // to, never written anew).
  blind_step_written_ = step_;
  const fs::path blind = fs::path(options_.out_dir) / "blind_control.csv";
  if (is_root() && fs::exists(blind)) {
    std::istringstream in(read_text(blind));
    std::string line, kept;
    while (std::getline(in, line)) {
      const std::vector<std::string> cells = split_csv_line(line);
      if (cells.size() != 11) continue;  // cut short by a crash
      const bool keep = line == kBlindHeader || parse_num(cells[0]) <= static_cast<double>(step_);
      if (keep) kept += line + "\n";
    }
    write_file_atomically(blind.string(), kept);
  }
  blind_file_fresh_ = false;
}

void Trainer::write_outputs() {
  if (!is_root()) return;
  const fs::path out(options_.out_dir);
  model_->save((out / "model.safetensors").string());
  write_log();
  if (options_.extensions.write_plot) {
    options_.extensions.write_plot(log_, (out / "loss_curve.png").string());
  }
  write_file_atomically((out / "train_config.json").string(), train_config_to_json(config_));
  // The last validation, for whoever brings the folder back from a remote run.
  const auto last = std::find_if(log_.rbegin(), log_.rend(), [](const LogRow& r) { return r.val; });
  if (last != log_.rend()) {
    const ValidationMetrics& v = *last->val;
    const PredictionMetrics& p = v.prediction;
    nlohmann::json j;
    j["step"] = last->step;
    j["steps_planned"] = config_.total_steps();
    j["stop_reason"] = stop_reason_.empty() ? "running" : stop_reason_;
    j["model"] = config_.model;
    j["device"] = device_.str();
    j["wall_s"] = last->wall_s;
    j["sequences"] = v.sequences;
    j["loss"] = v.loss;
    j["regression"] = v.regression;
    j["registered"] = v.registered;
    j["blind_ratio"] = v.blind.blind_ratio;
    j["shape_err"] = v.blind.shape_err;
    j["reg_true"] = v.blind.reg_true;
    j["reg_blind"] = v.blind.reg_blind;
    j["rot_err_deg"] = v.blind.rot_err_deg;
    j["rot_true_deg"] = v.blind.rot_true_deg;
    j["blind_frames"] = v.blind.frames;
    j["completion_true"] = v.completion.loss_true;
    j["completion_shuffled"] = v.completion.loss_shuffled;
    j["pointmap_err_m"] = p.pointmap_error;
    j["acc_mean_m"] = p.acc_mean;
    j["comp_mean_m"] = p.comp_mean;
    j["nc_mean"] = p.nc_mean;
    j["ate_rmse_m"] = p.ate_rmse;
    j["frames"] = p.frames;
    j["posed"] = p.posed;
    // NaN (a figure this build does not compute) is written as null.
    write_file_atomically((out / "validation.json").string(), j.dump(1) + "\n");
  }
}

LossTerms Trainer::sequence_step(const Batch& batch) {
  std::vector<StreamOutput> outputs, coarse;
  {
    // bfloat16 needs no loss scaling (which libtorch's C++ API lacks).
    std::optional<AutocastOn> autocast;
    if (mixed_precision_) autocast.emplace(device_.type(), at::kBFloat16);
    outputs = model_->forward_sequence(batch.frames, config_.loss.coarse ? &coarse : nullptr);
  }
  BatchShards shards;
  if (dp_) {
    shards.ranks = dp_->world_size();
    shards.sum = [this](const at::Tensor& t) { dp_->sum(t); };
  }
  LossTerms loss =
      sequence_loss(outputs, coarse, batch.pts, batch.valid, config_.loss, dp_ ? &shards : nullptr);
  loss.total.backward();
  return loss;
}

LossTerms Trainer::completion_step(const Batch& batch, double mask_ratio) {
  // The later frame is completed from the earlier one, as the coarse branch
  // decodes frame t+1 against frame t in the stream.
  const at::Tensor& masked = batch.frames[1];
  const at::Tensor& reference = batch.frames[0];
  const int64_t patch = model_->config().dust3r.patch_size;
  const at::Tensor visible =
      draw_visible_patches((masked.size(2) / patch) * (masked.size(3) / patch), mask_ratio);
  at::Tensor pred;
  {
    std::optional<AutocastOn> autocast;
    if (mixed_precision_) autocast.emplace(device_.type(), at::kBFloat16);
    pred = completion_head_(model_->complete_view(masked, reference, visible));
  }
  LossTerms loss;
  loss.total = completion_loss(pred, patchify(masked, patch), visible);
  loss.total.backward();
  // No confidence, scale or pointmap terms in this task: the log's columns
  // for them are 0 / NaN and `loss` is the completion error.
  loss.conf_loss = at::zeros({}, at::kFloat);
  loss.scale_loss = at::zeros({}, at::kFloat);
  loss.regression = std::numeric_limits<double>::quiet_NaN();
  return loss;
}

void Trainer::run() {
  int64_t end = config_.total_steps();
  stop_reason_ = "schedule";
  if (options_.max_steps >= 0 && options_.max_steps < end) {
    end = options_.max_steps;
    stop_reason_ = "max_steps";
  }
  const double run_start = now_s();
  int64_t steps_this_run = 0;
  if (!options_.quiet) {
    int64_t params = 0;
    for (const at::Tensor& p : optim_->params) params += p.numel();
    std::printf(
        "long3r_train: model %s (%.2f M parameters), %lld steps in %zu stages, device %s%s\n",
        config_.model.c_str(), static_cast<double>(params) / 1e6,
        static_cast<long long>(config_.total_steps()), config_.stages.size(), device_.str().c_str(),
        mixed_precision_ ? " (bf16 autocast, fp32 weights)" : " (fp32)");
    if (dp_) {
      std::printf("data parallel: %d ranks (%s, %s), each stage's batch split evenly over them\n",
                  dp_->world_size(), options_.distributed.launcher.c_str(), dp_->backend().c_str());
    }
    if (step_ > 0) std::printf("resumed at step %lld\n", static_cast<long long>(step_));
    std::fflush(stdout);
  }
  bool validated_last = false;
  bool stopped = false;
  while (step_ < end) {
    if (options_.stop_requested) {
      stopped = options_.stop_requested();
      if (dp_) stopped = dp_->any(stopped);  // the ranks stop together
      if (stopped) {
        stop_reason_ = "stop_request";
        if (!options_.quiet) {
          std::printf("stop requested: ending after step %lld (%lld steps of this run)\n",
                      static_cast<long long>(step_), static_cast<long long>(steps_this_run));
          std::fflush(stdout);
        }
        break;
      }
    }
    if (options_.time_budget_s > 0.0 && steps_this_run > 0) {
      const double spent = now_s() - run_start;
      bool out_of_time =
          spent + spent / static_cast<double>(steps_this_run) > options_.time_budget_s;
      if (dp_) out_of_time = dp_->any(out_of_time);  // the ranks stop together
      if (out_of_time) {
        stop_reason_ = "time_budget";
        if (!options_.quiet) {
          std::printf("time budget of %.0f s reached after %lld steps of this run (%.0f s)\n",
                      options_.time_budget_s, static_cast<long long>(steps_this_run), spent);
        }
        break;
      }
    }
    step();
    ++steps_this_run;
    validated_last = false;
    const ValidationConfig& vc = config_.validation;
    if (is_root() && vc.sequences > 0 && vc.every > 0 && step_ % vc.every == 0) {
      log_.back().val = run_validation();
      validated_last = true;
    }
    if (!options_.quiet && (step_ % config_.log_every == 0 || log_.back().val)) {
      const LogRow& r = log_.back();
      std::printf(
          "step %6lld/%lld stage %lld  loss %.4f (conf %.4f scale %.4f regr %.4f)  "
          "lr %.3g  |g| %.3g  %.2f s/step (data %.2f s)",
          static_cast<long long>(r.step), static_cast<long long>(end),
          static_cast<long long>(r.stage), r.loss, r.conf_loss, r.scale_loss, r.regression, r.lr,
          r.grad_norm, r.step_s, r.data_s);
      if (r.val) {
        std::printf("  | val loss %.4f pm_err %.3f m Acc %.3f Comp %.3f NC %.3f ATE %.3f m",
                    r.val->loss, r.val->prediction.pointmap_error, r.val->prediction.acc_mean,
                    r.val->prediction.comp_mean, r.val->prediction.nc_mean,
                    r.val->prediction.ate_rmse);
        if (r.val->blind.frames > 0) {
          std::printf("  blind ratio %.3f (shape %.3f, rot err %.2f of %.2f deg)",
                      r.val->blind.blind_ratio, r.val->blind.shape_err, r.val->blind.rot_err_deg,
                      r.val->blind.rot_true_deg);
        }
        if (std::isfinite(r.val->completion.loss_true)) {
          std::printf("  completion %.4f (shuffled reference %.4f)", r.val->completion.loss_true,
                      r.val->completion.loss_shuffled);
        }
      }
      std::printf("\n");
      std::fflush(stdout);
    }
    if (config_.checkpoint_every > 0 && step_ % config_.checkpoint_every == 0) {
      save_checkpoint();
      write_outputs();
    }
  }
  stop_prefetch();
  if (is_root() && config_.validation.sequences > 0 && !validated_last && !stopped &&
      !log_.empty()) {
    log_.back().val = run_validation();
    // A row already in the file cannot be appended to again.
    if (log_rows_written_ >= log_.size()) log_rewrite_ = true;
  }
  save_checkpoint();
  write_outputs();
  if (dp_) dp_->barrier();  // the job ends once rank 0's outputs are written
}

void Trainer::verify_replicas() {
  const uint64_t mine = tensors_fingerprint(optim_->params);
  const std::vector<int64_t> all = dp_->gather(static_cast<int64_t>(mine));
  for (std::size_t r = 0; r < all.size(); ++r) {
    if (all[r] != all[0]) {
      throw std::runtime_error("data parallel: after step " + std::to_string(step_) + " rank " +
                               std::to_string(r) + " holds other weights than rank 0");
    }
  }
  if (is_root()) {
    std::printf("step %lld: weights bit-identical on %d ranks (fingerprint %016llx)\n",
                static_cast<long long>(step_), dp_->world_size(),
                static_cast<unsigned long long>(mine));
    std::fflush(stdout);
  }
}

}  // namespace long3r

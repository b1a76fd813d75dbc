// The training loop: curriculum stages, AdamW with the schedule, clipping,
// autocast on CUDA, checkpoints (atomic, resumable), validation and logs.
#include <ATen/ATen.h>
#include <ATen/CPUGeneratorImpl.h>
#include <ATen/Parallel.h>
#include <ATen/autocast_mode.h>
#include <ATen/core/Generator.h>
#include <torch/cuda.h>
#include <torch/nn/module.h>
#include <torch/optim/adamw.h>
#include <torch/serialize.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>
#include <mutex>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>
#include <stdexcept>

#include "long3r/dataset/image_file.hpp"
#include "long3r/eval/eval.hpp"
#include "long3r/io/atomic_file.hpp"
#include "long3r/model/model_config.hpp"
#include "long3r/model/safetensors.hpp"
#include "long3r/train/train.hpp"

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

std::string to_hex(const at::Tensor& bytes) {
  const at::Tensor c = bytes.to(at::kCPU).contiguous();
  const uint8_t* d = c.data_ptr<uint8_t>();
  static const char* digits = "0123456789abcdef";
  std::string s;
  s.reserve(static_cast<std::size_t>(c.numel()) * 2);
  for (int64_t i = 0; i < c.numel(); ++i) {
    s.push_back(digits[d[i] >> 4]);
    s.push_back(digits[d[i] & 15]);
  }
  return s;
}

at::Tensor from_hex(const std::string& s) {
  at::Tensor t = at::empty({static_cast<int64_t>(s.size() / 2)}, at::kByte);
  uint8_t* d = t.data_ptr<uint8_t>();
  for (std::size_t i = 0; i + 1 < s.size(); i += 2) {
    d[i / 2] = static_cast<uint8_t>(std::stoi(s.substr(i, 2), nullptr, 16));
  }
  return t;
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

const char* kCsvHeader =
    "step,stage,loss,conf_loss,scale_loss,regression,lr,grad_norm,step_s,data_s,wall_s,"
    "val_loss,val_regression,val_pointmap_err_m,val_acc_mean_m,val_acc_median_m,"
    "val_comp_mean_m,val_comp_median_m,val_nc_mean,val_nc_median,val_ate_rmse_m";

std::vector<LogRow> read_log_csv(const fs::path& p) {
  std::vector<LogRow> rows;
  std::ifstream in(p);
  std::string line;
  if (!std::getline(in, line)) return rows;  // header
  while (std::getline(in, line)) {
    std::vector<std::string> f;
    std::stringstream ss(line);
    std::string cell;
    while (std::getline(ss, cell, ',')) f.push_back(cell);
    if (f.size() < 21) continue;
    LogRow r;
    r.step = std::stoll(f[0]);
    r.stage = std::stoll(f[1]);
    r.loss = parse_num(f[2]);
    r.conf_loss = parse_num(f[3]);
    r.scale_loss = parse_num(f[4]);
    r.regression = parse_num(f[5]);
    r.lr = parse_num(f[6]);
    r.grad_norm = parse_num(f[7]);
    r.step_s = parse_num(f[8]);
    r.data_s = parse_num(f[9]);
    r.wall_s = parse_num(f[10]);
    if (std::isfinite(parse_num(f[11]))) {
      ValidationMetrics v;
      v.loss = parse_num(f[11]);
      v.regression = parse_num(f[12]);
      v.pointmap_error = parse_num(f[13]);
      v.acc_mean = parse_num(f[14]);
      v.acc_median = parse_num(f[15]);
      v.comp_mean = parse_num(f[16]);
      v.comp_median = parse_num(f[17]);
      v.nc_mean = parse_num(f[18]);
      v.nc_median = parse_num(f[19]);
      v.ate_rmse = parse_num(f[20]);
      r.val = v;
    }
    rows.push_back(r);
  }
  return rows;
}

// Autocast for the forward pass on CUDA (bf16 needs no loss scaling, which
// libtorch's C++ API lacks); restores the previous state on exit.
class AutocastGuard {
 public:
  explicit AutocastGuard(bool enable) : enable_(enable) {
    if (!enable_) return;
    prev_enabled_ = at::autocast::is_enabled();
    prev_dtype_ = at::autocast::get_autocast_gpu_dtype();
    at::autocast::set_enabled(true);
    at::autocast::set_autocast_gpu_dtype(at::kBFloat16);
    at::autocast::increment_nesting();
  }
  ~AutocastGuard() {
    if (!enable_) return;
    if (at::autocast::decrement_nesting() == 0) at::autocast::clear_cache();
    at::autocast::set_enabled(prev_enabled_);
    at::autocast::set_autocast_gpu_dtype(prev_dtype_);
  }
  AutocastGuard(const AutocastGuard&) = delete;
  AutocastGuard& operator=(const AutocastGuard&) = delete;

 private:
  bool enable_;
  bool prev_enabled_ = false;
  at::ScalarType prev_dtype_ = at::kHalf;
};

at::Device parse_device(const std::string& name) {
  if (name == "cuda" || name.rfind("cuda:", 0) == 0) {
    if (!torch::cuda::is_available()) {
      throw std::runtime_error("--device " + name + ": this libtorch has no usable CUDA device");
    }
  }
  return at::Device(name);
}

}  // namespace

std::string log_rows_to_csv(const std::vector<LogRow>& rows) {
  std::ostringstream o;
  o << kCsvHeader << "\n";
  for (const LogRow& r : rows) {
    o << r.step << "," << r.stage << "," << fmt(r.loss) << "," << fmt(r.conf_loss) << ","
      << fmt(r.scale_loss) << "," << fmt(r.regression) << "," << fmt(r.lr) << ","
      << fmt(r.grad_norm) << "," << fmt(r.step_s) << "," << fmt(r.data_s) << "," << fmt(r.wall_s);
    if (r.val) {
      const ValidationMetrics& v = *r.val;
      for (double x : {v.loss, v.regression, v.pointmap_error, v.acc_mean, v.acc_median,
                       v.comp_mean, v.comp_median, v.nc_mean, v.nc_median, v.ate_rmse}) {
        o << "," << fmt(x);
      }
    } else {
      for (int i = 0; i < 10; ++i) o << ",nan";
    }
    o << "\n";
  }
  return o.str();
}

cv::Mat plot_training_curves(const std::vector<LogRow>& rows, int width, int height) {
  PlotSeries raw{"train loss", {}, {}, cv::Scalar(200, 200, 200), 1};
  PlotSeries smooth{"train loss (EMA 0.95)", {}, {}, cv::Scalar(180, 80, 0), 2};
  PlotSeries val{"validation loss", {}, {}, cv::Scalar(0, 0, 220), 2};
  double ema = std::numeric_limits<double>::quiet_NaN();
  double lo = std::numeric_limits<double>::infinity();
  for (const LogRow& r : rows) {
    lo = std::min({lo, r.loss, r.val ? r.val->loss : lo});
  }
  // The loss can go negative (the -alpha log conf term), so it is plotted
  // with an offset that keeps log-y usable and says so in the title.
  const double offset = std::isfinite(lo) && lo <= 0.0 ? -lo + 1e-2 : 0.0;
  for (const LogRow& r : rows) {
    if (!std::isfinite(r.loss)) continue;
    ema = std::isfinite(ema) ? 0.95 * ema + 0.05 * r.loss : r.loss;
    raw.x.push_back(static_cast<double>(r.step));
    raw.y.push_back(r.loss + offset);
    smooth.x.push_back(static_cast<double>(r.step));
    smooth.y.push_back(ema + offset);
    if (r.val) {
      val.x.push_back(static_cast<double>(r.step));
      val.y.push_back(r.val->loss + offset);
    }
  }
  std::string title = "LONG3R training loss";
  if (offset > 0.0) title += " (+" + fmt(offset) + ")";
  return plot_line_chart({raw, smooth, val}, title, "step", true, width, height);
}

struct Trainer::Optim {
  std::unique_ptr<torch::optim::AdamW> adamw;
  std::vector<at::Tensor> params;
};

Trainer::Trainer(const TrainConfig& config, const TrainOptions& options)
    : config_(config), options_(options), device_(parse_device(options.device)) {
  validate_train_config(config_);
  if (options_.out_dir.empty()) throw std::invalid_argument("Trainer: out_dir is empty");
  if (!options_.model_override.empty()) config_.model = options_.model_override;
  fs::create_directories(fs::path(options_.out_dir) / "checkpoint");
  at::manual_seed(options_.seed);
  model_ = std::make_unique<Long3rModel>(resolve_model_config(config_.model));
  if (config_.image_size % model_->config().dust3r.patch_size != 0) {
    throw std::invalid_argument("image_size must be a multiple of the model's patch size");
  }
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
  torch::optim::AdamWOptions defaults(config_.stages[0].lr);
  defaults.betas({config_.beta1, config_.beta2}).weight_decay(config_.weight_decay);
  std::vector<torch::optim::OptimizerParamGroup> groups;
  groups.emplace_back(decay, std::make_unique<torch::optim::AdamWOptions>(defaults));
  auto nd = std::make_unique<torch::optim::AdamWOptions>(defaults);
  nd->weight_decay(0.0);
  groups.emplace_back(no_decay, std::move(nd));
  optim_->adamw = std::make_unique<torch::optim::AdamW>(std::move(groups), defaults);

  sampler_ = std::make_unique<SequenceSampler>(config_.data, static_cast<int>(config_.image_size),
                                               options_.seed, at::get_num_threads());
  for (int64_t i = 0; i < config_.validation.sequences; ++i) {
    val_sequences_.push_back(
        sampler_->validation_sequence(i, config_.validation.frames, config_.validation.stride));
  }
  if (options_.resume) {
    const fs::path latest = fs::path(options_.out_dir) / "checkpoint" / "latest";
    if (!fs::exists(latest)) {
      throw std::runtime_error("--resume: no checkpoint in " + latest.parent_path().string());
    }
    std::string name = read_text(latest);
    while (!name.empty() && (name.back() == '\n' || name.back() == ' ')) name.pop_back();
    load_checkpoint((latest.parent_path() / name).string());
  }
  start_time_ = now_s();
}

Trainer::~Trainer() = default;

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

  const Batch batch = sampler_->sample_batch(stage.batch_size, stage.frames).to(device_);
  const double data_s = now_s() - t0;
  for (at::Tensor& p : optim_->params) p.mutable_grad() = at::Tensor();
  std::vector<StreamOutput> outputs, coarse;
  {
    AutocastGuard autocast(device_.is_cuda() && config_.amp == "bf16");
    outputs = model_->forward_sequence(batch.frames, config_.loss.coarse ? &coarse : nullptr);
  }
  const LossTerms loss = sequence_loss(outputs, coarse, batch.pts, batch.valid, config_.loss);
  loss.total.backward();
  outputs.clear();
  coarse.clear();

  std::vector<at::Tensor> with_grad;
  for (const at::Tensor& p : optim_->params) {
    if (p.grad().defined()) with_grad.push_back(p);
  }
  double sq = 0.0;
  for (const at::Tensor& p : with_grad) sq += p.grad().to(at::kDouble).pow(2).sum().item<double>();
  const double grad_norm = std::sqrt(sq);
  const double loss_value = loss.total.item<double>();
  if (std::isfinite(loss_value) && std::isfinite(grad_norm)) {
    if (config_.grad_clip > 0.0 && grad_norm > config_.grad_clip) {
      const double s = config_.grad_clip / (grad_norm + 1e-6);
      torch::NoGradGuard ng;
      for (at::Tensor& p : with_grad) p.mutable_grad().mul_(s);
    }
    optim_->adamw->step();
  } else if (!options_.quiet) {
    // A non-finite step would poison the weights and Adam's moments: skip it.
    std::fprintf(stderr, "long3r_train: step %lld: non-finite loss/gradient, update skipped\n",
                 static_cast<long long>(step_ + 1));
  }
  for (at::Tensor& p : optim_->params) p.mutable_grad() = at::Tensor();
  ++step_;

  LogRow row;
  row.step = step_;
  row.stage = stage_index + 1;
  row.loss = loss_value;
  row.conf_loss = loss.conf_loss.item<double>();
  row.scale_loss = loss.scale_loss.item<double>();
  row.regression = loss.regression;
  row.lr = lr;
  row.grad_norm = grad_norm;
  row.step_s = now_s() - t0;
  row.data_s = data_s;
  row.wall_s = wall_offset_s_ + now_s() - start_time_;
  log_.push_back(row);
  return row;
}

ValidationMetrics Trainer::run_validation() {
  ValidationMetrics v = validate(*model_, val_sequences_, config_.loss, config_.validation);
  // set_training() re-enabled every parameter: re-apply the stage's freeze.
  applied_stage_ = -1;
  return v;
}

void Trainer::save_checkpoint() {
  const fs::path root = fs::path(options_.out_dir) / "checkpoint";
  char name[32];
  std::snprintf(name, sizeof(name), "step_%08lld", static_cast<long long>(step_));
  const fs::path dir = root / name;
  const fs::path tmp = root / (std::string(name) + ".tmp");
  fs::remove_all(tmp);
  fs::create_directories(tmp);
  model_->save((tmp / "weights.safetensors").string());
  {
    std::ostringstream optimizer;
    torch::save(*optim_->adamw, optimizer);
    write_file_atomically((tmp / "optimizer.pt").string(), optimizer.str());
  }
  nlohmann::ordered_json st;
  st["step"] = step_;
  st["sampler_rng"] = sampler_->rng_state();
  {
    at::Generator gen = at::detail::getDefaultCPUGenerator();
    std::lock_guard<std::mutex> lock(gen.mutex());
    st["torch_cpu_rng"] = to_hex(gen.get_state());
  }
  st["wall_s"] = wall_offset_s_ + now_s() - start_time_;
  st["seed"] = options_.seed;
  st["model_config"] = model_config_to_json(model_->config());
  st["train_config"] = train_config_to_json(config_);
  write_file_atomically((tmp / "state.json").string(), st.dump(2));
  write_file_atomically((tmp / "train_log.csv").string(), log_rows_to_csv(log_));
  // The folder appears complete or not at all; "latest" moves only then.
  fs::remove_all(dir);
  fs::rename(tmp, dir);
  sync_directory(root.string());
  write_file_atomically((root / "latest").string(), std::string(name) + "\n");
  std::vector<fs::path> old;
  for (const auto& e : fs::directory_iterator(root)) {
    const std::string n = e.path().filename().string();
    if (e.is_directory() && n.rfind("step_", 0) == 0 && n.find(".tmp") == std::string::npos) {
      old.push_back(e.path());
    }
  }
  std::sort(old.begin(), old.end());
  while (static_cast<int64_t>(old.size()) > config_.keep_checkpoints) {
    fs::remove_all(old.front());
    old.erase(old.begin());
  }
}

void Trainer::load_checkpoint(const std::string& dir_s) {
  const fs::path dir(dir_s);
  const auto st = nlohmann::ordered_json::parse(read_text(dir / "state.json"));
  // Compared as configurations, not as text.
  const std::string mc = st.at("model_config").get<std::string>();
  if (model_config_to_json(parse_model_config(mc)) != model_config_to_json(model_->config())) {
    throw std::runtime_error("checkpoint " + dir_s +
                             " holds a different model configuration than --model-config/config");
  }
  const TensorFile weights = load_safetensors((dir / "weights.safetensors").string());
  model_->load_weights(weights.tensors, (dir / "weights.safetensors").string());
  model_->set_training(true);
  applied_stage_ = -1;
  torch::load(*optim_->adamw, (dir / "optimizer.pt").string(), device_);
  step_ = st.at("step").get<int64_t>();
  sampler_->set_rng_state(st.at("sampler_rng").get<std::string>());
  {
    at::Generator gen = at::detail::getDefaultCPUGenerator();
    std::lock_guard<std::mutex> lock(gen.mutex());
    gen.set_state(from_hex(st.at("torch_cpu_rng").get<std::string>()));
  }
  wall_offset_s_ = st.at("wall_s").get<double>();
  start_time_ = now_s();
  // The log up to the checkpoint (a crash may have logged further steps).
  log_ = read_log_csv(dir / "train_log.csv");
}

void Trainer::write_outputs() {
  const fs::path out(options_.out_dir);
  model_->save((out / "model.safetensors").string());
  write_file_atomically((out / "train_log.csv").string(), log_rows_to_csv(log_));
  write_image_atomically((out / "loss_curve.png").string(), plot_training_curves(log_));
  write_file_atomically((out / "train_config.json").string(), train_config_to_json(config_));
}

void Trainer::run() {
  int64_t end = config_.total_steps();
  if (options_.max_steps >= 0) end = std::min(end, options_.max_steps);
  if (!options_.quiet) {
    int64_t params = 0;
    for (const at::Tensor& p : optim_->params) params += p.numel();
    std::printf(
        "long3r_train: model %s (%.2f M parameters), %lld steps in %zu stages, device %s%s\n",
        config_.model.c_str(), static_cast<double>(params) / 1e6,
        static_cast<long long>(config_.total_steps()), config_.stages.size(), device_.str().c_str(),
        device_.is_cuda() && config_.amp == "bf16" ? " (bf16 autocast)" : " (fp32)");
    if (step_ > 0) std::printf("resumed at step %lld\n", static_cast<long long>(step_));
    std::fflush(stdout);
  }
  bool validated_last = false;
  while (step_ < end) {
    step();
    validated_last = false;
    const ValidationConfig& vc = config_.validation;
    if (vc.sequences > 0 && vc.every > 0 && step_ % vc.every == 0) {
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
                    r.val->loss, r.val->pointmap_error, r.val->acc_mean, r.val->comp_mean,
                    r.val->nc_mean, r.val->ate_rmse);
      }
      std::printf("\n");
      std::fflush(stdout);
    }
    if (config_.checkpoint_every > 0 && step_ % config_.checkpoint_every == 0) {
      save_checkpoint();
      write_outputs();
    }
  }
  if (config_.validation.sequences > 0 && !validated_last && !log_.empty()) {
    log_.back().val = run_validation();
  }
  save_checkpoint();
  write_outputs();
}

}  // namespace long3r

// long3r_model_eval: scores a LONG3R checkpoint (or a baseline) on held-out
// generated sequences with the evaluation metrics (Acc / Comp / NC after a
// Sim(3) alignment, ATE / RPE of the PnP poses). docs/model_card.md and the
// shipped model's test use it.
#include <ATen/ATen.h>
#include <ATen/Parallel.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <memory>
#include <nlohmann/json.hpp>
#include <stdexcept>
#include <string>
#include <vector>

#include "long3r/config/cli_options.hpp"
#include "long3r/io/atomic_file.hpp"
#include "long3r/model/loading/checkpoint.hpp"
#include "long3r/model/loading/safetensors.hpp"
#include "long3r/model/network/model_config.hpp"
#include "long3r/model/network/streaming.hpp"
#include "long3r/model/runtime/inference.hpp"
#include "long3r/model/runtime/threads.hpp"
#include "long3r/train/cv/train_cv.hpp"

namespace {

// JSON has no NaN: a metric that could not be computed is null.
nlohmann::ordered_json num(double v) {
  return std::isfinite(v) ? nlohmann::ordered_json(v) : nlohmann::ordered_json(nullptr);
}

double mean_finite(const std::vector<double>& v) {
  double s = 0.0;
  int n = 0;
  for (double x : v) {
    if (std::isfinite(x)) {
      s += x;
      ++n;
    }
  }
  return n > 0 ? s / n : std::nan("");
}

}  // namespace

int main(int argc, char** argv) {
  std::string model_path, untrained, baseline, picture, json_path, policy;
  bool blind = false;
  std::vector<int64_t> blind_strides, blind_lengths;
  int64_t blind_starts = 8;
  int64_t frames = 50, sequences = 3, stride = 2, img_size = 0;
  uint64_t seed_begin = 2000000, seed = 0;
  int pixel_step = 2;
  bool normals = true, estimate_intrinsics = false;
  long3r::PnpRansac pnp_ransac = long3r::PnpConfig{}.ransac;
  long3r::ThreadConfig threads;
  long3r::CliOptions cli("long3r_model_eval",
                         "Give exactly one of --model, --untrained, --baseline.");
  cli.option("--model", "FILE", &model_path, "LONG3R safetensors checkpoint");
  cli.option("--untrained", "CONFIG", &untrained,
             "randomly initialised model of a named config / JSON file");
  cli.option("--baseline", "", &baseline,
             "constant-depth: every pixel at frame 0's median GT depth, no camera motion; "
             "true-depth-no-motion: each frame's GT pointmap in its own camera, no motion; "
             "frame0-geometry: frame 0's GT pointmap for every frame")
      .choices({"constant-depth", "true-depth-no-motion", "frame0-geometry"});
  cli.option("--long-term-policy", "P", &policy,
             "override: voxel (the paper) | spann3r (ablation)");
  cli.option("--frames", "N", &frames, "frames per sequence").min(2);
  cli.option("--sequences", "S", &sequences, "held-out scenes").min(1);
  cli.option("--stride", "D", &stride, "trajectory frames between used frames").min(1);
  cli.option("--seed-begin", "N", &seed_begin,
             "first scene seed (training uses 1000.., validation 1000000..)");
  cli.option("--img-size", "N", &img_size, "model input N x N")
      .min(0)
      .shown_default(
          "the model's own (its recorded input size, else its config's img_size), 224 "
          "for a baseline");
  cli.option("--pixel-step", "N", &pixel_step, "cloud subsampling for the metrics").min(1);
  cli.flag("--no-normals", &normals, "skip NC", false);
  cli.flag("--estimate-intrinsics", &estimate_intrinsics,
           "PnP with the focal estimated from frame 0's pointmap (the pipeline without a "
           "calibration), not the GT one");
  cli.option("--pnp-ransac", "NAME", &pnp_ransac, "the RANSAC of the PnP poses (as pnp_ransac)");
  cli.option("--picture", "FILE.png", &picture,
             "top views of the first sequence (prediction vs GT)");
  cli.option("--json", "FILE", &json_path, "write the per-sequence and mean metrics");
  cli.flag("--blind-control", &blind,
           "instead of the metrics: the blind control (docs/model_card.md) of the model, per "
           "sequence length and stride: reg_true (placement error of frames 1.. given the true "
           "reference), reg_blind (each frame given itself as its reference) and blind_ratio = "
           "true / blind (about 1: no registration), with the shape error left after each frame's "
           "own Sim(3) alignment, the rotation error against the true relative rotation and the "
           "image motion in pixels and patches");
  cli.option("--blind-stride", "D", &blind_strides,
             "a stride of the blind control (repeatable; default 4, 8, 16, 32)");
  cli.option("--blind-frames", "N", &blind_lengths,
             "a sequence length of the blind control (repeatable; default 2 and 5)");
  cli.option("--blind-starts", "N", &blind_starts,
             "evenly spaced start frames per scene in the blind control")
      .min(1);
  long3r::add_thread_options(cli, &threads);
  long3r::InferenceConfig inference;
  long3r::add_inference_options(cli, &inference);
  long3r::add_memory_options(cli, &inference);
  cli.option("--seed", "N", &seed, "initialisation seed of --untrained");
  if (const auto rc = cli.parse_or_exit(argc, argv)) return *rc;
  const int sources = !model_path.empty() + !untrained.empty() + !baseline.empty();
  if (sources != 1) return cli.usage_error("give exactly one of --model, --untrained, --baseline");
  try {
    const long3r::ThreadState thread_state = long3r::apply_thread_config(threads);
    const long3r::InferenceTarget target = long3r::resolve_inference_target(inference);

    std::unique_ptr<long3r::Long3rModel> model;
    std::string what;
    if (baseline.empty()) {
      long3r::ModelConfig mc;
      long3r::TensorMap weights;
      if (!model_path.empty()) {
        long3r::TensorFile f = long3r::load_safetensors(model_path);
        mc = long3r::model_config_from_metadata(f.metadata, model_path);
        if (mc.kind != long3r::ModelKind::kLong3r) {
          throw std::runtime_error(model_path + " is not a LONG3R checkpoint");
        }
        weights = std::move(f.tensors);
        what = model_path;
      } else {
        mc = long3r::resolve_model_config(untrained);
        what = "untrained " + untrained;
      }
      long3r::apply_memory_overrides(inference, &mc);
      if (!policy.empty() && !long3r::config::enum_from_name(policy, &mc.long3r.long_term_policy)) {
        throw long3r::ConfigError("model config: long3r.long_term_policy: must be " +
                                  long3r::config::enum_choices<long3r::LongTermPolicy>() +
                                  ", got \"" + policy + "\"");
      }
      long3r::validate_model_config(mc);
      at::manual_seed(seed);
      model = std::make_unique<long3r::Long3rModel>(mc);
      if (!weights.empty()) model->load_weights(weights, model_path);
      model->to(target);
      // The model's own resolution unless asked: what it was trained at (the
      // recorded input size; files from before it was recorded: img_size).
      if (img_size == 0) {
        img_size = mc.input_width > 0 ? std::max(mc.input_width, mc.input_height)
                                      : std::max(mc.dust3r.img_size[0], mc.dust3r.img_size[1]);
      }
      if (img_size % mc.dust3r.patch_size != 0) {
        throw std::invalid_argument("--img-size must be a multiple of the patch size");
      }
      what += " (K " + std::to_string(mc.long3r.short_term_frames) + ", L " +
              std::to_string(mc.long3r.long_term_capacity) + ", " +
              long3r::config::enum_name(mc.long3r.long_term_policy) + " long-term memory, " +
              long3r::describe(target) + ")";
    } else {
      what = "baseline " + baseline;
      if (img_size == 0) img_size = 224;
    }

    long3r::DataConfig dc;
    dc.synth.val_seed_begin = seed_begin;
    dc.synth.train_scenes = 0;
    dc.synth.trajectory_frames = (frames - 1) * stride + 1;
    if (blind) {
      if (!model) throw std::invalid_argument("--blind-control needs --model or --untrained");
      if (blind_strides.empty()) blind_strides = {4, 8, 16, 32};
      if (blind_lengths.empty()) blind_lengths = {2, 5};
      // The training scenes' path length, so that the strides mean what they
      // mean in training.
      dc.synth.trajectory_frames = long3r::SynthDataConfig{}.trajectory_frames;
      long3r::SequenceSampler sampler(dc, static_cast<int>(img_size), 0,
                                      thread_state.torch_threads);
      const int64_t patch = model->config().dust3r.patch_size;
      std::printf("%s: blind control, %lld scenes x %lld starts at %lld x %lld, seeds %llu..\n",
                  what.c_str(), static_cast<long long>(sequences),
                  static_cast<long long>(blind_starts), static_cast<long long>(img_size),
                  static_cast<long long>(img_size), static_cast<unsigned long long>(seed_begin));
      std::printf("%6s %6s %6s %9s %9s %9s %9s %11s %9s %10s %11s\n", "frames", "stride", "scored",
                  "motion_px", "motion_tk", "reg_true", "reg_blind", "blind_ratio", "shape_err",
                  "rot_err_deg", "rot_true_deg");
      nlohmann::ordered_json rows = nlohmann::ordered_json::array();
      for (const int64_t n : blind_lengths) {
        for (const int64_t d : blind_strides) {
          long3r::ValidationConfig vc;
          vc.blind_scenes = sequences;
          vc.blind_starts = blind_starts;
          vc.blind_strides = {d};
          vc.blind_frames = n;
          if (n < 2 || d < 1 || (n - 1) * d + 1 > dc.synth.trajectory_frames) {
            throw std::invalid_argument("--blind-frames / --blind-stride: " + std::to_string(n) +
                                        " frames at stride " + std::to_string(d) +
                                        " do not fit a " +
                                        std::to_string(dc.synth.trajectory_frames) + "-frame path");
          }
          const long3r::BlindControl b = long3r::blind_control(*model, sampler.blind_sequences(vc));
          const double tokens = b.motion_px / static_cast<double>(patch);
          std::printf("%6lld %6lld %6lld %9.2f %9.2f %9.4f %9.4f %11.3f %9.4f %10.2f %11.2f\n",
                      static_cast<long long>(n), static_cast<long long>(d),
                      static_cast<long long>(b.frames), b.motion_px, tokens, b.reg_true,
                      b.reg_blind, b.blind_ratio, b.shape_err, b.rot_err_deg, b.rot_true_deg);
          std::fflush(stdout);
          nlohmann::ordered_json o;
          o["frames"] = n;
          o["stride"] = d;
          o["scored"] = b.frames;
          o["unplaced"] = b.unplaced;
          o["motion_px"] = num(b.motion_px);
          o["motion_tokens"] = num(tokens);
          o["reg_true"] = num(b.reg_true);
          o["reg_blind"] = num(b.reg_blind);
          o["blind_ratio"] = num(b.blind_ratio);
          o["shape_err"] = num(b.shape_err);
          o["rot_err_deg"] = num(b.rot_err_deg);
          o["rot_true_deg"] = num(b.rot_true_deg);
          rows.push_back(o);
        }
      }
      if (!json_path.empty()) {
        nlohmann::ordered_json root;
        root["what"] = what;
        root["img_size"] = img_size;
        root["seed_begin"] = static_cast<int64_t>(seed_begin);
        root["scenes"] = sequences;
        root["starts"] = blind_starts;
        root["blind_control"] = rows;
        long3r::write_file_atomically(json_path, root.dump(2) + "\n");
      }
      return 0;
    }
    long3r::SequenceSampler sampler(dc, static_cast<int>(img_size), 0, thread_state.torch_threads);

    std::printf("%s: %lld sequences x %lld frames (stride %lld) at %lld x %lld, seeds %llu..\n",
                what.c_str(), static_cast<long long>(sequences), static_cast<long long>(frames),
                static_cast<long long>(stride), static_cast<long long>(img_size),
                static_cast<long long>(img_size), static_cast<unsigned long long>(seed_begin));
    // loss / loss_reg: the training loss's regression term of the prediction,
    // and what is left of it once every frame is registered (probe_loss);
    // d_slope / d_corr: how each frame's depth follows the truth, medians
    // over the frames (depth_response: 1 / 1 is right, a slope below 1
    // compressed).
    std::printf("%8s %8s %8s %8s %8s %8s %8s %8s %8s %7s %7s %8s %8s %8s %8s\n", "seed", "Acc",
                "Acc_med", "Comp", "Comp_med", "NC", "NC_med", "ATE_m", "RPE_m", "posed", "fps",
                "loss", "loss_reg", "d_slope", "d_corr");
    nlohmann::ordered_json per_seq = nlohmann::ordered_json::array();
    std::vector<std::vector<double>> cols(15);
    for (int64_t s = 0; s < sequences; ++s) {
      const long3r::SequenceSample sample = sampler.validation_sequence(s, frames, stride);
      long3r::SequencePrediction pred;
      if (model) {
        pred = long3r::predict_sequence(*model, sample);
      } else if (baseline == "true-depth-no-motion") {
        pred = long3r::true_depth_no_motion_prediction(sample);
      } else if (baseline == "frame0-geometry") {
        pred = long3r::first_frame_prediction(sample);
      } else {
        // The plane at the median GT depth of frame 0 (generous: it knows the scale).
        const at::Tensor z = sample.pts[0].select(-1, 2).masked_select(sample.valid[0]);
        pred = long3r::constant_depth_prediction(sample,
                                                 z.numel() > 0 ? z.median().item<double>() : 1.0);
      }
      long3r::PredictionMetricsOptions po;
      po.pixel_step = pixel_step;
      po.normals = normals;
      po.estimate_intrinsics = estimate_intrinsics;
      po.pnp_ransac = pnp_ransac;
      if (s == 0) po.picture_path = picture;
      const long3r::PredictionMetrics m = long3r::evaluate_prediction(pred, sample, po);
      const double fps =
          pred.seconds > 0 ? static_cast<double>(frames) / pred.seconds : std::nan("");
      const long3r::LossProbe lp = long3r::probe_loss(pred, sample);
      const std::vector<double> row = {m.acc_mean,
                                       m.acc_median,
                                       m.comp_mean,
                                       m.comp_median,
                                       m.nc_mean,
                                       m.nc_median,
                                       m.ate_rmse,
                                       m.rpe_trans_rmse,
                                       m.rpe_rot_rmse_deg,
                                       static_cast<double>(m.posed),
                                       fps,
                                       lp.regression,
                                       lp.registered,
                                       m.depth_slope,
                                       m.depth_correlation};
      for (std::size_t c = 0; c < row.size(); ++c) cols[c].push_back(row[c]);
      std::printf(
          "%8llu %8.4f %8.4f %8.4f %8.4f %8.4f %8.4f %8.4f %8.4f %7lld %7.2f %8.4f %8.4f %8.3f "
          "%8.3f\n",
          static_cast<unsigned long long>(seed_begin + static_cast<uint64_t>(s)), m.acc_mean,
          m.acc_median, m.comp_mean, m.comp_median, m.nc_mean, m.nc_median, m.ate_rmse,
          m.rpe_trans_rmse, static_cast<long long>(m.posed), fps, lp.regression, lp.registered,
          m.depth_slope, m.depth_correlation);
      std::fflush(stdout);
      nlohmann::ordered_json o;
      o["seed"] = static_cast<int64_t>(seed_begin + static_cast<uint64_t>(s));
      o["frames"] = m.frames;
      o["posed"] = m.posed;
      o["acc_mean_m"] = num(m.acc_mean);
      o["acc_median_m"] = num(m.acc_median);
      o["comp_mean_m"] = num(m.comp_mean);
      o["comp_median_m"] = num(m.comp_median);
      o["nc_mean"] = num(m.nc_mean);
      o["nc_median"] = num(m.nc_median);
      o["pointmap_error_m"] = num(m.pointmap_error);
      o["ate_rmse_m"] = num(m.ate_rmse);
      o["rpe_trans_rmse_m"] = num(m.rpe_trans_rmse);
      o["rpe_rot_rmse_deg"] = num(m.rpe_rot_rmse_deg);
      o["fps"] = num(fps);
      o["loss_regression"] = num(lp.regression);
      o["loss_registered"] = num(lp.registered);
      o["depth_slope"] = num(m.depth_slope);
      o["depth_correlation"] = num(m.depth_correlation);
      per_seq.push_back(o);
    }
    const char* names[] = {"acc_mean_m",
                           "acc_median_m",
                           "comp_mean_m",
                           "comp_median_m",
                           "nc_mean",
                           "nc_median",
                           "ate_rmse_m",
                           "rpe_trans_rmse_m",
                           "rpe_rot_rmse_deg",
                           "posed",
                           "fps",
                           "loss_regression",
                           "loss_registered",
                           "depth_slope",
                           "depth_correlation"};
    nlohmann::ordered_json mean;
    for (std::size_t c = 0; c < cols.size(); ++c) mean[names[c]] = num(mean_finite(cols[c]));
    std::printf(
        "%8s %8.4f %8.4f %8.4f %8.4f %8.4f %8.4f %8.4f %8.4f %7.1f %7.2f %8.4f %8.4f %8.3f %8.3f\n",
        "mean", mean_finite(cols[0]), mean_finite(cols[1]), mean_finite(cols[2]),
        mean_finite(cols[3]), mean_finite(cols[4]), mean_finite(cols[5]), mean_finite(cols[6]),
        mean_finite(cols[7]), mean_finite(cols[9]), mean_finite(cols[10]), mean_finite(cols[11]),
        mean_finite(cols[12]), mean_finite(cols[13]), mean_finite(cols[14]));
    if (!json_path.empty()) {
      nlohmann::ordered_json root;
      root["what"] = what;
      root["frames"] = frames;
      root["stride"] = stride;
      root["img_size"] = img_size;
      root["seed_begin"] = static_cast<int64_t>(seed_begin);
      root["sequences"] = per_seq;
      root["mean"] = mean;
      long3r::write_file_atomically(json_path, root.dump(2) + "\n");
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "long3r_model_eval: %s\n", e.what());
    return 1;
  }
  return 0;
}

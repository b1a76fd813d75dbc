// long3r_train: trains a LONG3R model with the paper's two-stage curriculum on
// generated scenes and/or TUM-layout folders. See docs/training.md. Built
// without OpenCV (a machine with nothing but a libtorch), it trains on
// generated scenes and validates by the loss and pointmap figures only.
// SIGINT or SIGTERM ends a run after the step in progress, with that step's
// checkpoint (a second SIGINT at once): a sitting can stop when it must.
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <stdexcept>
#include <string>
#include <thread>

#include "long3r/config/cli_options.hpp"
#include "long3r/model/runtime/threads.hpp"
#include "long3r/train/data_parallel.hpp"
#include "long3r/train/train_config.hpp"
#include "long3r/train/trainer.hpp"
#ifdef LONG3R_TRAIN_WITH_OPENCV
#include "long3r/train/cv/train_cv.hpp"
#endif

namespace {

// SIGINT or SIGTERM: the run ends after the step in progress, with its
// checkpoint (TrainOptions::stop_requested). A second SIGINT (Ctrl-C twice)
// ends the process at once (checkpoints are written whole or not at all); a
// SIGTERM again changes nothing, as when a service manager signals the
// launcher and its ranks alike and the launcher passes its own on.
volatile std::sig_atomic_t g_stop_signal = 0;

extern "C" void on_stop_signal(int sig) {
  if (sig == SIGINT && g_stop_signal != 0) {
    std::signal(sig, SIG_DFL);
    std::raise(sig);
    return;
  }
  g_stop_signal = sig;
}

// SIGINT only where it is not ignored: a shell's background job ignores it,
// and its launcher (scripts/train_pairs_curve.sh) passes the stop on itself.
void install_stop_handlers() {
  struct sigaction action {};
  action.sa_handler = on_stop_signal;
  sigemptyset(&action.sa_mask);
  action.sa_flags = SA_RESTART;  // a collective's socket calls go on
  struct sigaction old {};
  if (sigaction(SIGINT, nullptr, &old) == 0 && old.sa_handler != SIG_IGN) {
    sigaction(SIGINT, &action, nullptr);
  }
  sigaction(SIGTERM, &action, nullptr);
}

}  // namespace

int main(int argc, char** argv) {
  std::string config_path = "config/train_default.json";
  long3r::TrainOptions opt;
  int threads = static_cast<int>(std::thread::hardware_concurrency());
  long3r::CliOptions cli("long3r_train");
  cli.option("--config", "FILE", &config_path, "training configuration (JSON)");
  cli.option("--model-config", "NAME", &opt.model_override,
             "long3r_ship | long3r_small | long3r_tiny | long3r_paper | FILE.json")
      .shown_default("the config's \"model\"");
  cli.option("--out", "DIR", &opt.out_dir,
             "model.safetensors, train_log.csv, loss_curve.png, checkpoint/")
      .required();
  cli.flag("--resume", &opt.resume, "continue from DIR/checkpoint/latest");
  cli.option("--init-dust3r", "FILE", &opt.init_checkpoint,
             "start from a DUSt3R / Spann3R / LONG3R safetensors checkpoint (tensors matching by "
             "name and shape; the rest fresh)");
  cli.option("--device", "cpu|cuda", &opt.device, "torch device");
  cli.option("--threads", "N", &threads, "torch intra-op threads")
      .min(1)
      .shown_default("hardware concurrency");
  cli.option("--seed", "N", &opt.seed, "initialisation and data sampling seed");
  cli.option("--max-steps", "N", &opt.max_steps,
             "stop after N global steps (smoke tests; schedule unchanged)")
      .shown_default("");
  cli.option("--render-threads", "N", &opt.render_threads,
             "threads rendering training scenes (0: as --threads)")
      .min(0);
  cli.option("--prefetch", "N", &opt.prefetch_batches,
             "batches prepared ahead on a data thread while the model trains (the same batches "
             "in the same order; for a GPU, whose steps leave the CPU cores free)")
      .min(0);
  cli.option("--frame-cache", "FILE", &opt.frame_cache,
             "read the training scenes' frames from this cache (long3r_frame_cache) instead of "
             "rendering them: the same bytes; refused unless made for this configuration")
      .shown_default("");
  cli.option("--time-budget-s", "S", &opt.time_budget_s,
             "stop before a step that would end past S seconds of this run, then validate and "
             "write the outputs (0: no budget)")
      .min(0);
  cli.flag("--quiet", &opt.quiet, "no per-step output");
  cli.option("--dist-backend", "auto|gloo|nccl", &opt.data_parallel.backend,
             "data-parallel process group when launched as several processes (torchrun, srun); "
             "auto: NCCL on CUDA where built with it, else Gloo");
  cli.option("--dist-timeout-s", "S", &opt.data_parallel.timeout_s,
             "a collective waiting longer fails and ends the job")
      .min(1);
  cli.option("--bucket-mib", "MIB", &opt.data_parallel.bucket_mib,
             "gradients all-reduced in buckets of about this size while backward runs");
  cli.flag("--verify-replicas", &opt.verify_replicas,
           "after every step, check that all ranks hold bit-identical weights");
  if (const auto rc = cli.parse_or_exit(argc, argv)) return *rc;
  std::string who = "long3r_train";
  try {
    opt.distributed = long3r::distributed_env();
    if (opt.distributed.distributed()) who += " (" + opt.distributed.describe() + ")";
    long3r::ThreadConfig tc;
    tc.torch_threads = threads;
    tc.openblas_threads = threads;  // the recipe's wall times were measured so
    long3r::apply_thread_config(tc);
    const long3r::TrainConfig config = long3r::load_train_config(config_path);
#ifdef LONG3R_TRAIN_WITH_OPENCV
    opt.extensions = long3r::opencv_trainer_extensions();
#endif
    install_stop_handlers();
    opt.stop_requested = [] { return g_stop_signal != 0; };
    long3r::Trainer trainer(config, opt);
    if (const auto& r = trainer.init_report()) {
      if (r->loaded == 0) throw std::runtime_error("--init-dust3r: no tensor matched the model");
      if (opt.distributed.rank == 0)
        std::printf(
            "init from %s: %lld tensors loaded, %lld shape mismatches (kept fresh), "
            "%lld unused, %lld model tensors fresh\n",
            opt.init_checkpoint.c_str(), static_cast<long long>(r->loaded),
            static_cast<long long>(r->shape_mismatch), static_cast<long long>(r->unused),
            static_cast<long long>(r->fresh));
    }
    trainer.run();
    if (opt.distributed.rank == 0) {
      std::printf("wrote %s/model.safetensors (step %lld, stopped by %s)\n", opt.out_dir.c_str(),
                  static_cast<long long>(trainer.global_step()), trainer.stop_reason().c_str());
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "%s: %s\n", who.c_str(), e.what());
    return 1;
  }
  return 0;
}

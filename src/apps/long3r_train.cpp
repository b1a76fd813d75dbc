// long3r_train: trains a LONG3R model with the paper's two-stage curriculum on
// generated scenes and/or TUM-layout folders. See docs/training.md.
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>

#include "long3r/model/threads.hpp"
#include "long3r/train/train.hpp"

namespace {

void usage() {
  std::puts(
      "usage: long3r_train --out DIR [options]\n"
      "  --config FILE        training configuration (JSON; default config/train_default.json)\n"
      "  --model-config NAME  long3r_ship | long3r_small | long3r_tiny | long3r_paper | FILE.json\n"
      "                       (default: the config's \"model\")\n"
      "  --out DIR            model.safetensors, train_log.csv, loss_curve.png, checkpoint/\n"
      "  --resume             continue from DIR/checkpoint/latest\n"
      "  --init-dust3r FILE   start from a DUSt3R / Spann3R / LONG3R safetensors checkpoint\n"
      "                       (tensors matching by name and shape; the rest fresh)\n"
      "  --device cpu|cuda    (default cpu)\n"
      "  --threads N          torch intra-op threads (default: hardware concurrency)\n"
      "  --seed N             initialisation and data sampling seed (default 0)\n"
      "  --max-steps N        stop after N global steps (smoke tests; schedule unchanged)\n"
      "  --quiet              no per-step output");
}

std::string read_file(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error("cannot read " + path);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

}  // namespace

int main(int argc, char** argv) {
  std::string config_path = "config/train_default.json";
  long3r::TrainOptions opt;
  int threads = static_cast<int>(std::thread::hardware_concurrency());
  try {
    for (int i = 1; i < argc; ++i) {
      const std::string a = argv[i];
      auto next = [&]() -> std::string {
        if (i + 1 >= argc) throw std::invalid_argument("missing value after " + a);
        return argv[++i];
      };
      if (a == "--config")
        config_path = next();
      else if (a == "--model-config")
        opt.model_override = next();
      else if (a == "--out")
        opt.out_dir = next();
      else if (a == "--resume")
        opt.resume = true;
      else if (a == "--init-dust3r")
        opt.init_checkpoint = next();
      else if (a == "--device")
        opt.device = next();
      else if (a == "--threads")
        threads = std::stoi(next());
      else if (a == "--seed")
        opt.seed = std::stoull(next());
      else if (a == "--max-steps")
        opt.max_steps = std::stoll(next());
      else if (a == "--quiet")
        opt.quiet = true;
      else if (a == "-h" || a == "--help") {
        usage();
        return 0;
      } else {
        throw std::invalid_argument("unknown option " + a);
      }
    }
    if (opt.out_dir.empty()) throw std::invalid_argument("--out is required");
    if (threads < 1) throw std::invalid_argument("--threads must be >= 1");
  } catch (const std::exception& e) {
    std::fprintf(stderr, "long3r_train: %s\n", e.what());
    usage();
    return 2;
  }
  try {
    long3r::ThreadConfig tc;
    tc.torch_threads = threads;
    tc.openblas_threads = threads;
    long3r::apply_thread_config(tc);
    const long3r::TrainConfig config = long3r::parse_train_config(read_file(config_path));
    long3r::Trainer trainer(config, opt);
    if (const auto& r = trainer.init_report()) {
      std::printf(
          "init from %s: %lld tensors loaded, %lld shape mismatches (kept fresh), "
          "%lld unused, %lld model tensors fresh\n",
          opt.init_checkpoint.c_str(), static_cast<long long>(r->loaded),
          static_cast<long long>(r->shape_mismatch), static_cast<long long>(r->unused),
          static_cast<long long>(r->fresh));
      if (r->loaded == 0) throw std::runtime_error("--init-dust3r: no tensor matched the model");
    }
    trainer.run();
    std::printf("wrote %s/model.safetensors (step %lld)\n", opt.out_dir.c_str(),
                static_cast<long long>(trainer.global_step()));
  } catch (const std::exception& e) {
    std::fprintf(stderr, "long3r_train: %s\n", e.what());
    return 1;
  }
  return 0;
}

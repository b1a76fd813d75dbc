// long3r_frame_cache: renders the generated training scenes of a training
// configuration once into a frame cache (train/frame_cache.hpp) that
// long3r_train --frame-cache reads instead of rendering; --check opens an
// existing cache as the trainer would (key, size, frames against the
// generator) and says whether it fits. See docs/training.md, "The frame
// cache".
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <stdexcept>
#include <string>
#include <thread>

#include "long3r/config/cli_options.hpp"
#include "long3r/model/runtime/threads.hpp"
#include "long3r/train/frame_cache.hpp"
#include "long3r/train/train_config.hpp"

namespace {

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

}  // namespace

int main(int argc, char** argv) {
  std::string config_path, out;
  int threads = static_cast<int>(std::thread::hardware_concurrency());
  int verify = 4;
  bool check = false, quiet = false;
  long3r::CliOptions cli("long3r_frame_cache");
  cli.option("--config", "FILE", &config_path, "training configuration (JSON)").required();
  cli.option("--out", "FILE", &out,
             "the cache file to write (or to check); a folder: the file named as --print-name "
             "says, in it")
      .required();
  bool print_name = false;
  cli.flag("--print-name", &print_name,
           "only print the file path --out stands for (the file name that says which scenes "
           "the configuration's cache holds, shared by configurations that draw the same frames)");
  cli.option("--threads", "N", &threads, "scenes rendered at a time")
      .min(1)
      .shown_default("hardware concurrency");
  cli.flag("--check", &check, "only open FILE as the trainer would and say whether it fits");
  cli.option("--verify-frames", "N", &verify,
             "frames rendered again and compared byte for byte when checking")
      .min(0);
  cli.flag("--quiet", &quiet, "no progress");
  if (const auto rc = cli.parse_or_exit(argc, argv)) return *rc;
  try {
    long3r::ThreadConfig tc;
    tc.torch_threads = 1;  // the scenes are rendered in parallel instead
    tc.openblas_threads = 1;
    long3r::apply_thread_config(tc);
    const long3r::TrainConfig config = long3r::load_train_config(config_path);
    const long3r::SynthDataConfig& synth = config.data.synth;
    const int size = synth.render_side(config.image_size);
    if (std::filesystem::is_directory(out)) {
      out = (std::filesystem::path(out) / long3r::FrameCache::file_name(synth, size)).string();
    }
    if (print_name) {
      std::printf("%s\n", out.c_str());
      return 0;
    }
    const auto t0 = std::chrono::steady_clock::now();
    if (!check) {
      if (!synth.enabled) throw std::runtime_error(config_path + " trains on no generated scenes");
      int64_t last_report = 0;
      long3r::FrameCache::write(out, synth, size, threads, [&](int64_t done, int64_t total) {
        if (quiet || (done - last_report < 50 && done != total)) return;
        last_report = done;
        std::printf("%lld / %lld scenes (%.0f s)\n", static_cast<long long>(done),
                    static_cast<long long>(total), seconds_since(t0));
        std::fflush(stdout);
      });
    }
    const long3r::FrameCache cache(out, synth, size, verify);
    std::printf(
        "%s: %lld scenes (seeds %llu on) x %lld frames at %d x %d px, %.2f GB; %s (%.0f s)\n",
        out.c_str(), static_cast<long long>(cache.scenes()),
        static_cast<unsigned long long>(synth.train_seed_begin),
        static_cast<long long>(cache.frames_per_scene()), size, size,
        static_cast<double>(cache.file_bytes()) / 1e9,
        check ? "fits the configuration" : "written and checked", seconds_since(t0));
  } catch (const std::exception& e) {
    std::fprintf(stderr, "long3r_frame_cache: %s\n", e.what());
    return 1;
  }
  return 0;
}

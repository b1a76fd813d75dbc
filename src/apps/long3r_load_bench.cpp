// long3r_load_bench: the peak memory of loading a streaming model from a
// checkpoint, the way the package loads it (tensor by tensor from a mapping
// of the file, make_streaming_model) beside the whole file read into memory
// first and then copied into the model (how it loaded before). Each way runs
// in a process of its own, so that one cannot lower or raise the other's
// peak; the table prints both, side by side, against the file's size.
//
// Peak RSS is the kernel's high-water mark (VmHWM) of the loading process,
// which includes libtorch's own footprint (the "baseline" column: VmRSS
// before the load).
#include <ATen/ATen.h>
#include <sys/stat.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <memory>
#include <string>
#include <vector>

#include "long3r/config/cli_options.hpp"
#include "long3r/model/loading/safetensors.hpp"
#include "long3r/model/network/long3r_model.hpp"
#include "long3r/model/network/model_shell.hpp"
#include "long3r/model/network/spann3r_model.hpp"
#include "long3r/model/runtime/inference.hpp"
#include "long3r/model/runtime/threads.hpp"

namespace {

// A field of /proc/self/status in MiB ("VmRSS", "VmHWM").
double status_mib(const char* field) {
  std::ifstream in("/proc/self/status");
  const std::string key = std::string(field) + ":";
  for (std::string line; std::getline(in, line);) {
    if (line.rfind(key, 0) == 0) return std::atof(line.c_str() + key.size()) / 1024.0;
  }
  return 0.0;
}

// One way of loading, in this process; prints "baseline_MiB peak_MiB seconds".
int measure(const std::string& path, const std::string& way,
            const long3r::InferenceConfig& inference) {
  const long3r::InferenceTarget target = long3r::resolve_inference_target(inference);
  const double baseline = status_mib("VmRSS");
  const auto t0 = std::chrono::steady_clock::now();
  std::unique_ptr<long3r::StreamingModel> model;
  if (way == "streamed") {
    model = long3r::make_streaming_model(path, inference);
  } else {  // the whole file in memory, then the model: what loading did before
    long3r::TensorFile file = long3r::load_safetensors(path);
    long3r::ModelCheckpoint c{long3r::model_config_from_metadata(file.metadata, path),
                              std::move(file.tensors)};
    if (c.config.kind == long3r::ModelKind::kLong3r) {
      auto m = long3r::model_from_checkpoint<long3r::Long3rModel>(c, path);
      m->to(target);
      model = std::move(m);
    } else {
      auto m = long3r::model_from_checkpoint<long3r::Spann3rModel>(c, path);
      m->to(target);
      model = std::move(m);
    }
  }
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  std::printf("%.1f %.1f %.2f\n", baseline, status_mib("VmHWM"), seconds);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  std::string path, way;
  long3r::ThreadConfig threads;
  long3r::InferenceConfig inference;
  long3r::CliOptions cli(
      "long3r_load_bench",
      "Peak RSS of loading a streaming model (Spann3R or LONG3R) from FILE: streamed from a "
      "mapping of the file, as the package loads, beside the whole file read first; each in a "
      "process of its own, printed side by side against the file's size.");
  cli.positional("FILE.safetensors", &path, "the checkpoint").required();
  cli.option("--way", "W", &way,
             "measure only this way in this process: streamed or whole (what the table runs)");
  long3r::add_thread_options(cli, &threads);
  long3r::add_inference_options(cli, &inference);
  if (const auto rc = cli.parse_or_exit(argc, argv)) return *rc;
  try {
    long3r::apply_thread_config(threads);
    if (!way.empty()) {
      if (way != "streamed" && way != "whole") throw std::runtime_error("--way streamed or whole");
      return measure(path, way, inference);
    }
    struct stat st;
    if (::stat(path.c_str(), &st) != 0) throw std::runtime_error(path + ": cannot stat");
    const double file_mib = static_cast<double>(st.st_size) / (1024.0 * 1024.0);
    const long3r::InferenceTarget target = long3r::resolve_inference_target(inference);
    std::printf("cpu %s\n", long3r::describe_cpu().c_str());
    std::printf("checkpoint %s: %.1f MiB; model %s\n", path.c_str(), file_mib,
                long3r::describe(target).c_str());
    std::printf("%-9s %12s %12s %14s %16s %9s\n", "way", "baseline_MiB", "peak_MiB", "peak/file",
                "(peak-base)/file", "seconds");
    // This executable with every flag again, for the children.
    char self[4096];
    const ssize_t n = ::readlink("/proc/self/exe", self, sizeof self - 1);
    if (n <= 0) throw std::runtime_error("cannot find this executable (/proc/self/exe)");
    self[n] = '\0';
    for (const char* w : {"streamed", "whole"}) {
      std::string command = std::string("'") + self + "'";
      for (int i = 1; i < argc; ++i) command += std::string(" '") + argv[i] + "'";
      command += std::string(" --way ") + w;
      FILE* child = ::popen(command.c_str(), "r");
      double baseline = 0, peak = 0, seconds = 0;
      const bool ok =
          child != nullptr && std::fscanf(child, "%lf %lf %lf", &baseline, &peak, &seconds) == 3;
      const int rc = child != nullptr ? ::pclose(child) : -1;
      if (!ok || rc != 0) throw std::runtime_error(std::string("the ") + w + " load failed");
      std::printf("%-9s %12.1f %12.1f %14.2f %16.2f %9.2f\n", w, baseline, peak, peak / file_mib,
                  (peak - baseline) / file_mib, seconds);
      std::fflush(stdout);
    }
  } catch (const std::exception& e) {
    std::cerr << "long3r_load_bench: " << e.what() << "\n";
    return 1;
  }
  return 0;
}

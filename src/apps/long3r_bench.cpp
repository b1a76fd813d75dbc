// long3r_bench: streams synthetic frames through a randomly initialised LONG3R
// model of a named configuration and prints per-frame latency and memory size
// at fixed frame counts, the latency growth ratio, and peak RSS. A figure
// printer, not a test: random weights give meaningless point maps, but the
// cost of every step (and the memory's growth and bound) is the real one.
//
// Frames vary smoothly over time (shifted sinusoids) so that consecutive point
// maps are similar, as in a real video.
#include <ATen/ATen.h>
#include <sys/resource.h>
#include <time.h>
#include <torch/csrc/autograd/profiler_legacy.h>
#include <torch/nn/module.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <iostream>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "long3r/config/cli_options.hpp"
#include "long3r/model/network/long3r_model.hpp"
#include "long3r/model/network/model_config.hpp"
#include "long3r/model/runtime/inference.hpp"
#include "long3r/model/runtime/threads.hpp"

namespace {

at::Tensor synthetic_frame(int64_t t, int64_t H, int64_t W) {
  const auto f = at::TensorOptions().dtype(at::kFloat);
  const at::Tensor y = at::arange(H, f).view({1, H, 1});
  const at::Tensor x = at::arange(W, f).view({1, 1, W});
  const at::Tensor c = at::arange(3, f).view({3, 1, 1});
  const double s = 0.05 * static_cast<double>(t);
  return (at::sin(x * (0.03 + 0.01 * std::sin(s)) + y * 0.02 + c * 1.3 + s) * 0.6 +
          at::cos(y * 0.015 - s + x * 0.005) * 0.3)
      .unsqueeze(0);
}

// CPU time of the whole process (all threads), ms. With one torch thread it
// is the work of the step, free of the waits that other load on a shared
// machine adds to the wall time; with more threads it includes their spinning.
double process_cpu_ms() {
  timespec ts{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return static_cast<double>(ts.tv_sec) * 1e3 + static_cast<double>(ts.tv_nsec) * 1e-6;
}

// --profile-frames: where a step's time goes, from torch's own per-operator
// records (the calling thread's; an operator's time includes the work of the
// OpenMP threads it runs on). Self time = an operator's time minus that of the
// operators it called, so the rows add up to the profiled steps' time.
namespace prof = torch::autograd::profiler;

struct OpTime {
  double self_ms = 0;
  double flops = 0;  // torch's count, for the operators it counts (products, convolutions)
  int64_t calls = 0;
};

std::map<std::string, OpTime> self_times(prof::thread_event_lists& lists) {
  std::map<std::string, OpTime> ops;
  for (auto& events : lists) {
    struct Open {
      prof::LegacyEvent* push;
      double children_us;
    };
    std::vector<Open> open;
    for (auto& e : events) {
      if (e.kind() == prof::EventKind::PushRange) {
        open.push_back({&e, 0.0});
      } else if (e.kind() == prof::EventKind::PopRange && !open.empty()) {
        const Open o = open.back();
        open.pop_back();
        const double us = o.push->cpuElapsedUs(e);
        OpTime& op = ops[o.push->name()];
        op.self_ms += (us - o.children_us) / 1e3;
        op.flops += static_cast<double>(o.push->flops());
        ++op.calls;
        if (!open.empty()) open.back().children_us += us;
      }
    }
  }
  return ops;
}

// Classes of operators, for the per-class lines of the profile.
const char* op_class(const std::string& name) {
  auto has = [&name](const char* s) { return name.find(s) != std::string::npos; };
  if (has("addmm") || has("::mm") || has("bmm") || has("matmul") || has("linear") || has("baddbmm"))
    return "matrix products (linear, matmul)";
  if (has("conv")) return "convolutions";
  if (has("softmax")) return "softmax";
  if (has("layer_norm")) return "layer norms";
  if (has("copy") || has("::to") || has("contiguous") || has("clone") || has("cat") || has("stack"))
    return "copies and conversions";
  if (has("upsample")) return "upsampling";
  return "other (elementwise, indexing, memory bookkeeping)";
}

// Rows of a by-name table, the largest self time first.
std::vector<std::pair<std::string, OpTime>> by_self_time(const std::map<std::string, OpTime>& m) {
  std::vector<std::pair<std::string, OpTime>> rows(m.begin(), m.end());
  std::sort(rows.begin(), rows.end(),
            [](const auto& a, const auto& b) { return a.second.self_ms > b.second.self_ms; });
  return rows;
}

void print_profile(prof::thread_event_lists& lists, int64_t steps) {
  const std::vector<std::pair<std::string, OpTime>> rows = by_self_time(self_times(lists));
  double total = 0;
  std::map<std::string, OpTime> classes;
  for (const auto& r : rows) {
    total += r.second.self_ms;
    OpTime& c = classes[op_class(r.first)];
    c.self_ms += r.second.self_ms;
    c.flops += r.second.flops;
  }
  const double n = static_cast<double>(std::max<int64_t>(1, steps));
  std::printf("profile of %lld step(s): %.1f ms per step in operators\n",
              static_cast<long long>(steps), total / n);
  // GFLOP/s of a class: the FLOPs torch counts for its operators over the
  // class's self time (a convolution's FLOPs are counted on aten::conv2d,
  // its time on the kernel below it: both land in the class).
  std::printf("%-52s %12s %7s %12s %9s\n", "operator class", "ms per step", "share", "GFLOP/step",
              "GFLOP/s");
  for (const auto& c : by_self_time(classes)) {
    std::printf("%-52s %12.1f %6.1f%% %12.1f %9.0f\n", c.first.c_str(), c.second.self_ms / n,
                100.0 * c.second.self_ms / std::max(total, 1e-9), c.second.flops / n / 1e9,
                c.second.flops / 1e9 / std::max(c.second.self_ms / 1e3, 1e-9));
  }
  std::printf("%-52s %12s %7s %10s\n", "operator (top 20 by self time)", "ms per step", "share",
              "calls");
  for (std::size_t i = 0; i < std::min<std::size_t>(rows.size(), 20); ++i) {
    const auto& r = rows[i];
    std::printf("%-52s %12.1f %6.1f%% %10.0f\n", r.first.c_str(), r.second.self_ms / n,
                100.0 * r.second.self_ms / std::max(total, 1e-9),
                static_cast<double>(r.second.calls) / n);
  }
}

double min_window(const std::vector<double>& v, std::size_t end, std::size_t n) {
  const std::size_t begin = end > n ? end - n : 0;
  if (end <= begin) return 0.0;
  return *std::min_element(v.begin() + static_cast<std::ptrdiff_t>(begin),
                           v.begin() + static_cast<std::ptrdiff_t>(end));
}

double median_window(const std::vector<double>& v, std::size_t end, std::size_t n) {
  const std::size_t begin = end > n ? end - n : 0;
  std::vector<double> w(v.begin() + static_cast<std::ptrdiff_t>(begin),
                        v.begin() + static_cast<std::ptrdiff_t>(end));
  std::sort(w.begin(), w.end());
  return w.empty() ? 0.0 : w[w.size() / 2];
}

}  // namespace

int main(int argc, char** argv) {
  std::string config_name;
  int64_t frames = 100, size = 224;
  long3r::ThreadConfig threads;
  uint64_t seed = 0;
  bool projection_cache = true;
  int64_t profile_frames = 0;
  long3r::CliOptions cli(
      "long3r_bench",
      "Streams N synthetic S x S frames (plus one, for the one-frame latency) through a random "
      "model; prints latency and memory tokens at frames 10, 50, 100, 500, 1000 (those <= N); "
      "latency = wall time of the push that returns the frame.\n"
      "median10 / min10: median / fastest of the 10 frames up to that one (min10 is the least "
      "disturbed by other load on the machine, which only adds time).\n"
      "cpu_ms: process CPU time of the step (with --threads 1: the work itself).");
  cli.option("--config", "NAME", &config_name,
             "long3r_small | long3r_tiny | long3r_paper | long3r_ship")
      .required();
  cli.option("--frames", "N", &frames, "frames streamed").min(2);
  cli.option("--size", "S", &size, "frame size S x S").min(1);
  long3r::add_thread_options(cli, &threads);
  cli.option("--seed", "N", &seed, "initialisation seed");
  cli.flag("--no-projection-cache", &projection_cache,
           "recompute the memory blocks' key/value projections of the relevant tokens at every "
           "step (the reference path)",
           false);
  cli.option("--profile-frames", "N", &profile_frames,
             "profile the last N steps: time per operator class and the top operators (self "
             "time)")
      .min(0);
  long3r::InferenceConfig inference;
  long3r::add_inference_options(cli, &inference);
  if (const auto rc = cli.parse_or_exit(argc, argv)) return *rc;
  try {
    const long3r::InferenceTarget target = long3r::resolve_inference_target(inference);
    const long3r::ThreadState used = long3r::apply_thread_config(threads);
    std::printf("cpu %s\n", long3r::describe_cpu().c_str());
    at::manual_seed(seed);
    const long3r::ModelConfig config = long3r::named_model_config(config_name);
    const auto t_build = std::chrono::steady_clock::now();
    long3r::Long3rModel model(config);
    model.to(target);
    model.set_memory_projection_cache(projection_cache);
    int64_t params = 0;
    for (const auto& p : model.module().parameters()) params += p.numel();
    const int64_t P = (size / config.dust3r.patch_size) * (size / config.dust3r.patch_size);
    std::printf(
        "config %s: %.1f M parameters, %lldx%lld frames (P = %lld tokens), %s, "
        "K = %lld, L = %lld, bound K*P + L = %lld tokens, memory projection cache %s, %s "
        "(built in %.1f s)\n",
        config_name.c_str(), params / 1e6, static_cast<long long>(size),
        static_cast<long long>(size), static_cast<long long>(P), long3r::describe(used).c_str(),
        static_cast<long long>(config.long3r.short_term_frames),
        static_cast<long long>(config.long3r.long_term_capacity),
        static_cast<long long>(config.long3r.short_term_frames * P +
                               config.long3r.long_term_capacity),
        projection_cache ? "on" : "off", long3r::describe(target).c_str(),
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t_build).count());
    std::fflush(stdout);

    std::vector<double> latency;    // latency[k]: push that returned frame k, ms
    std::vector<double> cpu;        // process CPU time of that push, ms
    std::vector<int64_t> tokens;    // memory tokens after that step
    std::vector<int64_t> relevant;  // relevant tokens of that step
    const std::vector<int64_t> marks{10, 50, 100, 500, 1000};
    std::printf("%8s %12s %12s %10s %10s %10s %10s %10s %10s %10s %10s\n", "frame", "latency_ms",
                "median10_ms", "min10_ms", "cpu_ms", "encode_ms", "decode_ms", "memory_ms",
                "mem_short", "mem_long", "relevant");
    // N + 1 pushes: the step for frame k runs when frame k + 1 arrives, so
    // this gives N outputs from the refined head.
    std::unique_ptr<prof::TLSLegacyProfilerGuard> profiler;
    prof::thread_event_lists profile;
    for (int64_t t = 0; t <= frames; ++t) {
      const at::Tensor img = synthetic_frame(t, size, size);
      if (profile_frames > 0 && t == frames + 1 - profile_frames) {
        profiler = std::make_unique<prof::TLSLegacyProfilerGuard>(
            torch::profiler::impl::ProfilerConfig(torch::profiler::impl::ProfilerState::CPU,
                                                  /*report_input_shapes=*/true,
                                                  /*profile_memory=*/false, /*with_stack=*/false,
                                                  /*with_flops=*/true),
            [&profile](prof::thread_event_lists lists) { profile = std::move(lists); });
      }
      const auto t0 = std::chrono::steady_clock::now();
      const double c0 = process_cpu_ms();
      auto out = model.push(img);
      // On a GPU the step runs asynchronously: the latency ends with the
      // outputs on the host, as the pipeline copies them (nothing to do on
      // the CPU).
      if (out && !out->pts3d.is_cpu()) {
        out->pts3d = out->pts3d.to(at::kCPU);
        out->conf = out->conf.to(at::kCPU);
      }
      const double cpu_ms = process_cpu_ms() - c0;
      const double ms =
          std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
      if (!out) continue;
      latency.push_back(ms);
      cpu.push_back(cpu_ms);
      tokens.push_back(out->stats.mem_short_tokens + out->stats.mem_long_tokens);
      relevant.push_back(out->stats.relevant_tokens);
      const int64_t n = out->frame_index + 1;  // frames processed
      if (std::find(marks.begin(), marks.end(), n) != marks.end() || frames <= 5) {
        std::printf("%8lld %12.1f %12.1f %10.1f %10.1f %10.1f %10.1f %10.1f %10lld %10lld %10lld\n",
                    static_cast<long long>(n), ms, median_window(latency, latency.size(), 10),
                    min_window(latency, latency.size(), 10), cpu_ms, out->stats.encode_ms,
                    out->stats.decode_ms, out->stats.memory_ms,
                    static_cast<long long>(out->stats.mem_short_tokens),
                    static_cast<long long>(out->stats.mem_long_tokens),
                    static_cast<long long>(out->stats.relevant_tokens));
        std::fflush(stdout);
      }
    }
    if (profiler) {
      profiler.reset();  // hands the events over
      print_profile(profile, std::min(profile_frames, frames + 1));
    }
    model.flush();
    if (latency.size() >= 50) {
      const std::size_t end = std::min<std::size_t>(latency.size(), 1000);
      std::printf("latency ratio median10(%zu) / median10(50) = %.3f\n", end,
                  median_window(latency, end, 10) / median_window(latency, 50, 10));
      std::printf("latency ratio min10(%zu) / min10(50) = %.3f\n", end,
                  min_window(latency, end, 10) / min_window(latency, 50, 10));
      std::printf("cpu time ratio median10(%zu) / median10(50) = %.3f\n", end,
                  median_window(cpu, end, 10) / median_window(cpu, 50, 10));
    }
    const int64_t peak_tokens =
        tokens.empty() ? 0 : *std::max_element(tokens.begin(), tokens.end());
    double total = 0;
    for (double v : latency) total += v;
    std::printf("frames %zu, mean latency %.1f ms (%.2f FPS), peak memory tokens %lld\n",
                latency.size(), total / std::max<std::size_t>(1, latency.size()),
                latency.empty() ? 0.0 : 1000.0 * latency.size() / total,
                static_cast<long long>(peak_tokens));
    struct rusage ru;
    getrusage(RUSAGE_SELF, &ru);
    std::printf("peak RSS %.1f MiB\n", ru.ru_maxrss / 1024.0);
  } catch (const std::exception& e) {
    std::cerr << "long3r_bench: " << e.what() << "\n";
    return 1;
  }
  return 0;
}

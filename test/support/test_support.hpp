// Fixtures shared by the unit tests of both gtest binaries: scratch folders,
// whole-file reads and writes, command lines (Argv), the tiny model
// configurations, synthetic input frames and tensor comparisons. libtorch and
// the standard library only (long3r_model_tests links it without OpenCV); the
// OpenCV side is in cv_test_support.hpp.
#pragma once

#include <ATen/core/Tensor.h>

#include <cstdint>
#include <functional>
#include <string>
#include <utility>
#include <vector>

#include "long3r/model/network/model_config.hpp"

namespace torch::nn {
class Module;
}  // namespace torch::nn

namespace long3r::test {

// A fresh, empty folder <build>/test_tmp/<name> (name may contain '/').
std::string scratch_dir(const std::string& name);

std::string read_file(const std::string& path);  // all bytes; "" when unreadable
void write_file(const std::string& path, const std::string& bytes);
// Names of a folder's entries, sorted (e.g. to see that no temporary is left).
std::vector<std::string> folder_entries(const std::string& dir);

// `act` throws a std::exception whose message contains `text`.
void expect_throw_naming(const std::function<void()>& act, const std::string& text);

// While alive, files this process writes are limited to `bytes` (RLIMIT_FSIZE,
// SIGXFSZ ignored), so a write past it fails with EFBIG as on a full disk.
class FileSizeLimit {
 public:
  explicit FileSizeLimit(unsigned long bytes);
  ~FileSizeLimit();
  FileSizeLimit(const FileSizeLimit&) = delete;
  FileSizeLimit& operator=(const FileSizeLimit&) = delete;

 private:
  unsigned long old_soft_limit_ = 0;
  void (*old_handler_)(int) = nullptr;
};

// A small DUSt3R with the golden models' tiny widths (encoder 32 x 2 blocks,
// decoder 16 x 4, DPT features 8), for shape and mechanics tests.
Dust3rConfig tiny_dust3r_config();
// The named configuration "long3r_tiny" (64 x 64 inputs).
ModelConfig tiny_long3r_config();

// Synthetic model inputs: a smooth pattern, [1, 3, h, w] float32, that moves
// with the frame number t (the same t gives the same tensor, bit for bit).
//
// Over the unit square (at::linspace(0, 1, .) across each axis), with s = 0.15 t:
//   clamp(sin(6 (x + s) + 2 c) * cos(5 (y - s / 2) + c), -1, 1)  for channel c.
at::Tensor grid_wave_frame(int64_t t, int64_t h, int64_t w);

// Over pixel indices (at::arange: x, y in pixels, c the channel), with
// s = step t + phase:
//   amplitude * sin(x_rate x + y_rate y + channel_rate c + s)
//     + cos_amplitude * cos(cos_y_rate y - s).
// The defaults are the LONG3R model tests' wave; `phase` tells streams apart.
struct PixelWave {
  double step = 0.15;
  double x_rate = 0.11;
  double y_rate = 0.07;
  double channel_rate = 1.3;
  double amplitude = 0.6;
  double cos_y_rate = 0.05;
  double cos_amplitude = 0.3;
  double phase = 0.0;
};
at::Tensor pixel_wave_frame(int64_t t, int64_t h, int64_t w, const PixelWave& wave = {});

// Copies every parameter of `from` into `to` (same architecture), strictly.
void copy_parameters(torch::nn::Module& from, torch::nn::Module& to);

// max |x - ref| / max |ref| in double; also a gtest failure (and infinity)
// when the shapes differ; 0 / infinity when ref is all zeros.
double rel_diff(const at::Tensor& x, const at::Tensor& ref);

// argv from a list of words, the program name first.
struct Argv {
  explicit Argv(std::vector<std::string> words) : words_(std::move(words)) {
    words_.insert(words_.begin(), "prog");
    for (const std::string& w : words_) ptrs_.push_back(w.c_str());
  }
  int argc() const { return static_cast<int>(ptrs_.size()); }
  const char* const* argv() const { return ptrs_.data(); }

 private:
  std::vector<std::string> words_;
  std::vector<const char*> ptrs_;
};

}  // namespace long3r::test

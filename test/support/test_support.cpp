#include "support/test_support.hpp"

#include <ATen/ATen.h>
#include <gtest/gtest.h>
#include <torch/nn/module.h>

#include <sys/resource.h>

#include <algorithm>
#include <csignal>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <map>
#include <vector>

#include "long3r/model/loading/checkpoint.hpp"

namespace long3r::test {

std::string scratch_dir(const std::string& name) {
  const auto d = std::filesystem::path(LONG3R_BINARY_DIR) / "test_tmp" / name;
  std::filesystem::remove_all(d);
  std::filesystem::create_directories(d);
  return d.string();
}

void expect_throw_naming(const std::function<void()>& act, const std::string& text) {
  try {
    act();
  } catch (const std::exception& e) {
    EXPECT_NE(std::string(e.what()).find(text), std::string::npos) << e.what();
    return;
  }
  ADD_FAILURE() << "no exception naming " << text;
}

std::string read_file(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

void write_file(const std::string& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary);
  out << bytes;
}

std::vector<std::string> folder_entries(const std::string& dir) {
  std::vector<std::string> names;
  for (const auto& e : std::filesystem::directory_iterator(dir)) {
    names.push_back(e.path().filename().string());
  }
  std::sort(names.begin(), names.end());
  return names;
}

FileSizeLimit::FileSizeLimit(unsigned long bytes) {
  struct rlimit limit {};
  if (::getrlimit(RLIMIT_FSIZE, &limit) != 0) ADD_FAILURE() << "getrlimit failed";
  old_soft_limit_ = limit.rlim_cur;
  old_handler_ = std::signal(SIGXFSZ, SIG_IGN);
  limit.rlim_cur = bytes;
  if (::setrlimit(RLIMIT_FSIZE, &limit) != 0) ADD_FAILURE() << "setrlimit failed";
}

FileSizeLimit::~FileSizeLimit() {
  struct rlimit limit {};
  ::getrlimit(RLIMIT_FSIZE, &limit);
  limit.rlim_cur = old_soft_limit_;
  ::setrlimit(RLIMIT_FSIZE, &limit);
  std::signal(SIGXFSZ, old_handler_);
}

Dust3rConfig tiny_dust3r_config() {
  Dust3rConfig c;
  c.enc_embed_dim = 32;
  c.enc_depth = 2;
  c.enc_num_heads = 2;
  c.dec_embed_dim = 16;
  c.dec_depth = 4;
  c.dec_num_heads = 2;
  c.dpt.feature_dim = 8;
  c.dpt.last_dim = 6;
  c.dpt.layer_dims = {4, 6, 8, 8};
  c.dpt.hooks = {0, 2, 3, 4};
  c.dpt.dim_tokens = {32, 16, 16, 16};
  return c;
}

ModelConfig tiny_long3r_config() { return named_model_config("long3r_tiny"); }

at::Tensor grid_wave_frame(int64_t t, int64_t h, int64_t w) {
  const at::Tensor y = at::linspace(0, 1, h).view({1, 1, h, 1});
  const at::Tensor x = at::linspace(0, 1, w).view({1, 1, 1, w});
  const double s = 0.15 * static_cast<double>(t);
  std::vector<at::Tensor> ch;
  for (int c = 0; c < 3; ++c) {
    ch.push_back(at::sin(6.0 * (x + s) + 2.0 * c) * at::cos(5.0 * (y - 0.5 * s) + c));
  }
  return at::cat(ch, 1).clamp(-1, 1);
}

at::Tensor pixel_wave_frame(int64_t t, int64_t h, int64_t w, const PixelWave& wave) {
  const auto f = at::TensorOptions().dtype(at::kFloat);
  const at::Tensor y = at::arange(h, f).view({1, h, 1});
  const at::Tensor x = at::arange(w, f).view({1, 1, w});
  const at::Tensor c = at::arange(3, f).view({3, 1, 1});
  const double s = wave.step * static_cast<double>(t) + wave.phase;
  return at::sin(x * wave.x_rate + y * wave.y_rate + c * wave.channel_rate + s)
      .mul(wave.amplitude)
      .add(at::cos(y * wave.cos_y_rate - s) * wave.cos_amplitude)
      .unsqueeze(0);
}

void copy_parameters(torch::nn::Module& from, torch::nn::Module& to) {
  std::map<std::string, at::Tensor> t;
  for (const auto& kv : from.named_parameters()) t[kv.key()] = kv.value().detach();
  load_module_strict(to, t, "copy");
}

double rel_diff(const at::Tensor& x, const at::Tensor& ref) {
  EXPECT_EQ(x.sizes(), ref.sizes());
  if (x.sizes() != ref.sizes()) return std::numeric_limits<double>::infinity();
  const double diff = (x.to(at::kDouble) - ref.to(at::kDouble)).abs().max().item<double>();
  const double scale = ref.to(at::kDouble).abs().max().item<double>();
  if (scale == 0.0) return diff == 0.0 ? 0.0 : std::numeric_limits<double>::infinity();
  return diff / scale;
}

}  // namespace long3r::test

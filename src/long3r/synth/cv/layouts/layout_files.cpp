// The dataset-layout writers' shared file pieces; see layout_files.hpp.
#include "long3r/synth/cv/layouts/layout_files.hpp"

#include <opencv2/imgcodecs.hpp>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <system_error>

namespace long3r::synth::layouts {

void make_dirs(const std::string& dir) {
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) throw std::runtime_error(dir + ": cannot be created (" + ec.message() + ")");
}

void write_text(const std::string& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(text.data(), static_cast<std::streamsize>(text.size()));
  if (!out.flush()) throw std::runtime_error(path + ": cannot be written");
}

void write_image(const std::string& path, const cv::Mat& image, const std::vector<int>& params) {
  bool ok = false;
  try {
    ok = cv::imwrite(path, image, params);
  } catch (const cv::Exception&) {
    ok = false;
  }
  if (!ok) throw std::runtime_error(path + ": cannot be written");
}

void list_once(const std::string& path, const std::string& name) {
  const std::filesystem::path folder = std::filesystem::path(path).parent_path();
  if (!folder.empty()) make_dirs(folder.string());
  {
    std::ifstream in(path);
    for (std::string line; std::getline(in, line);) {
      if (line == name) return;
    }
  }
  std::ofstream app(path, std::ios::app);
  app << name << "\n";
  if (!app.flush()) throw std::runtime_error(path + ": cannot be written");
}

cv::Mat depth_mm(const cv::Mat& depth_m) {
  cv::Mat mm(depth_m.size(), CV_16U);
  for (int r = 0; r < depth_m.rows; ++r) {
    const float* d = depth_m.ptr<float>(r);
    uint16_t* o = mm.ptr<uint16_t>(r);
    for (int c = 0; c < depth_m.cols; ++c) {
      const double v = std::isfinite(d[c]) && d[c] > 0.0f ? std::round(d[c] * 1000.0) : 0.0;
      o[c] = static_cast<uint16_t>(std::min(v, 65535.0));
    }
  }
  return mm;
}

}  // namespace long3r::synth::layouts

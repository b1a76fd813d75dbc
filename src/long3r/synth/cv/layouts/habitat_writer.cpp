// A sequence written as Habitat renders in the layout of CroCo's generator
// (src/long3r/train/cv/datasets/habitat.cpp has the layout): groups of 5 views,
// JPEG colour, half-float EXR z-depth in metres, and a JSON camera file per
// view with K and the camera-to-world pose (OpenCV axes).
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>

#include <algorithm>
#include <cctype>
#include <cstdio>
#include <filesystem>
#include <stdexcept>

#include "long3r/synth/cv/dataset_layouts.hpp"
#include "long3r/synth/cv/layouts/layout_files.hpp"

namespace long3r::synth {

namespace {

namespace fs = std::filesystem;

constexpr std::size_t kViews = 5;

// The number after the last group already in `dir` (0 when none), so that
// a second call adds groups.
long next_group(const fs::path& dir) {
  long next = 0;
  for (const auto& entry : fs::directory_iterator(dir)) {
    const std::string name = entry.path().filename().string();
    const std::size_t us = name.find('_');
    if (us == std::string::npos || us == 0 || entry.path().extension() != ".jpeg") continue;
    const std::string group = name.substr(0, us);
    if (std::all_of(group.begin(), group.end(),
                    [](char c) { return std::isdigit(static_cast<unsigned char>(c)); })) {
      next = std::max(next, std::stol(group) + 1);
    }
  }
  return next;
}

nlohmann::json rows(const Eigen::Matrix3d& m) {
  nlohmann::json out = nlohmann::json::array();
  for (int r = 0; r < 3; ++r) out.push_back({m(r, 0), m(r, 1), m(r, 2)});
  return out;
}

}  // namespace

void write_habitat_sequence(const std::string& root, const std::string& name,
                            const std::vector<LayoutFrame>& frames) {
  if (frames.empty() || frames.size() % kViews != 0) {
    throw std::invalid_argument("write_habitat_sequence: frames come in groups of 5, not " +
                                std::to_string(frames.size()));
  }
  // `name` is "<dataset>/<scene>".
  const fs::path dir = fs::path(root) / name;
  layouts::make_dirs(dir.string());
  const long first = next_group(dir);
  for (std::size_t i = 0; i < frames.size(); ++i) {
    const LayoutFrame& f = frames[i];
    char base[48];
    std::snprintf(base, sizeof(base), "%08ld_%zu", first + static_cast<long>(i / kViews),
                  i % kViews + 1);  // views numbered from 1
    layouts::write_image((dir / (std::string(base) + ".jpeg")).string(), f.bgr,
                         {cv::IMWRITE_JPEG_QUALITY, 95});
    layouts::write_image((dir / (std::string(base) + "_depth.exr")).string(), f.depth_m,
                         {cv::IMWRITE_EXR_TYPE, cv::IMWRITE_EXR_TYPE_HALF});
    const Eigen::Vector3d t = f.T_W_C.translation();
    nlohmann::json params;
    params["camera_intrinsics"] = rows(f.intrinsics.matrix());
    params["R_cam2world"] = rows(f.T_W_C.linear());
    params["t_cam2world"] = {t.x(), t.y(), t.z()};
    layouts::write_text((dir / (std::string(base) + "_camera_params.json")).string(),
                        params.dump());
  }
}

}  // namespace long3r::synth

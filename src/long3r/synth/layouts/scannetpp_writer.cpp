// A sequence written as a ScanNet++ scene (DSLR, undistorted) in the layout
// Spann3R reads (src/long3r/train/datasets/scannetpp.cpp has the layout):
// DSCxxxxx.JPG colour, 16-bit millimetre depth PNGs, the nerfstudio
// transforms_undistorted.json (the scene's pinhole K, camera-to-world in
// OpenGL camera axes), train_test_lists.json with every frame in "train",
// and the scene added to splits/nvs_sem_train.txt.
#include <opencv2/imgcodecs.hpp>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <stdexcept>

#include "long3r/synth/dataset_layouts.hpp"

namespace long3r::synth {

namespace {

namespace fs = std::filesystem;

void check_written(const std::ofstream& out, const std::string& path) {
  if (!out) throw std::runtime_error(path + ": cannot be written");
}

void write_json(const std::string& path, const nlohmann::json& j) {
  std::ofstream out(path);
  out << j.dump(2) << "\n";  // doubles with round-trip precision
  out.close();
  check_written(out, path);
}

// Millimetres as uint16, 0 where no depth; beyond 65.535 m clipped, as
// ScanNet++'s rendered depth is.
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

}  // namespace

void write_scannetpp_sequence(const std::string& root, const std::string& name,
                              const std::vector<LayoutFrame>& frames) {
  if (frames.empty()) throw std::invalid_argument("write_scannetpp_sequence: no frames");
  // ScanNet++ stores one K per scene: every frame must share it.
  const PinholeIntrinsics& k = frames.front().intrinsics;
  const int width = frames.front().bgr.cols, height = frames.front().bgr.rows;
  for (const LayoutFrame& f : frames) {
    if (f.intrinsics.fx != k.fx || f.intrinsics.fy != k.fy || f.intrinsics.cx != k.cx ||
        f.intrinsics.cy != k.cy || f.bgr.cols != width || f.bgr.rows != height) {
      throw std::invalid_argument(
          "write_scannetpp_sequence: a ScanNet++ scene has one camera (intrinsics and size)");
    }
  }
  const fs::path dslr = fs::path(root) / "data" / name / "dslr";
  for (const char* sub : {"undistorted_images", "undistorted_depths", "nerfstudio"}) {
    std::error_code ec;
    fs::create_directories(dslr / sub, ec);
    if (ec) throw std::runtime_error((dslr / sub).string() + ": " + ec.message());
  }

  nlohmann::json tf_frames = nlohmann::json::array();
  nlohmann::json train = nlohmann::json::array();
  for (std::size_t i = 0; i < frames.size(); ++i) {
    const LayoutFrame& f = frames[i];
    char stem[32];
    std::snprintf(stem, sizeof(stem), "DSC%05zu", i);
    const std::string image_name = std::string(stem) + ".JPG";
    const std::string image = (dslr / "undistorted_images" / image_name).string();
    const std::string depth = (dslr / "undistorted_depths" / (std::string(stem) + ".png")).string();
    if (!cv::imwrite(image, f.bgr, {cv::IMWRITE_JPEG_QUALITY, 95})) {
      throw std::runtime_error(image + ": cannot be written");
    }
    if (!cv::imwrite(depth, depth_mm(f.depth_m))) {
      throw std::runtime_error(depth + ": cannot be written");
    }
    // OpenCV camera axes to OpenGL's (y up, z backward): columns 1 and 2
    // negated, the inverse of the reader's conversion.
    Eigen::Matrix4d c2w = f.T_W_C.matrix();
    c2w.col(1) *= -1.0;
    c2w.col(2) *= -1.0;
    nlohmann::json m = nlohmann::json::array();
    for (int r = 0; r < 4; ++r) {
      m.push_back({c2w(r, 0), c2w(r, 1), c2w(r, 2), c2w(r, 3)});
    }
    tf_frames.push_back({{"file_path", image_name}, {"transform_matrix", m}});
    train.push_back(image_name);
  }
  const nlohmann::json tf = {{"camera_model", "PINHOLE"},
                             {"fl_x", k.fx},
                             {"fl_y", k.fy},
                             {"cx", k.cx},
                             {"cy", k.cy},
                             {"w", width},
                             {"h", height},
                             {"frames", tf_frames}};
  write_json((dslr / "nerfstudio" / "transforms_undistorted.json").string(), tf);
  write_json((dslr / "train_test_lists.json").string(),
             {{"train", train}, {"test", nlohmann::json::array()}});

  // Added to the "train" split unless listed already.
  const fs::path splits = fs::path(root) / "splits";
  std::error_code ec;
  fs::create_directories(splits, ec);
  if (ec) throw std::runtime_error(splits.string() + ": " + ec.message());
  const std::string list = (splits / "nvs_sem_train.txt").string();
  bool listed = false;
  {
    std::ifstream in(list);
    for (std::string line; std::getline(in, line);) {
      if (line == name) listed = true;
    }
  }
  if (!listed) {
    std::ofstream app(list, std::ios::app);
    app << name << "\n";
    app.close();
    check_written(app, list);
  }
}

}  // namespace long3r::synth

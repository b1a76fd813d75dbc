// A sequence written as a ScanNet++ scene (DSLR, undistorted) in the layout
// Spann3R reads (src/long3r/train/cv/datasets/scannetpp.cpp has the layout):
// DSCxxxxx.JPG colour, 16-bit millimetre depth PNGs, the nerfstudio
// transforms_undistorted.json (the scene's pinhole K, camera-to-world in
// OpenGL camera axes), train_test_lists.json with every frame in "train",
// and the scene added to splits/nvs_sem_train.txt.
#include <opencv2/imgcodecs.hpp>

#include <cstdio>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <stdexcept>

#include "long3r/synth/cv/dataset_layouts.hpp"
#include "long3r/synth/cv/layouts/layout_files.hpp"

namespace long3r::synth {

namespace {

namespace fs = std::filesystem;

void write_json(const std::string& path, const nlohmann::json& j) {
  layouts::write_text(path, j.dump(2) + "\n");  // doubles with round-trip precision
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
    layouts::make_dirs((dslr / sub).string());
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
    layouts::write_image(image, f.bgr, {cv::IMWRITE_JPEG_QUALITY, 95});
    // Millimetres, clipped beyond 65.535 m as ScanNet++'s rendered depth is.
    layouts::write_image(depth, layouts::depth_mm(f.depth_m));
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

  // In the "train" split, once however often the scene is written.
  layouts::list_once((fs::path(root) / "splits" / "nvs_sem_train.txt").string(), name);
}

}  // namespace long3r::synth

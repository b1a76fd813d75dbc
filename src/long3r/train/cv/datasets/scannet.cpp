// ScanNet in the layout that Spann3R reads (spann3r/datasets/scannet.py; the
// frames as SimpleRecon's ScanNet scripts export them):
//   ROOT/splits/scannetv2_{split}.txt                 scene names, one a line
//   ROOT/scans/<scene>/ (split "test": ROOT/scans_test/<scene>/)
//     intrinsic/intrinsic_depth.txt                   4 x 4 text, K of the depth image top left
//     sensor_data/frame-XXXXXX.color.jpg              colour, larger than the depth
//     sensor_data/frame-XXXXXX.depth.png              16-bit millimetres, 0 invalid
//     sensor_data/frame-XXXXXX.pose.txt               4 x 4 text camera-to-world, OpenCV axes
// One sequence per scene, its frames in frame-number (time) order. As the
// official reader, the colour is resized to the depth's size and the depth
// intrinsics describe both.
#include <algorithm>
#include <cctype>
#include <cstdio>
#include <filesystem>
#include <set>
#include <utility>

#include "long3r/train/cv/datasets/dataset_io.hpp"

namespace long3r::datasets {

namespace {

namespace fs = std::filesystem;

// The frame number of "frame-XXXXXX.color.jpg" (six digits); -1 for any
// other name (SimpleRecon's optional frame-XXXXXX.color.512.png among them).
int64_t color_frame_id(const std::string& name) {
  const std::string prefix = "frame-", suffix = ".color.jpg";
  if (name.size() != prefix.size() + 6 + suffix.size() || name.compare(0, 6, prefix) != 0 ||
      name.compare(prefix.size() + 6, suffix.size(), suffix) != 0) {
    return -1;
  }
  const std::string digits = name.substr(prefix.size(), 6);
  for (const char c : digits) {
    if (!std::isdigit(static_cast<unsigned char>(c))) return -1;
  }
  return std::stoll(digits);
}

std::string scannet_stem(int64_t id) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "frame-%06lld", static_cast<long long>(id));
  return buf;
}

RawFrame load_scannet_frame(const fs::path& data, int64_t id, const Eigen::Matrix3d& k_depth,
                            const std::string& k_path) {
  const std::string stem = scannet_stem(id);
  const std::string image = (data / (stem + ".color.jpg")).string();
  const std::string depth_path = (data / (stem + ".depth.png")).string();
  const std::string pose_path = (data / (stem + ".pose.txt")).string();
  const cv::Mat bgr = read_color(image);
  const cv::Mat depth = read_depth(depth_path, 1e-3);  // millimetres
  // ScanNet's -inf poses (lost tracking) fail here, as the official reader
  // rejects non-finite poses.
  const Eigen::Isometry3d T_W_C = rigid_from_matrix(read_matrix_text(pose_path, 4, 4), pose_path);
  const PinholeIntrinsics k = intrinsics_from_k(k_depth, depth.cols, depth.rows, k_path);
  return make_frame(bgr, depth, k, T_W_C, image, /*resize_color=*/true);
}

}  // namespace

DatasetScan open_scannet(const DatasetSource& source) {
  const fs::path root(source.root);
  if (!fs::is_directory(root)) throw DatasetError(source.root + ": no ScanNet folder there");
  const std::string& label = source.label();
  const fs::path scans = root / (source.split == "test" ? "scans_test" : "scans");
  // A missing split list throws (DatasetError naming it).
  const std::vector<std::string> scenes =
      read_lines((root / "splits" / ("scannetv2_" + source.split + ".txt")).string());
  DatasetScan scan;
  std::set<std::string> seen;
  for (const std::string& scene : scenes) {
    if (!seen.insert(scene).second) continue;
    const fs::path dir = scans / scene;
    const std::string k_path = (dir / "intrinsic" / "intrinsic_depth.txt").string();
    Eigen::Matrix3d k_depth;
    try {
      const Eigen::Matrix4d m = read_matrix_text(k_path, 4, 4);
      k_depth = m.topLeftCorner<3, 3>();
      intrinsics_from_k(k_depth, 0, 0, k_path);  // only checked here
    } catch (const DatasetError& e) {
      scan.skipped.push_back(e.what());
      continue;
    }
    const fs::path data = dir / "sensor_data";
    std::error_code ec;
    if (!fs::is_directory(data, ec)) {
      scan.skipped.push_back(data.string() + ": missing");
      continue;
    }
    // The frames are the colour images there (the official reader counts
    // them), by frame number.
    std::vector<int64_t> ids;
    for (fs::directory_iterator it(data, ec), end; !ec && it != end; it.increment(ec)) {
      const int64_t id = color_frame_id(it->path().filename().string());
      if (id >= 0) ids.push_back(id);
    }
    if (ec) {
      scan.skipped.push_back(data.string() + ": cannot be listed (" + ec.message() + ")");
      continue;
    }
    if (ids.empty()) {
      scan.skipped.push_back(data.string() + ": no frame-XXXXXX.color.jpg images");
      continue;
    }
    std::sort(ids.begin(), ids.end());
    const int64_t size = static_cast<int64_t>(ids.size());
    scan.sequences.push_back(std::make_unique<FrameListSource>(
        label + "/" + scene, size, [data, ids = std::move(ids), k_depth, k_path](int64_t i) {
          return load_scannet_frame(data, ids.at(static_cast<std::size_t>(i)), k_depth, k_path);
        }));
  }
  return scan;
}

}  // namespace long3r::datasets

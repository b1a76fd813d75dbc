// Co3D-v2 as DUSt3R's preprocess_co3d.py leaves it and Spann3R reads it
// (spann3r/datasets/co3d.py):
//   <root>/selected_seqs_<split>.json   {category: {sequence: [frame numbers]}}
//   <root>/<category>/<sequence>/images/frame<n:06d>.jpg   colour
//   .../images/frame<n:06d>.npz   camera_intrinsics (3 x 3), camera_pose (4 x 4
//                                 camera-to-world, OpenCV axes), maximum_depth
//   .../depths/frame<n:06d>.jpg.geometric.png   uint16 = depth / maximum_depth * 65535
//   .../masks/frame<n:06d>.png    uint8 object mask * 255
// Depth is in Co3D's own (not metric) unit. With mask_background, depth off
// the object (mask / 255 <= 0.1) is invalid.
#include <opencv2/imgcodecs.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <string>
#include <system_error>
#include <utility>
#include <vector>

#include "long3r/train/cv/datasets/dataset_io.hpp"

namespace long3r::datasets {

namespace {

namespace fs = std::filesystem;

std::string co3d_stem(int64_t n) {
  char text[32];
  std::snprintf(text, sizeof(text), "frame%06lld", static_cast<long long>(n));
  return text;
}

RawFrame load_co3d_frame(const std::string& dir, int64_t n, bool mask_background) {
  const std::string stem = co3d_stem(n);
  const std::string image_path = dir + "/images/" + stem + ".jpg";
  const std::string meta_path = dir + "/images/" + stem + ".npz";
  const std::string depth_path = dir + "/depths/" + stem + ".jpg.geometric.png";
  const std::map<std::string, NpyArray> meta = read_npz(meta_path);
  const Eigen::Matrix3d k = npz_matrix(meta, "camera_intrinsics", 3, 3, meta_path);
  const Eigen::Matrix4d pose = npz_matrix(meta, "camera_pose", 4, 4, meta_path);
  const double maximum_depth = npz_matrix(meta, "maximum_depth", 1, 1, meta_path)(0, 0);
  // Spann3R maps a NaN maximum to 0, which leaves no valid depth.
  if (!std::isfinite(maximum_depth) || maximum_depth <= 0.0) {
    throw DatasetError(meta_path + ": maximum_depth " + std::to_string(maximum_depth) +
                       " (no valid depth)");
  }
  const cv::Mat bgr = read_color(image_path);
  cv::Mat depth = read_depth(depth_path, maximum_depth / 65535.0);
  if (mask_background) {
    const std::string mask_path = dir + "/masks/" + stem + ".png";
    const cv::Mat mask = cv::imread(mask_path, cv::IMREAD_GRAYSCALE);
    if (mask.empty()) {
      throw DatasetError(mask_path + ": not a readable mask image (missing or truncated?)");
    }
    if (mask.size() != depth.size()) {
      throw DatasetError(mask_path + ": mask " + std::to_string(mask.cols) + " x " +
                         std::to_string(mask.rows) + " and depth " + std::to_string(depth.cols) +
                         " x " + std::to_string(depth.rows) + " differ in size");
    }
    // mask / 255 > 0.1: foreground from 26 up.
    depth.setTo(0.0f, mask <= 25);
  }
  if (cv::countNonZero(depth) == 0) {
    throw DatasetError(depth_path + ": no valid depth" +
                       (mask_background ? std::string(" on the object's mask") : std::string()));
  }
  const PinholeIntrinsics intrinsics = intrinsics_from_k(k, depth.cols, depth.rows, meta_path);
  const Eigen::Isometry3d T_W_C = rigid_from_matrix(pose, meta_path);
  return make_frame(bgr, depth, intrinsics, T_W_C, image_path);
}

// The frame numbers of a sequence's entry in the split list; DatasetError
// naming the list and the sequence when it is not a list of them.
std::vector<int64_t> frame_numbers(const nlohmann::json& entry, const std::string& what) {
  if (!entry.is_array()) throw DatasetError(what + ": not a list of frame numbers");
  std::vector<int64_t> numbers;
  for (const nlohmann::json& n : entry) {
    if (!n.is_number_integer() || n.get<int64_t>() < 0) {
      throw DatasetError(what + ": " + n.dump() + " is not a frame number");
    }
    numbers.push_back(n.get<int64_t>());
  }
  if (numbers.empty()) throw DatasetError(what + ": no frames");
  // Time order (the list is written in it; sorted in case it is not).
  std::sort(numbers.begin(), numbers.end());
  numbers.erase(std::unique(numbers.begin(), numbers.end()), numbers.end());
  return numbers;
}

}  // namespace

DatasetScan open_co3d(const DatasetSource& source) {
  std::error_code ec;
  if (!fs::is_directory(source.root, ec)) throw DatasetError(source.root + ": missing");
  const std::string list_path = source.root + "/selected_seqs_" + source.split + ".json";
  const nlohmann::json list = read_json(list_path);
  if (!list.is_object()) {
    throw DatasetError(list_path + ": not an object {category: {sequence: [frames]}}");
  }
  const std::string& prefix = source.label();
  const bool mask_background = source.mask_background;
  DatasetScan scan;
  for (auto c = list.begin(); c != list.end(); ++c) {
    const std::string& category = c.key();
    const nlohmann::json& sequences = c.value();
    if (!sequences.is_object()) {
      scan.skipped.push_back(list_path + ": category \"" + category +
                             "\" is not an object {sequence: [frames]}");
      continue;
    }
    for (auto q = sequences.begin(); q != sequences.end(); ++q) {
      const std::string& sequence = q.key();
      const nlohmann::json& entry = q.value();
      const std::string dir = source.root + "/" + category + "/" + sequence;
      try {
        std::vector<int64_t> numbers =
            frame_numbers(entry, list_path + ": " + category + "/" + sequence);
        for (const char* sub : {"/images", "/depths"}) {
          if (!fs::is_directory(dir + sub, ec)) throw DatasetError(dir + sub + ": missing");
        }
        if (mask_background && !fs::is_directory(dir + "/masks", ec)) {
          throw DatasetError(dir + "/masks: missing (needed by mask_background)");
        }
        const int64_t size = static_cast<int64_t>(numbers.size());
        scan.sequences.push_back(std::make_unique<FrameListSource>(
            prefix + "/" + category + "/" + sequence, size,
            [dir, numbers = std::move(numbers), mask_background](int64_t i) {
              if (i < 0 || i >= static_cast<int64_t>(numbers.size())) {
                throw std::out_of_range(dir + ": no frame " + std::to_string(i));
              }
              return load_co3d_frame(dir, numbers[static_cast<std::size_t>(i)], mask_background);
            }));
      } catch (const DatasetError& e) {
        scan.skipped.push_back(e.what());
      }
    }
  }
  return scan;
}

}  // namespace long3r::datasets

// ScanNet++ (DSLR, undistorted) in the layout that Spann3R reads
// (spann3r/datasets/scannetpp.py; undistorted as SplaTAM's ScanNet++ scripts
// leave it):
//   ROOT/splits/nvs_sem_{split}.txt                        scene names, one a line
//   ROOT/data/<scene>/dslr/undistorted_images/DSCxxxxx.JPG     colour
//   ROOT/data/<scene>/dslr/undistorted_depths/DSCxxxxx.png     16-bit millimetres, 0 invalid
//   ROOT/data/<scene>/dslr/nerfstudio/transforms_undistorted.json
//       the scene's pinhole "fl_x", "fl_y", "cx", "cy" (and "w", "h"), and
//       "frames": [{"file_path": image name, "transform_matrix": camera-to-world
//       4 x 4 in OpenGL camera axes}]
//   ROOT/data/<scene>/dslr/train_test_lists.json          {"train": [image names], "test": [...]}
// One sequence per scene: its "train" images sorted by name (capture order),
// for every split, as the official reader.
#include <filesystem>
#include <limits>
#include <map>
#include <set>
#include <utility>

#include "long3r/train/cv/datasets/dataset_io.hpp"

namespace long3r::datasets {

namespace {

namespace fs = std::filesystem;

struct ScannetppFrame {
  std::string image;       // name in undistorted_images
  Eigen::Matrix4d c2w_gl;  // transform_matrix as stored
};

double json_number(const nlohmann::json& j, const char* key, const std::string& path) {
  if (!j.contains(key) || !j[key].is_number()) {
    throw DatasetError(path + ": no number \"" + key + "\"");
  }
  return j[key].get<double>();
}

Eigen::Matrix4d json_matrix4(const nlohmann::json& j, const std::string& path,
                             const std::string& image) {
  if (!j.is_array() || j.size() != 4) {
    throw DatasetError(path + ": the transform_matrix of " + image + " is not 4 x 4");
  }
  Eigen::Matrix4d m;
  for (int r = 0; r < 4; ++r) {
    const nlohmann::json& row = j[static_cast<std::size_t>(r)];
    if (!row.is_array() || row.size() != 4) {
      throw DatasetError(path + ": the transform_matrix of " + image + " is not 4 x 4");
    }
    for (int c = 0; c < 4; ++c) {
      const nlohmann::json& v = row[static_cast<std::size_t>(c)];
      // JSON has no infinity or NaN: a null stands for them (the frame is
      // then rejected when read, not the scene).
      if (v.is_null()) {
        m(r, c) = std::numeric_limits<double>::quiet_NaN();
      } else if (v.is_number()) {
        m(r, c) = v.get<double>();
      } else {
        throw DatasetError(path + ": the transform_matrix of " + image + " holds a non-number");
      }
    }
  }
  return m;
}

// The scene's K and its train frames, sorted by name; DatasetError naming
// the file that is missing or broken.
Eigen::Matrix3d read_scene(const fs::path& dslr, std::vector<ScannetppFrame>* frames, int* width,
                           int* height) {
  const std::string tf_path = (dslr / "nerfstudio" / "transforms_undistorted.json").string();
  const std::string lists_path = (dslr / "train_test_lists.json").string();
  const nlohmann::json tf = read_json(tf_path);
  if (!tf.is_object()) throw DatasetError(tf_path + ": not a JSON object");
  Eigen::Matrix3d k = Eigen::Matrix3d::Identity();
  k(0, 0) = json_number(tf, "fl_x", tf_path);
  k(1, 1) = json_number(tf, "fl_y", tf_path);
  k(0, 2) = json_number(tf, "cx", tf_path);
  k(1, 2) = json_number(tf, "cy", tf_path);
  intrinsics_from_k(k, 0, 0, tf_path);  // checked here
  // The image size where given (0: taken from the images).
  const double w = tf.contains("w") ? json_number(tf, "w", tf_path) : 0.0;
  const double h = tf.contains("h") ? json_number(tf, "h", tf_path) : 0.0;
  if (!(w >= 0.0 && w < 1e6 && h >= 0.0 && h < 1e6)) {
    throw DatasetError(tf_path + ": an image size \"w\", \"h\" out of range");
  }
  *width = static_cast<int>(w);
  *height = static_cast<int>(h);
  if (!tf.contains("frames") || !tf["frames"].is_array()) {
    throw DatasetError(tf_path + ": no \"frames\" list");
  }
  std::map<std::string, Eigen::Matrix4d> poses;
  for (const nlohmann::json& f : tf["frames"]) {
    if (!f.is_object() || !f.contains("file_path") || !f["file_path"].is_string() ||
        !f.contains("transform_matrix")) {
      throw DatasetError(tf_path + ": a frame without file_path and transform_matrix");
    }
    const std::string image = f["file_path"].get<std::string>();
    poses[image] = json_matrix4(f["transform_matrix"], tf_path, image);
  }
  const nlohmann::json lists = read_json(lists_path);
  if (!lists.is_object() || !lists.contains("train") || !lists["train"].is_array()) {
    throw DatasetError(lists_path + ": no \"train\" list");
  }
  std::set<std::string> train;
  for (const nlohmann::json& name : lists["train"]) {
    if (!name.is_string()) throw DatasetError(lists_path + ": a train entry is not a name");
    train.insert(name.get<std::string>());
  }
  if (train.empty()) throw DatasetError(lists_path + ": no train images");
  frames->clear();
  for (const std::string& image : train) {  // sorted, as the official reader
    const auto it = poses.find(image);
    if (it == poses.end()) {
      throw DatasetError(lists_path + ": train image " + image + " has no frame in " + tf_path);
    }
    frames->push_back({image, it->second});
  }
  return k;
}

// "DSC01234.JPG" -> "DSC01234.png", as the official reader's replace.
std::string depth_name(const std::string& image) {
  const std::size_t at = image.rfind(".JPG");
  return at == std::string::npos ? image + ".png" : image.substr(0, at) + ".png";
}

RawFrame load_scannetpp_frame(const fs::path& dslr, const ScannetppFrame& f,
                              const PinholeIntrinsics& k, const std::string& tf_path) {
  const std::string image = (dslr / "undistorted_images" / f.image).string();
  const std::string depth_path = (dslr / "undistorted_depths" / depth_name(f.image)).string();
  const cv::Mat bgr = read_color(image);
  const cv::Mat depth = read_depth(depth_path, 1e-3);  // millimetres
  // OpenGL camera axes (y up, z backward) to OpenCV's: camera y and z
  // negated, i.e. the matrix's columns 1 and 2.
  Eigen::Matrix4d c2w = f.c2w_gl;
  c2w.col(1) *= -1.0;
  c2w.col(2) *= -1.0;
  const Eigen::Isometry3d T_W_C = rigid_from_matrix(c2w, tf_path + " (" + f.image + ")");
  return make_frame(bgr, depth, k, T_W_C, image);
}

}  // namespace

DatasetScan open_scannetpp(const DatasetSource& source) {
  const fs::path root(source.root);
  if (!fs::is_directory(root)) throw DatasetError(source.root + ": no ScanNet++ folder there");
  const std::string& label = source.label();
  // A missing split list throws (DatasetError naming it).
  const std::vector<std::string> scenes =
      read_lines((root / "splits" / ("nvs_sem_" + source.split + ".txt")).string());
  DatasetScan scan;
  std::set<std::string> seen;
  for (const std::string& scene : scenes) {
    if (!seen.insert(scene).second) continue;
    const fs::path dslr = root / "data" / scene / "dslr";
    std::vector<ScannetppFrame> frames;
    PinholeIntrinsics k;
    try {
      int width = 0, height = 0;
      const Eigen::Matrix3d km = read_scene(dslr, &frames, &width, &height);
      k = intrinsics_from_k(km, width, height, dslr.string());
    } catch (const DatasetError& e) {
      scan.skipped.push_back(e.what());
      continue;
    }
    const std::string tf_path = (dslr / "nerfstudio" / "transforms_undistorted.json").string();
    const int64_t size = static_cast<int64_t>(frames.size());
    scan.sequences.push_back(std::make_unique<FrameListSource>(
        label + "/" + scene, size, [dslr, frames = std::move(frames), k, tf_path](int64_t i) {
          return load_scannetpp_frame(dslr, frames.at(static_cast<std::size_t>(i)), k, tf_path);
        }));
  }
  return scan;
}

}  // namespace long3r::datasets

// Habitat renders in the layout of CroCo's generator
// (croco/datasets/habitat_sim/generate_multiview_images.py), as Spann3R reads
// them (spann3r/datasets/habitat.py):
//   ROOT/<dataset>/<scene>/{seq:08d}_{v}.jpeg                 colour, v = 1..5
//   ROOT/<dataset>/<scene>/{seq:08d}_{v}_depth.exr            z-depth, metres (half float)
//   ROOT/<dataset>/<scene>/{seq:08d}_{v}_camera_params.json   camera_intrinsics (3 x 3),
//       R_cam2world (3 x 3), t_cam2world (3): camera-to-world, OpenCV axes already
// Each 5-view group is one sequence, its views in order 1..5 (Spann3R
// shuffles them; the trainer's sampling and reversal stand in for that).
// Habitat has no split file: like Spann3R, every dataset folder and scene
// under the root is taken, whatever the split.
#include <algorithm>
#include <cctype>
#include <filesystem>
#include <set>
#include <utility>

#include "long3r/train/cv/datasets/dataset_io.hpp"

namespace long3r::datasets {

namespace {

namespace fs = std::filesystem;

constexpr int kViews = 5;  // views per group, as Spann3R reads them

bool all_digits(const std::string& s) {
  return !s.empty() && s.size() <= 12 && std::all_of(s.begin(), s.end(), [](char c) {
    return std::isdigit(static_cast<unsigned char>(c));
  });
}

std::string view_name(const std::string& group, int view) {
  return group + "_" + std::to_string(view);
}

// A json array of `n` numbers, or DatasetError naming `path` and `key`.
Eigen::VectorXd numbers(const nlohmann::json& a, int n, const std::string& path,
                        const std::string& key) {
  if (!a.is_array() || static_cast<int>(a.size()) != n) {
    throw DatasetError(path + ": \"" + key + "\" is not " + std::to_string(n) + " numbers");
  }
  Eigen::VectorXd v(n);
  for (int i = 0; i < n; ++i) {
    if (!a[static_cast<std::size_t>(i)].is_number()) {
      throw DatasetError(path + ": \"" + key + "\" holds something other than numbers");
    }
    v(i) = a[static_cast<std::size_t>(i)].get<double>();
  }
  return v;
}

// A json 3 x 3 list of lists (rows).
Eigen::Matrix3d matrix3(const nlohmann::json& params, const std::string& key,
                        const std::string& path) {
  if (!params.contains(key)) throw DatasetError(path + ": no \"" + key + "\"");
  const nlohmann::json& rows = params[key];
  if (!rows.is_array() || rows.size() != 3) {
    throw DatasetError(path + ": \"" + key + "\" is not a 3 x 3 matrix");
  }
  Eigen::Matrix3d m;
  for (int r = 0; r < 3; ++r) {
    m.row(r) = numbers(rows[static_cast<std::size_t>(r)], 3, path, key).transpose();
  }
  return m;
}

RawFrame load_habitat_frame(const fs::path& scene, const std::string& view) {
  const std::string image = (scene / (view + ".jpeg")).string();
  const std::string depth_path = (scene / (view + "_depth.exr")).string();
  const std::string params_path = (scene / (view + "_camera_params.json")).string();
  const cv::Mat bgr = read_color(image);
  const cv::Mat depth = read_depth(depth_path, 1.0);  // metres already
  const nlohmann::json params = read_json(params_path);
  if (!params.is_object()) throw DatasetError(params_path + ": not a JSON object");
  // K as it stands (CroCo puts the principal point at (w/2, h/2) and uses it
  // with OpenCV pixel coordinates, as Spann3R does).
  const PinholeIntrinsics k = intrinsics_from_k(matrix3(params, "camera_intrinsics", params_path),
                                                depth.cols, depth.rows, params_path);
  if (!params.contains("t_cam2world")) throw DatasetError(params_path + ": no \"t_cam2world\"");
  Eigen::Matrix4d m = Eigen::Matrix4d::Identity();
  m.topLeftCorner<3, 3>() = matrix3(params, "R_cam2world", params_path);
  m.topRightCorner<3, 1>() = numbers(params["t_cam2world"], 3, params_path, "t_cam2world");
  return make_frame(bgr, depth, k, rigid_from_matrix(m, params_path), image);
}

// The sub-folders of `dir`, sorted by name.
std::vector<std::string> folders(const fs::path& dir) {
  std::vector<std::string> out;
  std::error_code ec;
  for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    std::error_code type_ec;
    if (it->is_directory(type_ec)) out.push_back(it->path().filename().string());
  }
  if (ec) throw DatasetError(dir.string() + ": cannot be listed (" + ec.message() + ")");
  std::sort(out.begin(), out.end());
  return out;
}

}  // namespace

DatasetScan open_habitat(const DatasetSource& source) {
  const fs::path root(source.root);
  if (!fs::is_directory(root)) throw DatasetError(source.root + ": no Habitat folder there");
  const std::string& label = source.label();
  DatasetScan scan;
  for (const std::string& dataset : folders(root)) {
    std::vector<std::string> scenes;
    try {
      scenes = folders(root / dataset);
    } catch (const DatasetError& e) {
      scan.skipped.push_back(e.what());
      continue;
    }
    for (const std::string& scene : scenes) {
      const fs::path dir = root / dataset / scene;
      // The scene's file names; a group's index is its views' images and
      // camera files. Only their presence is checked here: reading every
      // camera file of a real Habitat set (about a million) would make
      // opening slow; a broken one fails its frame instead.
      std::set<std::string> names;
      std::set<std::pair<int64_t, std::string>> groups;  // by number
      std::error_code ec;
      for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
        const std::string name = it->path().filename().string();
        names.insert(name);
        const std::size_t us = name.find('_');
        if (us == std::string::npos || it->path().extension() != ".jpeg") continue;
        const std::string group = name.substr(0, us);
        const std::string view = it->path().stem().string().substr(us + 1);
        if (all_digits(group) && all_digits(view)) groups.emplace(std::stoll(group), group);
      }
      if (ec) {
        scan.skipped.push_back(dir.string() + ": cannot be listed (" + ec.message() + ")");
        continue;
      }
      if (groups.empty()) {
        scan.skipped.push_back(dir.string() + ": no view groups ({seq:08d}_{v}.jpeg)");
        continue;
      }
      for (const auto& g : groups) {
        const std::string& group = g.second;
        std::string missing;
        for (int v = 1; v <= kViews && missing.empty(); ++v) {
          for (const std::string suffix : {".jpeg", "_camera_params.json"}) {
            const std::string file = view_name(group, v) + suffix;
            if (!names.count(file)) {
              missing = (dir / file).string();
              break;
            }
          }
        }
        if (!missing.empty()) {
          scan.skipped.push_back(missing + ": missing (a group has views 1 to " +
                                 std::to_string(kViews) + ")");
          continue;
        }
        scan.sequences.push_back(std::make_unique<FrameListSource>(
            label + "/" + dataset + "/" + scene + "/" + group, kViews, [dir, group](int64_t i) {
              if (i < 0 || i >= kViews) throw std::out_of_range("habitat: no such view");
              return load_habitat_frame(dir, view_name(group, static_cast<int>(i) + 1));
            }));
      }
    }
  }
  return scan;
}

}  // namespace long3r::datasets

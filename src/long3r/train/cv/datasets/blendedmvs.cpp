// BlendedMVS in the raw layout that Spann3R reads (spann3r/datasets/blendedmvs.py):
//   ROOT/{split}_list.txt                      scene folder names, one a line
//   ROOT/<scene>/blended_images/XXXXXXXX.jpg   colour (the *_masked.jpg beside them unused)
//   ROOT/<scene>/rendered_depth_maps/XXXXXXXX.pfm   float depth, the scene's own unit
//   ROOT/<scene>/cams/XXXXXXXX_cam.txt         MVSNet camera: world-to-camera extrinsic, K
//   ROOT/<scene>/cams/pair.txt                 MVSNet view neighbours
// One sequence per scene, its frames in id order. Spann3R draws a random
// reference view of pair.txt and random neighbours of it; here the trainer's
// gap sampling over the id order stands in for that (BlendedMVS ids follow
// the capture, so nearby ids see the same surfaces), and pair.txt is only
// checked, as the index of the scene's views.
#include <algorithm>
#include <cctype>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>
#include <utility>

#include "long3r/train/cv/datasets/dataset_io.hpp"

namespace long3r::datasets {

namespace {

namespace fs = std::filesystem;

// The id of a name made of digits only ("00000012" -> 12); -1 otherwise.
int64_t parse_id(const std::string& s) {
  if (s.empty() || s.size() > 12) return -1;
  for (const char c : s) {
    if (!std::isdigit(static_cast<unsigned char>(c))) return -1;
  }
  return std::stoll(s);
}

struct MvsnetCamera {
  Eigen::Matrix4d world_to_camera;
  Eigen::Matrix3d k;
};

// "extrinsic", 16 numbers, "intrinsic", 9 numbers; the depth range after
// them is not used (Spann3R's load_cam_mvsnet reads the same two blocks).
MvsnetCamera read_mvsnet_camera(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw DatasetError(path + ": cannot be read (missing?)");
  auto expect_word = [&](const char* word) {
    std::string token;
    if (!(in >> token) || token != word) {
      throw DatasetError(path + ": not an MVSNet camera file (no \"" + word + "\" block)");
    }
  };
  auto numbers = [&](Eigen::Ref<Eigen::MatrixXd> m) {
    for (int r = 0; r < m.rows(); ++r) {
      for (int c = 0; c < m.cols(); ++c) {
        std::string token;
        if (!(in >> token)) throw DatasetError(path + ": truncated MVSNet camera file");
        if (!parse_finite(token, &m(r, c))) {
          throw DatasetError(path + ": \"" + token + "\" is not a number");
        }
      }
    }
  };
  MvsnetCamera cam;
  Eigen::MatrixXd e(4, 4), k(3, 3);
  expect_word("extrinsic");
  numbers(e);
  expect_word("intrinsic");
  numbers(k);
  cam.world_to_camera = e;
  cam.k = k;
  return cam;
}

// Empty when pair.txt is well formed and names only views that have an
// image; else why not (its path in front).
std::string check_pairs(const std::string& path, const std::set<int64_t>& ids) {
  std::vector<std::string> lines;
  try {
    lines = read_lines(path);
  } catch (const DatasetError& e) {
    return e.what();
  }
  auto id_known = [&](const std::string& token, int64_t* id) {
    *id = parse_id(token);
    return *id >= 0 && ids.count(*id) > 0;
  };
  const int64_t views = lines.empty() ? -1 : parse_id(lines[0]);
  if (views < 1) return path + ": no view count on the first line";
  if (static_cast<int64_t>(lines.size()) < 1 + 2 * views) {
    return path + ": " + std::to_string(views) + " views announced, " +
           std::to_string((lines.size() - 1) / 2) + " listed";
  }
  for (int64_t v = 0; v < views; ++v) {
    const std::string& ref = lines[static_cast<std::size_t>(1 + 2 * v)];
    int64_t id = -1;
    if (!id_known(ref, &id)) return path + ": view \"" + ref + "\" has no image";
    std::istringstream in(lines[static_cast<std::size_t>(2 + 2 * v)]);
    std::vector<std::string> tokens;
    for (std::string t; in >> t;) tokens.push_back(t);
    const int64_t n = tokens.empty() ? -1 : parse_id(tokens[0]);
    if (n < 0 || static_cast<int64_t>(tokens.size()) != 1 + 2 * n) {
      return path + ": the neighbours of view " + ref + " are not \"n id score ...\"";
    }
    for (int64_t j = 0; j < n; ++j) {
      const std::string& nb = tokens[static_cast<std::size_t>(1 + 2 * j)];
      double score = 0;
      if (!id_known(nb, &id)) return path + ": neighbour \"" + nb + "\" has no image";
      if (!parse_finite(tokens[static_cast<std::size_t>(2 + 2 * j)], &score)) {
        return path + ": a score of view " + ref + " is not a number";
      }
    }
  }
  return "";
}

RawFrame load_blendedmvs_frame(const fs::path& scene, const std::string& stem) {
  const std::string image = (scene / "blended_images" / (stem + ".jpg")).string();
  const std::string depth_path = (scene / "rendered_depth_maps" / (stem + ".pfm")).string();
  const std::string cam_path = (scene / "cams" / (stem + "_cam.txt")).string();
  const cv::Mat bgr = read_color(image);
  // The reconstruction's own unit (BlendedMVS has no metric scale); NaN -> 0.
  const cv::Mat depth = read_depth(depth_path, 1.0);
  const MvsnetCamera cam = read_mvsnet_camera(cam_path);
  // K is used as it stands, as Spann3R does (OpenCV pixel convention).
  const PinholeIntrinsics k = intrinsics_from_k(cam.k, depth.cols, depth.rows, cam_path);
  const Eigen::Isometry3d T_W_C = rigid_from_matrix(cam.world_to_camera, cam_path).inverse();
  return make_frame(bgr, depth, k, T_W_C, image);
}

}  // namespace

DatasetScan open_blendedmvs(const DatasetSource& source) {
  const fs::path root(source.root);
  if (!fs::is_directory(root)) throw DatasetError(source.root + ": no BlendedMVS folder there");
  const std::string& label = source.label();
  // A missing split list throws (DatasetError naming it).
  const std::vector<std::string> scenes =
      read_lines((root / (source.split + "_list.txt")).string());
  DatasetScan scan;
  std::set<std::string> seen;
  for (const std::string& scene : scenes) {
    if (!seen.insert(scene).second) continue;
    const fs::path dir = root / scene;
    const fs::path images = dir / "blended_images";
    std::error_code ec;
    if (!fs::is_directory(images, ec)) {
      scan.skipped.push_back(images.string() + ": missing");
      continue;
    }
    // Views by id: XXXXXXXX.jpg only (not XXXXXXXX_masked.jpg).
    std::vector<std::pair<int64_t, std::string>> views;
    for (fs::directory_iterator it(images, ec), end; !ec && it != end; it.increment(ec)) {
      const fs::path p = it->path();
      if (p.extension() != ".jpg") continue;
      const int64_t id = parse_id(p.stem().string());
      if (id >= 0) views.emplace_back(id, p.stem().string());
    }
    if (ec) {
      scan.skipped.push_back(images.string() + ": cannot be listed (" + ec.message() + ")");
      continue;
    }
    if (views.empty()) {
      scan.skipped.push_back(images.string() + ": no images");
      continue;
    }
    std::sort(views.begin(), views.end());
    std::set<int64_t> ids;
    std::vector<std::string> stems;
    for (const auto& v : views) {
      ids.insert(v.first);
      stems.push_back(v.second);
    }
    const std::string why = check_pairs((dir / "cams" / "pair.txt").string(), ids);
    if (!why.empty()) {
      scan.skipped.push_back(why);
      continue;
    }
    const int64_t size = static_cast<int64_t>(stems.size());
    scan.sequences.push_back(std::make_unique<FrameListSource>(
        label + "/" + scene, size, [dir, stems = std::move(stems)](int64_t i) {
          return load_blendedmvs_frame(dir, stems.at(static_cast<std::size_t>(i)));
        }));
  }
  return scan;
}

}  // namespace long3r::datasets

// ARKitScenes in the raw low-resolution layout that Spann3R trains on
// (spann3r/datasets/arkit.py):
//   <root>/raw/{Training|Validation}/<video>/
//     lowres_wide/<video>_<ts>.png               colour
//     lowres_depth/<video>_<ts>.png              uint16 millimetres, 0 invalid
//     lowres_wide_intrinsics/<video>_<ts>.pincam "w h fx fy cx cy"
//     lowres_wide.traj                           "ts ax ay az tx ty tz" per line
// ts has 3 decimals in the file names. A .traj line is the world-to-camera
// transform (Rodrigues rotation vector, translation), inverted here. Spann3R
// also rotates the world frame (an axis swap) and flips the camera's y and z
// axes twice, which cancels; only the world's orientation differs from the
// inverse used here, and the training losses do not depend on it.
#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <sstream>
#include <string>
#include <system_error>
#include <utility>
#include <vector>

#include "long3r/train/cv/datasets/dataset_io.hpp"

namespace long3r::datasets {

namespace {

namespace fs = std::filesystem;

// Milliseconds: the traj is keyed by timestamps rounded to 3 decimals.
int64_t to_ms(double ts) { return static_cast<int64_t>(std::llround(ts * 1000.0)); }

std::string format_ts(double ts) {
  char text[64];
  std::snprintf(text, sizeof(text), "%.3f", ts);
  return text;
}

// The camera-to-world poses of a .traj file by timestamp (ms); throws
// DatasetError naming the file and line.
std::map<int64_t, Eigen::Isometry3d> read_traj(const std::string& path) {
  std::map<int64_t, Eigen::Isometry3d> poses;
  const std::vector<std::string> lines = read_lines(path);
  for (std::size_t n = 0; n < lines.size(); ++n) {
    std::istringstream in(lines[n]);
    std::vector<double> v;
    std::string token;
    while (in >> token) {
      double x = 0.0;
      if (!parse_finite(token, &x)) {
        throw DatasetError(path + ":" + std::to_string(n + 1) + ": \"" + token +
                           "\" is not a finite number");
      }
      v.push_back(x);
    }
    if (v.size() != 7) {
      throw DatasetError(path + ":" + std::to_string(n + 1) + ": " + std::to_string(v.size()) +
                         " numbers, not 7 (ts ax ay az tx ty tz)");
    }
    const Eigen::Vector3d axis_angle(v[1], v[2], v[3]);
    const double angle = axis_angle.norm();
    Eigen::Isometry3d T_C_W = Eigen::Isometry3d::Identity();
    if (angle > 0.0) T_C_W.linear() = Eigen::AngleAxisd(angle, axis_angle / angle).matrix();
    T_C_W.translation() = Eigen::Vector3d(v[4], v[5], v[6]);
    poses[to_ms(v[0])] = T_C_W.inverse();
  }
  if (poses.empty()) throw DatasetError(path + ": no poses");
  return poses;
}

// The pose of the frame at `ms`: that timestamp's, else the nearest one less
// than 0.1 s away (as Spann3R looks them up); nullptr when none.
const Eigen::Isometry3d* find_pose(const std::map<int64_t, Eigen::Isometry3d>& poses, int64_t ms) {
  const auto exact = poses.find(ms);
  if (exact != poses.end()) return &exact->second;
  const Eigen::Isometry3d* best = nullptr;
  int64_t best_gap = 100;
  for (auto it = poses.lower_bound(ms - 99); it != poses.end() && it->first < ms + 100; ++it) {
    const int64_t gap = std::abs(it->first - ms);
    if (gap < best_gap) {
      best_gap = gap;
      best = &it->second;
    }
  }
  return best;
}

struct ArkitFrame {
  std::string ts;  // as in the file names
  double ts_s = 0.0;
  Eigen::Isometry3d T_W_C = Eigen::Isometry3d::Identity();
};

RawFrame load_arkitscenes_frame(const std::string& dir, const std::string& video,
                                const ArkitFrame& f) {
  const std::string stem = video + "_" + f.ts;
  const std::string color_path = dir + "/lowres_wide/" + stem + ".png";
  const std::string depth_path = dir + "/lowres_depth/" + stem + ".png";
  // The intrinsics of a frame may be stamped a millisecond off (Spann3R's
  // look-up order).
  std::string pincam;
  for (const std::string& ts : {f.ts, format_ts(f.ts_s - 0.001), format_ts(f.ts_s + 0.001)}) {
    const std::string p = dir + "/lowres_wide_intrinsics/" + video + "_" + ts + ".pincam";
    std::error_code ec;
    if (fs::exists(p, ec)) {
      pincam = p;
      break;
    }
  }
  if (pincam.empty()) {
    throw DatasetError(dir + "/lowres_wide_intrinsics/" + stem + ".pincam: missing");
  }
  const cv::Mat bgr = read_color(color_path);
  const cv::Mat depth = read_depth(depth_path, 1e-3);
  const Eigen::MatrixXd p = read_matrix_text(pincam, 1, 6);
  if (p(0, 0) != depth.cols || p(0, 1) != depth.rows) {
    std::ostringstream m;
    m << pincam << ": intrinsics of a " << p(0, 0) << " x " << p(0, 1) << " image for "
      << depth_path << " of " << depth.cols << " x " << depth.rows;
    throw DatasetError(m.str());
  }
  Eigen::Matrix3d k;
  k << p(0, 2), 0.0, p(0, 4), 0.0, p(0, 3), p(0, 5), 0.0, 0.0, 1.0;
  const PinholeIntrinsics intrinsics = intrinsics_from_k(k, depth.cols, depth.rows, pincam);
  if (cv::countNonZero(depth) == 0) throw DatasetError(depth_path + ": no valid depth");
  return make_frame(bgr, depth, intrinsics, f.T_W_C, stem);
}

}  // namespace

DatasetScan open_arkitscenes(const DatasetSource& source) {
  std::string folder;
  if (source.split == "train") {
    folder = "Training";
  } else if (source.split == "val" || source.split == "test") {
    folder = "Validation";
  } else {
    throw DatasetError(source.root + ": arkitscenes has no split \"" + source.split +
                       "\" (train, val)");
  }
  const std::string split_dir = source.root + "/raw/" + folder;
  std::error_code ec;
  if (!fs::is_directory(split_dir, ec)) {
    throw DatasetError(split_dir + ": missing (the " + source.split + " split's videos)");
  }
  std::vector<std::string> videos;
  for (const fs::directory_entry& e : fs::directory_iterator(split_dir, ec)) {
    std::error_code entry_ec;  // a dangling link is no video, not a listing error
    if (e.is_directory(entry_ec)) videos.push_back(e.path().filename().string());
  }
  if (ec) throw DatasetError(split_dir + ": cannot be listed (" + ec.message() + ")");
  std::sort(videos.begin(), videos.end());

  const std::string& prefix = source.label();
  DatasetScan scan;
  for (const std::string& video : videos) {
    const std::string dir = split_dir + "/" + video;
    const std::string depth_dir = dir + "/lowres_depth";
    try {
      for (const char* sub : {"/lowres_wide", "/lowres_depth", "/lowres_wide_intrinsics"}) {
        if (!fs::is_directory(dir + sub, ec)) throw DatasetError(dir + sub + ": missing");
      }
      const std::map<int64_t, Eigen::Isometry3d> poses = read_traj(dir + "/lowres_wide.traj");
      // The frames are the depth images "<video>_<ts>.png", in time order.
      std::vector<ArkitFrame> frames;
      for (const fs::directory_entry& e : fs::directory_iterator(depth_dir, ec)) {
        const std::string file = e.path().filename().string();
        if (file.size() <= video.size() + 5 ||
            file.compare(0, video.size() + 1, video + "_") != 0 ||
            file.compare(file.size() - 4, 4, ".png") != 0) {
          continue;
        }
        ArkitFrame f;
        f.ts = file.substr(video.size() + 1, file.size() - video.size() - 5);
        if (!parse_finite(f.ts, &f.ts_s)) continue;
        const Eigen::Isometry3d* pose = find_pose(poses, to_ms(f.ts_s));
        // Never readable: Spann3R draws another sample at such a frame.
        if (pose == nullptr) continue;
        f.T_W_C = *pose;
        frames.push_back(std::move(f));
      }
      if (ec) throw DatasetError(depth_dir + ": cannot be listed (" + ec.message() + ")");
      if (frames.empty()) {
        throw DatasetError(depth_dir + ": no <video>_<ts>.png depth images with a pose in " + dir +
                           "/lowres_wide.traj");
      }
      std::stable_sort(frames.begin(), frames.end(),
                       [](const ArkitFrame& a, const ArkitFrame& b) { return a.ts_s < b.ts_s; });
      const int64_t size = static_cast<int64_t>(frames.size());
      scan.sequences.push_back(std::make_unique<FrameListSource>(
          prefix + "/" + video, size, [dir, video, frames = std::move(frames)](int64_t i) {
            if (i < 0 || i >= static_cast<int64_t>(frames.size())) {
              throw std::out_of_range(dir + ": no frame " + std::to_string(i));
            }
            return load_arkitscenes_frame(dir, video, frames[static_cast<std::size_t>(i)]);
          }));
    } catch (const DatasetError& e) {
      scan.skipped.push_back(e.what());
    }
  }
  return scan;
}

}  // namespace long3r::datasets

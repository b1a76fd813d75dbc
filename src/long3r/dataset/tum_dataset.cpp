#include "long3r/dataset/tum_dataset.hpp"

#include <opencv2/imgcodecs.hpp>

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>
#include <cstdarg>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>
#include <stdexcept>
#include <tuple>

#include "long3r/io/atomic_file.hpp"
#include "long3r/io/data_lines.hpp"

namespace long3r {

namespace fs = std::filesystem;

namespace {

// printf onto the end of *out (file text is built in memory, then written at once).
__attribute__((format(printf, 2, 3))) void append_printf(std::string* out, const char* format,
                                                         ...) {
  va_list args, again;
  va_start(args, format);
  va_copy(again, args);
  const int n = std::vsnprintf(nullptr, 0, format, args);
  va_end(args);
  if (n > 0) {
    const size_t old = out->size();
    out->resize(old + static_cast<size_t>(n) + 1);
    std::vsnprintf(out->data() + old, static_cast<size_t>(n) + 1, format, again);
    out->resize(old + static_cast<size_t>(n));
  }
  va_end(again);
}

[[noreturn]] void bad_line(const std::string& path, int number, const std::string& what) {
  throw std::runtime_error(path + ":" + std::to_string(number) + ": " + what);
}

std::string join(const std::string& root, const std::string& rel) {
  fs::path p(rel);
  if (p.is_absolute()) return p.string();
  return (fs::path(root) / p).string();
}

}  // namespace

std::vector<Eigen::Vector3d> PoseTrajectory::positions() const {
  std::vector<Eigen::Vector3d> out;
  out.reserve(poses.size());
  for (const auto& p : poses) out.push_back(p.translation());
  return out;
}

namespace {

// "tx ty tz qx qy qz qw" from `ss`; the quaternion is normalised.
// `layout` names the whole line for error messages.
Eigen::Isometry3d parse_pose(std::istringstream& ss, const std::string& path, int number,
                             const std::string& layout) {
  double v[7];
  for (double& x : v) {
    if (!(ss >> x)) bad_line(path, number, "expected " + layout);
  }
  std::string extra;
  if (ss >> extra) bad_line(path, number, "more values than " + layout);
  Eigen::Quaterniond q(v[6], v[3], v[4], v[5]);
  const double norm = q.norm();
  if (!(norm > 1e-9) || !std::isfinite(norm)) bad_line(path, number, "invalid quaternion");
  q.coeffs() /= norm;
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  pose.linear() = q.toRotationMatrix();
  pose.translation() = Eigen::Vector3d(v[0], v[1], v[2]);
  return pose;
}

void append_pose(std::string* text, const Eigen::Isometry3d& p) {
  Eigen::Quaterniond q(p.rotation());
  q.normalize();
  // A fixed sign (qw >= 0) makes the text a function of the rotation alone.
  if (q.w() < 0.0) q.coeffs() = -q.coeffs();
  const Eigen::Vector3d t = p.translation();
  append_printf(text, "%.9f %.9f %.9f %.9f %.9f %.9f %.9f\n", t.x(), t.y(), t.z(), q.x(), q.y(),
                q.z(), q.w());
}

}  // namespace

PoseTrajectory read_tum_trajectory(const std::string& path) {
  PoseTrajectory traj;
  for (const auto& [number, line] : data_lines(path)) {
    std::istringstream ss(line);
    double stamp = 0.0;
    const std::string layout = "8 numbers 't tx ty tz qx qy qz qw'";
    if (!(ss >> stamp)) bad_line(path, number, "expected " + layout);
    traj.poses.push_back(parse_pose(ss, path, number, layout));
    traj.stamps.push_back(stamp);
  }
  return traj;
}

void write_tum_trajectory(const std::string& path, const PoseTrajectory& trajectory,
                          const std::string& header_comment) {
  if (trajectory.stamps.size() != trajectory.poses.size()) {
    throw std::invalid_argument("write_tum_trajectory: stamps and poses differ in size");
  }
  std::string text;
  if (!header_comment.empty()) text += "# " + header_comment + "\n";
  text += "# timestamp tx ty tz qx qy qz qw\n";
  for (size_t i = 0; i < trajectory.size(); ++i) {
    append_printf(&text, "%.6f ", trajectory.stamps[i]);
    append_pose(&text, trajectory.poses[i]);
  }
  write_file_atomically(path, text);
}

Eigen::Isometry3d read_pose_file(const std::string& path) {
  const auto lines = data_lines(path);
  if (lines.size() != 1) throw std::runtime_error(path + ": expected one pose line");
  std::istringstream ss(lines.front().second);
  return parse_pose(ss, path, lines.front().first, "7 numbers 'tx ty tz qx qy qz qw'");
}

void write_pose_file(const std::string& path, const Eigen::Isometry3d& pose,
                     const std::string& header_comment) {
  std::string text;
  if (!header_comment.empty()) text += "# " + header_comment + "\n";
  text += "# tx ty tz qx qy qz qw\n";
  append_pose(&text, pose);
  write_file_atomically(path, text);
}

namespace {

struct DistortionModel {
  const char* name;
  int count;
};
// ROS CameraInfo's models (sensor_msgs/distortion_models.h) that OpenCV implements.
constexpr DistortionModel kDistortionModels[] = {
    {"plumb_bob", 5}, {"rational_polynomial", 8}, {"equidistant", 4}};

}  // namespace

int distortion_coefficient_count(const std::string& model) {
  if (model.empty()) return 0;
  for (const auto& m : kDistortionModels) {
    if (model == m.name) return m.count;
  }
  throw std::invalid_argument("unknown distortion model '" + model +
                              "' (plumb_bob | rational_polynomial | equidistant)");
}

bool CameraCalibration::distorted() const {
  return std::any_of(distortion.begin(), distortion.end(), [](double d) { return d != 0.0; });
}

CameraCalibration read_camera_calibration(const std::string& path) {
  const auto lines = data_lines(path);
  if (lines.empty()) throw std::runtime_error(path + ": no calibration line");
  const auto& [number, line] = lines.front();
  std::istringstream ss(line);
  CameraCalibration c;
  PinholeIntrinsics& k = c.intrinsics;
  if (!(ss >> k.fx >> k.fy >> k.cx >> k.cy)) bad_line(path, number, "expected 'fx fy cx cy'");
  double w = 0, h = 0;
  if (ss >> w) {
    if (!(ss >> h)) bad_line(path, number, "width without height");
    if (w < 1 || h < 1 || w != std::floor(w) || h != std::floor(h)) {
      bad_line(path, number, "bad width/height");
    }
    k.width = static_cast<int>(w);
    k.height = static_cast<int>(h);
    if (ss >> c.distortion_model) {
      int n = 0;
      try {
        n = distortion_coefficient_count(c.distortion_model);
      } catch (const std::invalid_argument& e) {
        bad_line(path, number, e.what());
      }
      c.distortion.resize(n);
      for (double& d : c.distortion) {
        if (!(ss >> d) || !std::isfinite(d)) {
          bad_line(path, number,
                   c.distortion_model + " needs " + std::to_string(n) + " finite coefficients");
        }
      }
      std::string extra;
      if (ss >> extra) bad_line(path, number, "values after the distortion coefficients");
    }
  }
  if (!k.valid()) bad_line(path, number, "focal lengths must be positive");
  return c;
}

void write_camera_calibration(const std::string& path, const CameraCalibration& c) {
  const PinholeIntrinsics& k = c.intrinsics;
  if (static_cast<int>(c.distortion.size()) != distortion_coefficient_count(c.distortion_model)) {
    throw std::invalid_argument("write_camera_calibration: " + c.distortion_model + " takes " +
                                std::to_string(distortion_coefficient_count(c.distortion_model)) +
                                " coefficients, got " + std::to_string(c.distortion.size()));
  }
  std::string text = "# pinhole intrinsics in pixels; pixel centres at integer coordinates\n";
  if (c.distortion_model.empty()) {
    text += "# fx fy cx cy width height\n";
  } else {
    text += "# fx fy cx cy width height distortion_model D (as in sensor_msgs/CameraInfo)\n";
  }
  append_printf(&text, "%.9g %.9g %.9g %.9g %d %d", k.fx, k.fy, k.cx, k.cy, k.width, k.height);
  if (!c.distortion_model.empty()) {
    text += " " + c.distortion_model;
    // Shortest text that reads back bit for bit (the render used exactly these).
    for (double d : c.distortion) {
      char buf[32];
      const auto end = std::to_chars(buf, buf + sizeof(buf), d).ptr;
      text += " " + std::string(buf, end);
    }
  }
  text += "\n";
  write_file_atomically(path, text);
}

PinholeIntrinsics read_calibration_file(const std::string& path) {
  const CameraCalibration c = read_camera_calibration(path);
  if (c.distorted()) {
    throw std::runtime_error(path + ": has " + c.distortion_model +
                             " lens distortion; read_camera_calibration reads it");
  }
  return c.intrinsics;
}

void write_calibration_file(const std::string& path, const PinholeIntrinsics& k) {
  write_camera_calibration(path, CameraCalibration{k, "", {}});
}

std::vector<TimestampedPath> read_tum_file_list(const std::string& path) {
  std::vector<TimestampedPath> out;
  for (const auto& [number, line] : data_lines(path)) {
    std::istringstream ss(line);
    TimestampedPath e;
    if (!(ss >> e.stamp >> e.path)) bad_line(path, number, "expected 'timestamp path'");
    out.push_back(e);
  }
  return out;
}

std::vector<std::pair<int, int>> associate_timestamps(const std::vector<double>& a,
                                                      const std::vector<double>& b, double max_diff,
                                                      double offset) {
  // Candidate pairs via a window search over b sorted by time.
  std::vector<int> b_order(b.size());
  for (size_t j = 0; j < b.size(); ++j) b_order[j] = static_cast<int>(j);
  std::stable_sort(b_order.begin(), b_order.end(), [&](int x, int y) { return b[x] < b[y]; });
  std::vector<double> b_sorted(b.size());
  for (size_t j = 0; j < b.size(); ++j) b_sorted[j] = b[b_order[j]] + offset;

  std::vector<std::tuple<double, double, double, int, int>> cand;  // diff, a, b, ia, ib
  for (size_t i = 0; i < a.size(); ++i) {
    auto lo = std::lower_bound(b_sorted.begin(), b_sorted.end(), a[i] - max_diff);
    for (auto it = lo; it != b_sorted.end() && *it <= a[i] + max_diff; ++it) {
      const double diff = std::abs(a[i] - *it);
      if (diff < max_diff) {
        const int jb = b_order[it - b_sorted.begin()];
        cand.emplace_back(diff, a[i], b[jb], static_cast<int>(i), jb);
      }
    }
  }
  std::sort(cand.begin(), cand.end());
  std::vector<char> used_a(a.size(), 0), used_b(b.size(), 0);
  std::vector<std::pair<int, int>> matches;
  for (const auto& c : cand) {
    const int ia = std::get<3>(c), ib = std::get<4>(c);
    if (used_a[ia] || used_b[ib]) continue;
    used_a[ia] = used_b[ib] = 1;
    matches.emplace_back(ia, ib);
  }
  std::sort(matches.begin(), matches.end(), [&](const auto& x, const auto& y) {
    return std::make_pair(a[x.first], b[x.second]) < std::make_pair(a[y.first], b[y.second]);
  });
  return matches;
}

TumDataset TumDataset::open(const std::string& root, const TumDatasetOptions& options) {
  TumDataset ds;
  ds.root_ = root;
  ds.options_ = options;
  const fs::path r(root);
  if (!fs::is_directory(r)) throw std::runtime_error("not a directory: " + root);

  const auto rgb = read_tum_file_list((r / "rgb.txt").string());
  std::vector<TimestampedPath> depth;
  if (fs::exists(r / "depth.txt")) depth = read_tum_file_list((r / "depth.txt").string());
  if (fs::exists(r / "groundtruth.txt")) {
    ds.ground_truth_ = read_tum_trajectory((r / "groundtruth.txt").string());
  }
  if (fs::exists(r / "calibration.txt")) {
    const std::string path = (r / "calibration.txt").string();
    ds.camera_ = read_camera_calibration(path);
    if (ds.camera_->distorted() && !options.allow_distortion) {
      throw std::runtime_error(path + ": has " + ds.camera_->distortion_model +
                               " lens distortion, which this reader's user does not model "
                               "(TumDatasetOptions::allow_distortion)");
    }
    ds.calibration_ = ds.camera_->intrinsics;
  }

  std::vector<double> rgb_t, depth_t;
  for (const auto& e : rgb) rgb_t.push_back(e.stamp);
  for (const auto& e : depth) depth_t.push_back(e.stamp);
  std::vector<int> depth_of(rgb.size(), -1);
  for (const auto& [i, j] : associate_timestamps(rgb_t, depth_t, options.max_diff)) {
    depth_of[i] = j;
  }

  // Nearest ground-truth stamp (first of equals) within max_diff.
  const auto& gt = ds.ground_truth_;
  std::vector<int> gt_order(gt.size());
  for (size_t j = 0; j < gt.size(); ++j) gt_order[j] = static_cast<int>(j);
  std::stable_sort(gt_order.begin(), gt_order.end(),
                   [&](int x, int y) { return gt.stamps[x] < gt.stamps[y]; });
  auto nearest_gt = [&](double t) -> int {
    if (gt_order.empty()) return -1;
    auto it = std::lower_bound(gt_order.begin(), gt_order.end(), t,
                               [&](int j, double v) { return gt.stamps[j] < v; });
    const long pos = it - gt_order.begin();
    int best = -1;
    double best_d = std::numeric_limits<double>::infinity();
    for (long c : {pos - 1, pos}) {
      if (c < 0 || c >= static_cast<long>(gt_order.size())) continue;
      const double d = std::abs(gt.stamps[gt_order[c]] - t);
      if (d < best_d) {
        best_d = d;
        best = gt_order[c];
      }
    }
    return best_d <= options.max_diff ? best : -1;
  };

  for (size_t i = 0; i < rgb.size(); ++i) {
    TumFrame f;
    f.stamp = rgb[i].stamp;
    f.rgb_path = join(root, rgb[i].path);
    if (depth_of[i] >= 0) {
      f.depth_path = join(root, depth[depth_of[i]].path);
      f.depth_stamp = depth[depth_of[i]].stamp;
    }
    const int g = nearest_gt(f.stamp);
    if (g >= 0) {
      f.pose = gt.poses[g];
      f.pose_stamp = gt.stamps[g];
    }
    if (options.require_depth && f.depth_path.empty()) continue;
    if (options.require_pose && !f.pose) continue;
    ds.frames_.push_back(std::move(f));
  }
  return ds;
}

PoseTrajectory TumDataset::frame_trajectory() const {
  PoseTrajectory t;
  for (const auto& f : frames_) {
    if (!f.pose) continue;
    t.stamps.push_back(f.stamp);
    t.poses.push_back(*f.pose);
  }
  return t;
}

cv::Mat TumDataset::load_rgb(size_t i) const {
  const std::string& p = frame(i).rgb_path;
  cv::Mat img = cv::imread(p, cv::IMREAD_COLOR);
  if (img.empty()) throw std::runtime_error("cannot read image " + p);
  return img;
}

cv::Mat TumDataset::load_depth(size_t i) const {
  const std::string& p = frame(i).depth_path;
  if (p.empty()) throw std::runtime_error("frame " + std::to_string(i) + " has no depth");
  cv::Mat raw = cv::imread(p, cv::IMREAD_ANYDEPTH);
  if (raw.empty()) throw std::runtime_error("cannot read depth " + p);
  if (raw.channels() != 1) throw std::runtime_error("depth image is not single-channel: " + p);
  cv::Mat depth;
  raw.convertTo(depth, CV_32F, 1.0 / options_.depth_factor);
  return depth;
}

bool natural_less(const std::string& a, const std::string& b) {
  size_t i = 0, j = 0;
  while (i < a.size() && j < b.size()) {
    const bool da = std::isdigit(static_cast<unsigned char>(a[i]));
    const bool db = std::isdigit(static_cast<unsigned char>(b[j]));
    if (da && db) {
      size_t ie = i, je = j;
      while (ie < a.size() && std::isdigit(static_cast<unsigned char>(a[ie]))) ++ie;
      while (je < b.size() && std::isdigit(static_cast<unsigned char>(b[je]))) ++je;
      // Compare by value without overflow: strip leading zeros, then length, then digits.
      size_t is = i, js = j;
      while (is + 1 < ie && a[is] == '0') ++is;
      while (js + 1 < je && b[js] == '0') ++js;
      if (ie - is != je - js) return ie - is < je - js;
      const int c = a.compare(is, ie - is, b, js, je - js);
      if (c != 0) return c < 0;
      if (ie - i != je - j) return ie - i < je - j;  // fewer leading zeros first
      i = ie;
      j = je;
    } else {
      if (a[i] != b[j]) return static_cast<unsigned char>(a[i]) < static_cast<unsigned char>(b[j]);
      ++i;
      ++j;
    }
  }
  return a.size() - i < b.size() - j;
}

ImageFolder ImageFolder::open(const std::string& dir) {
  if (!fs::is_directory(dir)) throw std::runtime_error("not a directory: " + dir);
  static const char* kExt[] = {".png",  ".jpg", ".jpeg", ".bmp", ".tif",
                               ".tiff", ".ppm", ".pgm",  ".webp"};
  ImageFolder f;
  std::vector<std::string> names;
  for (const auto& e : fs::directory_iterator(dir)) {
    if (!e.is_regular_file()) continue;
    std::string ext = e.path().extension().string();
    std::transform(ext.begin(), ext.end(), ext.begin(),
                   [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
    if (std::find(std::begin(kExt), std::end(kExt), ext) == std::end(kExt)) continue;
    names.push_back(e.path().filename().string());
  }
  std::sort(names.begin(), names.end(), natural_less);
  for (const auto& n : names) f.paths_.push_back((fs::path(dir) / n).string());
  return f;
}

cv::Mat ImageFolder::load(size_t i) const {
  cv::Mat img = cv::imread(path(i), cv::IMREAD_COLOR);
  if (img.empty()) throw std::runtime_error("cannot read image " + path(i));
  return img;
}

}  // namespace long3r

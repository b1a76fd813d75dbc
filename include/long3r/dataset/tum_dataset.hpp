// Readers and writers for the TUM RGB-D dataset layout, and a plain
// folder-of-images reader.
//
// TUM layout (https://cvg.cit.tum.de/data/datasets/rgbd-dataset/file_formats):
//   rgb.txt, depth.txt      "timestamp path" per line, '#' comments
//   rgb/<t>.png             8-bit colour
//   depth/<t>.png           16-bit depth, metres = value / depth_factor (5000), 0 = none
//   groundtruth.txt         "timestamp tx ty tz qx qy qz qw": pose T_W_C of the
//                           camera optical frame (x right, y down, z forward)
//                           in the world frame
//   calibration.txt         (this project's addition; optional) one line
//                           "fx fy cx cy [width height [model d1 .. dn]]" after
//                           '#' comments; model and D as in ROS's CameraInfo
//                           (below), e.g. "... 640 480 plumb_bob k1 k2 p1 p2 k3"
//
// Frames are the rgb.txt entries. Depth images are matched to them one-to-one
// like TUM's associate.py (closest pairs first, |dt| < max_diff); ground truth
// is the nearest groundtruth.txt pose with |dt| <= max_diff (not interpolated).
#pragma once

#include <Eigen/Geometry>
#include <opencv2/core.hpp>

#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "long3r/geometry/pinhole_intrinsics.hpp"

namespace long3r {

// Timestamped camera poses T_W_C (one trajectory).
struct PoseTrajectory {
  std::vector<double> stamps;
  std::vector<Eigen::Isometry3d> poses;
  size_t size() const { return stamps.size(); }
  std::vector<Eigen::Vector3d> positions() const;
};

// TUM trajectory text: "t tx ty tz qx qy qz qw" per line; '#' comments and blank
// lines skipped; commas also accepted as separators. Quaternions are
// normalised. Throws std::runtime_error on an unreadable file or bad line.
PoseTrajectory read_tum_trajectory(const std::string& path);
void write_tum_trajectory(const std::string& path, const PoseTrajectory& trajectory,
                          const std::string& header_comment = "");

// A camera's calibration as calibration.txt holds it: pinhole intrinsics of
// the (distorted) image and, optionally, its lens distortion named as ROS's
// CameraInfo names it.
struct CameraCalibration {
  PinholeIntrinsics intrinsics;
  // "" (none), "plumb_bob" (k1 k2 p1 p2 k3: OpenCV's order), "rational_polynomial"
  // (k1 k2 p1 p2 k3 k4 k5 k6) or "equidistant" (k1 k2 k3 k4).
  std::string distortion_model;
  std::vector<double> distortion;  // D: distortion_coefficient_count(model) values
  bool distorted() const;          // a model with a nonzero coefficient
};
// Number of coefficients of a distortion model ("" has 0). Throws
// std::invalid_argument for an unknown name.
int distortion_coefficient_count(const std::string& model);

// calibration.txt: see above. Throws std::runtime_error. Without a model
// the file is the one-line "fx fy cx cy width height" of earlier versions.
CameraCalibration read_camera_calibration(const std::string& path);
void write_camera_calibration(const std::string& path, const CameraCalibration& calibration);
// Intrinsics only; a file with lens distortion is refused (std::runtime_error)
// rather than read as a pinhole camera.
PinholeIntrinsics read_calibration_file(const std::string& path);
void write_calibration_file(const std::string& path, const PinholeIntrinsics& intrinsics);

// One pose "tx ty tz qx qy qz qw" (a TUM trajectory line without its stamp)
// after '#' comments, e.g. a fixed mount. Throws std::runtime_error.
Eigen::Isometry3d read_pose_file(const std::string& path);
void write_pose_file(const std::string& path, const Eigen::Isometry3d& pose,
                     const std::string& header_comment = "");

struct TimestampedPath {
  double stamp = 0.0;
  std::string path;  // as written in the list (relative to the dataset root)
};
// rgb.txt / depth.txt. Throws std::runtime_error.
std::vector<TimestampedPath> read_tum_file_list(const std::string& path);

// TUM associate.py: all pairs with |a_i - (b_j + offset)| < max_diff, taken
// closest first (ties by a, then b), each index used once; sorted by a.
std::vector<std::pair<int, int>> associate_timestamps(const std::vector<double>& a,
                                                      const std::vector<double>& b, double max_diff,
                                                      double offset = 0.0);

struct TumDatasetOptions {
  double max_diff = 0.02;        // seconds, for depth and ground truth
  double depth_factor = 5000.0;  // depth PNG value per metre
  bool require_depth = false;    // drop frames without a depth match
  bool require_pose = false;     // drop frames without a ground-truth match
  // A calibration.txt with lens distortion is refused unless the caller says
  // it handles distortion (camera()), so that no tool takes it for a pinhole.
  bool allow_distortion = false;
};

struct TumFrame {
  double stamp = 0.0;      // rgb timestamp
  std::string rgb_path;    // absolute (root joined)
  std::string depth_path;  // empty when no depth matched
  double depth_stamp = 0.0;
  std::optional<Eigen::Isometry3d> pose;  // T_W_C, when ground truth matched
  double pose_stamp = 0.0;
};

class TumDataset {
 public:
  // Reads the lists in `root` (rgb.txt required; the others optional).
  // Throws std::runtime_error.
  static TumDataset open(const std::string& root, const TumDatasetOptions& options = {});

  const std::string& root() const { return root_; }
  size_t size() const { return frames_.size(); }
  const TumFrame& frame(size_t i) const { return frames_.at(i); }
  const std::vector<TumFrame>& frames() const { return frames_; }
  const std::optional<PinholeIntrinsics>& calibration() const { return calibration_; }
  // The whole calibration.txt, distortion included.
  const std::optional<CameraCalibration>& camera() const { return camera_; }
  // All of groundtruth.txt (empty without one).
  const PoseTrajectory& ground_truth() const { return ground_truth_; }
  // Ground truth of the frames that have one, at the rgb timestamps.
  PoseTrajectory frame_trajectory() const;

  cv::Mat load_rgb(size_t i) const;    // CV_8UC3, OpenCV BGR order; throws if unreadable
  cv::Mat load_depth(size_t i) const;  // CV_32FC1 metres, 0 = no depth; throws if none

 private:
  std::string root_;
  TumDatasetOptions options_;
  std::vector<TumFrame> frames_;
  std::optional<PinholeIntrinsics> calibration_;
  std::optional<CameraCalibration> camera_;
  PoseTrajectory ground_truth_;
};

// Images (png, jpg, jpeg, bmp, tif, tiff, ppm, pgm, webp; any case) directly
// inside a folder, in natural name order (digit runs compare by value:
// "2.png" < "10.png").
class ImageFolder {
 public:
  static ImageFolder open(const std::string& dir);  // throws std::runtime_error
  size_t size() const { return paths_.size(); }
  const std::string& path(size_t i) const { return paths_.at(i); }
  const std::vector<std::string>& paths() const { return paths_; }
  cv::Mat load(size_t i) const;  // CV_8UC3 BGR; throws if unreadable

 private:
  std::vector<std::string> paths_;
};

// Natural order used by ImageFolder.
bool natural_less(const std::string& a, const std::string& b);

}  // namespace long3r

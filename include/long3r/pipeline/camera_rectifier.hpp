// A camera's calibration as ROS's sensor_msgs/CameraInfo describes it (REP
// 104), without ROS: every field validated, distorted images rectified
// before the model, and the intrinsics of the image the model then sees.
//
// The node fills a CameraModel from camera_info, long3r_reconstruct from a
// dataset's calibration.txt; both go through the one CameraRectifier, so the
// command-line tool accepts the cameras the node accepts. Rectification is
// OpenCV's (plumb_bob and rational_polynomial through
// cv::initUndistortRectifyMap, equidistant through cv::fisheye), with the
// maps built once per calibration at the binned resolution and cut to the ROI,
// as image_geometry does. Raw images (image_is_rectified false) with non-zero
// distortion are rectified with K, D, R and P; rectified images are used as
// they are. Either way the intrinsics are P's, moved by the ROI and scaled by
// the binning: they describe the rectified image (for an undistorted raw
// camera P = K).
#pragma once

#include <opencv2/core/mat.hpp>
#include <opencv2/imgproc.hpp>

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "long3r/geometry/pinhole_intrinsics.hpp"

namespace long3r {

// The fields of sensor_msgs/CameraInfo, in its units and order.
struct CameraModel {
  std::int64_t width = 0, height = 0;  // of the full sensor
  std::string distortion_model;        // plumb_bob, rational_polynomial, equidistant
  std::vector<double> D;
  std::array<double, 9> K{};                  // row-major 3x3
  std::array<double, 9> R{};                  // row-major 3x3
  std::array<double, 12> P{};                 // row-major 3x4
  std::int64_t binning_x = 0, binning_y = 0;  // 0 reads as 1
  struct Roi {
    std::int64_t x_offset = 0, y_offset = 0, width = 0, height = 0;  // all 0: the whole sensor
    bool operator==(const Roi& o) const {
      return x_offset == o.x_offset && y_offset == o.y_offset && width == o.width &&
             height == o.height;
    }
  } roi;

  bool operator==(const CameraModel& o) const;
  bool operator!=(const CameraModel& o) const { return !(*this == o); }
};

// A pinhole camera of k.width x k.height with an optional lens distortion
// (a calibration.txt): K = P = the intrinsics, R the identity.
CameraModel camera_model(const PinholeIntrinsics& k, const std::string& distortion_model = "",
                         const std::vector<double>& D = {});

class CameraRectifier {
 public:
  // Why `camera` cannot calibrate images of image_width x image_height,
  // naming the field ("K[2] (cx) is nan", "D has 3 coefficients, plumb_bob
  // takes 5", "width 640 / binning 1 does not match the images' 320x240"),
  // or "" when it can.
  static std::string problem(const CameraModel& camera, int image_width, int image_height);

  // Adopts a calibration problem() accepted. Fields left empty by many
  // drivers are read as what they mean: P all zero as [K | 0], R all zero
  // as the identity, an empty distortion_model without coefficients as none.
  // Returns true when it differs from the current one (the maps are rebuilt).
  bool set(const CameraModel& camera, bool image_is_rectified);
  bool valid() const { return valid_; }

  // Whether prepare() remaps (a raw image with distortion).
  bool rectifies() const { return valid_ && rectifies_; }
  // The image the model should see: rectified when rectifies(), else `image`
  // itself. INTER_NEAREST for images whose values must not blend (depth);
  // float images are NaN where no raw pixel maps.
  cv::Mat prepare(const cv::Mat& image, int interpolation = cv::INTER_LINEAR) const;
  // Intrinsics of the prepared image, in its pixels.
  PinholeIntrinsics intrinsics() const;

  // One line for the log: model, intrinsics, rectification, binning / ROI.
  std::string describe() const;

 private:
  CameraModel camera_;  // as adopted (empty fields filled in)
  bool valid_ = false;
  bool rectifies_ = false;
  cv::Mat map1_, map2_;  // raw pixel of each rectified pixel (cv::remap's fixed-point pair)
};

}  // namespace long3r

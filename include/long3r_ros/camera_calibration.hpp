// The camera as camera_info describes it: every field validated, distorted
// images rectified before the model, and the intrinsics of the image the
// model then sees.
//
// Built on image_geometry's PinholeCameraModel (plumb_bob,
// rational_polynomial and equidistant distortion; binning and ROI; its
// rectification maps are computed once per calibration and reused). Raw
// images (image_is_rectified false) with non-zero distortion are rectified
// with K, D, R and P; rectified images are used as they are. Either way the
// intrinsics are P's (for the binned / ROI image), which describe the
// rectified image; for an undistorted raw camera P = K.
#pragma once

#include <image_geometry/pinhole_camera_model.h>
#include <sensor_msgs/CameraInfo.h>

#include <opencv2/core/mat.hpp>
#include <opencv2/imgproc.hpp>
#include <string>

#include "long3r/pipeline/pinhole_intrinsics.hpp"

namespace long3r_ros {

class CameraCalibration {
 public:
  // Why `info` cannot calibrate images of image_width x image_height,
  // naming the field ("K[2] (cx) is nan", "D has 3 coefficients, plumb_bob
  // takes 5", "width 640 / binning 1 does not match the images' 320x240"),
  // or "" when it can.
  static std::string problem(const sensor_msgs::CameraInfo& info, int image_width,
                             int image_height);

  // Adopts a calibration problem() accepted. Fields left empty by many
  // drivers are read as what they mean: P all zero as [K | 0], R all zero
  // as the identity, an empty distortion_model without coefficients as none.
  // Returns true when it differs from the current one (the maps are then
  // rebuilt at the next rectification).
  bool set(const sensor_msgs::CameraInfo& info, bool image_is_rectified);
  bool valid() const { return valid_; }

  // Whether prepare() remaps (a raw image with distortion).
  bool rectifies() const { return valid_ && rectifies_; }
  // The image the model should see: rectified when rectifies(), else `image`
  // itself. INTER_NEAREST for images whose values must not blend (depth).
  cv::Mat prepare(const cv::Mat& image, int interpolation = cv::INTER_LINEAR) const;
  // Intrinsics of the prepared image, in its pixels.
  long3r::PinholeIntrinsics intrinsics() const;

  // One line for the log: model, intrinsics, rectification, binning / ROI.
  std::string describe() const;

 private:
  image_geometry::PinholeCameraModel model_;
  sensor_msgs::CameraInfo info_;  // as adopted (empty fields filled in)
  bool valid_ = false;
  bool rectifies_ = false;
};

}  // namespace long3r_ros

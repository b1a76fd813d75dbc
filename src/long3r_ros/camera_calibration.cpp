#include "long3r_ros/camera_calibration.hpp"

#include <sensor_msgs/distortion_models.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <sstream>
#include <vector>

namespace long3r_ros {

namespace {

namespace dm = sensor_msgs::distortion_models;

template <class Array>
bool allZero(const Array& a) {
  return std::all_of(a.begin(), a.end(), [](double v) { return v == 0.0; });
}

// The fields drivers leave empty, read as what they mean.
sensor_msgs::CameraInfo normalized(sensor_msgs::CameraInfo info) {
  if (allZero(info.P)) {
    info.P = {info.K[0], info.K[1], info.K[2], 0.0,       info.K[3], info.K[4],
              info.K[5], 0.0,       info.K[6], info.K[7], info.K[8], 0.0};
  }
  if (allZero(info.R)) info.R = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  if (info.distortion_model.empty() && allZero(info.D)) {
    info.distortion_model = dm::PLUMB_BOB;
    info.D.assign(5, 0.0);
  }
  return info;
}

std::vector<std::size_t> coefficientCounts(const std::string& model) {
  if (model == dm::PLUMB_BOB) return {4, 5, 8};
  if (model == dm::RATIONAL_POLYNOMIAL) return {8, 12, 14};
  if (model == dm::EQUIDISTANT) return {4};
  return {};
}

std::string number(double v) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%g", v);
  return buf;
}

// The size of the images this calibration describes: ROI, then binning.
void imageSize(const sensor_msgs::CameraInfo& info, int* width, int* height) {
  const unsigned bx = std::max(1u, info.binning_x), by = std::max(1u, info.binning_y);
  const unsigned w = info.roi.width > 0 ? info.roi.width : info.width;
  const unsigned h = info.roi.height > 0 ? info.roi.height : info.height;
  *width = static_cast<int>(w / bx);
  *height = static_cast<int>(h / by);
}

}  // namespace

std::string CameraCalibration::problem(const sensor_msgs::CameraInfo& raw, int image_width,
                                       int image_height) {
  const sensor_msgs::CameraInfo info = normalized(raw);
  if (info.width == 0 || info.height == 0) {
    return "width x height is " + std::to_string(info.width) + "x" + std::to_string(info.height);
  }
  const char* k_names[9] = {"fx", "", "cx", "", "fy", "cy", "", "", ""};
  for (int i = 0; i < 9; ++i) {
    if (!std::isfinite(info.K[i])) {
      return "K[" + std::to_string(i) + "]" +
             (*k_names[i] ? std::string(" (") + k_names[i] + ")" : "") + " is " + number(info.K[i]);
    }
  }
  if (!(info.K[0] > 0.0)) return "K[0] (fx) is " + number(info.K[0]) + ", not positive";
  if (!(info.K[4] > 0.0)) return "K[4] (fy) is " + number(info.K[4]) + ", not positive";
  if (!(info.K[2] >= 0.0 && info.K[2] < info.width)) {
    return "K[2] (cx) = " + number(info.K[2]) + " is outside the image (width " +
           std::to_string(info.width) + ")";
  }
  if (!(info.K[5] >= 0.0 && info.K[5] < info.height)) {
    return "K[5] (cy) = " + number(info.K[5]) + " is outside the image (height " +
           std::to_string(info.height) + ")";
  }
  const std::vector<std::size_t> counts = coefficientCounts(info.distortion_model);
  if (counts.empty()) {
    return "distortion_model '" + info.distortion_model +
           "' is not supported (plumb_bob, rational_polynomial, equidistant)";
  }
  if (std::find(counts.begin(), counts.end(), info.D.size()) == counts.end()) {
    std::string takes;
    for (std::size_t i = 0; i < counts.size(); ++i) {
      takes += (i == 0 ? "" : i + 1 == counts.size() ? " or " : ", ") + std::to_string(counts[i]);
    }
    return "D has " + std::to_string(info.D.size()) + " coefficients, " + info.distortion_model +
           " takes " + takes;
  }
  for (std::size_t i = 0; i < info.D.size(); ++i) {
    if (!std::isfinite(info.D[i])) return "D[" + std::to_string(i) + "] is " + number(info.D[i]);
  }
  for (int i = 0; i < 9; ++i) {
    if (!std::isfinite(info.R[i])) return "R[" + std::to_string(i) + "] is " + number(info.R[i]);
  }
  const cv::Matx33d R(info.R.data());
  if (cv::norm(R * R.t() - cv::Matx33d::eye(), cv::NORM_INF) > 1e-3 || cv::determinant(R) <= 0.0) {
    return "R is not a rotation";
  }
  for (int i = 0; i < 12; ++i) {
    if (!std::isfinite(info.P[i])) return "P[" + std::to_string(i) + "] is " + number(info.P[i]);
  }
  if (!(info.P[0] > 0.0)) return "P[0] (fx') is " + number(info.P[0]) + ", not positive";
  if (!(info.P[5] > 0.0)) return "P[5] (fy') is " + number(info.P[5]) + ", not positive";
  if (!(info.P[2] >= 0.0 && info.P[2] < info.width) ||
      !(info.P[6] >= 0.0 && info.P[6] < info.height)) {
    return "P's principal point (" + number(info.P[2]) + ", " + number(info.P[6]) +
           ") is outside the image";
  }
  if (info.roi.width > 0 || info.roi.height > 0) {
    if (info.roi.width == 0 || info.roi.height == 0 ||
        info.roi.x_offset + info.roi.width > info.width ||
        info.roi.y_offset + info.roi.height > info.height) {
      return "roi (" + std::to_string(info.roi.x_offset) + ", " +
             std::to_string(info.roi.y_offset) + ", " + std::to_string(info.roi.width) + "x" +
             std::to_string(info.roi.height) + ") does not lie inside the " +
             std::to_string(info.width) + "x" + std::to_string(info.height) + " sensor";
    }
  }
  int w = 0, h = 0;
  imageSize(info, &w, &h);
  if (w != image_width || h != image_height) {
    return "width x height " + std::to_string(info.width) + "x" + std::to_string(info.height) +
           (info.roi.width > 0 ? " with its roi" : "") +
           (std::max(1u, info.binning_x) > 1 || std::max(1u, info.binning_y) > 1
                ? " binned " + std::to_string(info.binning_x) + "x" + std::to_string(info.binning_y)
                : "") +
           " gives " + std::to_string(w) + "x" + std::to_string(h) + " images, but they are " +
           std::to_string(image_width) + "x" + std::to_string(image_height);
  }
  return "";
}

bool CameraCalibration::set(const sensor_msgs::CameraInfo& raw, bool image_is_rectified) {
  sensor_msgs::CameraInfo info = normalized(raw);
  info.header = std_msgs::Header();  // the stamp does not make a calibration differ
  const bool rectifies = !image_is_rectified && !allZero(info.D);
  const bool changed = !valid_ || rectifies != rectifies_ || !(info == info_);
  info_ = info;
  model_.fromCameraInfo(info_);
  rectifies_ = rectifies;
  valid_ = true;
  return changed;
}

cv::Mat CameraCalibration::prepare(const cv::Mat& image, int interpolation) const {
  if (!rectifies()) return image;
  cv::Mat rectified;
  model_.rectifyImage(image, rectified, interpolation);
  return rectified;
}

long3r::PinholeIntrinsics CameraCalibration::intrinsics() const {
  long3r::PinholeIntrinsics k;
  if (!valid_) return k;
  k.fx = model_.fx();
  k.fy = model_.fy();
  k.cx = model_.cx();
  k.cy = model_.cy();
  const cv::Size size = model_.reducedResolution();
  k.width = size.width;
  k.height = size.height;
  return k;
}

std::string CameraCalibration::describe() const {
  if (!valid_) return "no calibration";
  const long3r::PinholeIntrinsics k = intrinsics();
  std::ostringstream s;
  s << "fx " << k.fx << ", fy " << k.fy << ", cx " << k.cx << ", cy " << k.cy << " at " << k.width
    << "x" << k.height << " (P), " << info_.distortion_model;
  if (rectifies_) {
    s << " distortion [";
    for (std::size_t i = 0; i < info_.D.size(); ++i) s << (i ? " " : "") << info_.D[i];
    s << "], images rectified by the node";
  } else {
    s << ", images used as they are";
  }
  if (std::max(1u, info_.binning_x) > 1 || std::max(1u, info_.binning_y) > 1) {
    s << ", binning " << info_.binning_x << "x" << info_.binning_y;
  }
  if (info_.roi.width > 0) {
    s << ", roi " << info_.roi.width << "x" << info_.roi.height << "+" << info_.roi.x_offset << "+"
      << info_.roi.y_offset;
  }
  return s.str();
}

}  // namespace long3r_ros

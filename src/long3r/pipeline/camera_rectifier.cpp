// Camera calibration and rectification; see camera_rectifier.hpp.
#include "long3r/pipeline/camera_rectifier.hpp"

#include <opencv2/calib3d.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <sstream>

namespace long3r {

namespace {

constexpr const char* kPlumbBob = "plumb_bob";
constexpr const char* kRationalPolynomial = "rational_polynomial";
constexpr const char* kEquidistant = "equidistant";

template <class Array>
bool all_zero(const Array& a) {
  return std::all_of(a.begin(), a.end(), [](double v) { return v == 0.0; });
}

// The fields drivers leave empty, read as what they mean.
CameraModel normalized(CameraModel c) {
  if (all_zero(c.P)) {
    c.P = {c.K[0], c.K[1], c.K[2], 0.0, c.K[3], c.K[4], c.K[5], 0.0, c.K[6], c.K[7], c.K[8], 0.0};
  }
  if (all_zero(c.R)) c.R = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  if (c.distortion_model.empty() && all_zero(c.D)) {
    c.distortion_model = kPlumbBob;
    c.D.assign(5, 0.0);
  }
  return c;
}

std::vector<std::size_t> coefficient_counts(const std::string& model) {
  if (model == kPlumbBob) return {4, 5, 8};
  if (model == kRationalPolynomial) return {8, 12, 14};
  if (model == kEquidistant) return {4};
  return {};
}

std::string short_text(double v) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%g", v);
  return buf;
}

std::int64_t binning(std::int64_t b) { return std::max<std::int64_t>(1, b); }

bool has_roi(const CameraModel& c) { return c.roi.width > 0 || c.roi.height > 0; }

// The size of the images this calibration describes: ROI, then binning.
void image_size(const CameraModel& c, std::int64_t* width, std::int64_t* height) {
  const std::int64_t w = c.roi.width > 0 ? c.roi.width : c.width;
  const std::int64_t h = c.roi.height > 0 ? c.roi.height : c.height;
  *width = w / binning(c.binning_x);
  *height = h / binning(c.binning_y);
}

// K and P at the binned resolution (the ROI not yet applied).
void binned(const CameraModel& c, cv::Matx33d* K, cv::Matx33d* P) {
  *K = cv::Matx33d(c.K.data());
  *P = cv::Matx33d(c.P[0], c.P[1], c.P[2], c.P[4], c.P[5], c.P[6], c.P[8], c.P[9], c.P[10]);
  const double sx = 1.0 / static_cast<double>(binning(c.binning_x));
  const double sy = 1.0 / static_cast<double>(binning(c.binning_y));
  for (cv::Matx33d* m : {K, P}) {
    (*m)(0, 0) *= sx;
    (*m)(0, 2) *= sx;
    (*m)(1, 1) *= sy;
    (*m)(1, 2) *= sy;
  }
}

}  // namespace

bool CameraModel::operator==(const CameraModel& o) const {
  return width == o.width && height == o.height && distortion_model == o.distortion_model &&
         D == o.D && K == o.K && R == o.R && P == o.P && binning_x == o.binning_x &&
         binning_y == o.binning_y && roi == o.roi;
}

CameraModel camera_model(const PinholeIntrinsics& k, const std::string& distortion_model,
                         const std::vector<double>& D) {
  CameraModel c;
  c.width = k.width;
  c.height = k.height;
  c.distortion_model = distortion_model;
  c.D = D;
  c.K = {k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0};
  c.R = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  c.P = {k.fx, 0.0, k.cx, 0.0, 0.0, k.fy, k.cy, 0.0, 0.0, 0.0, 1.0, 0.0};
  return c;
}

std::string CameraRectifier::problem(const CameraModel& raw, int image_width, int image_height) {
  const CameraModel c = normalized(raw);
  if (c.width <= 0 || c.height <= 0) {
    return "width x height is " + std::to_string(c.width) + "x" + std::to_string(c.height);
  }
  const char* k_names[9] = {"fx", "", "cx", "", "fy", "cy", "", "", ""};
  for (int i = 0; i < 9; ++i) {
    if (!std::isfinite(c.K[i])) {
      return "K[" + std::to_string(i) + "]" +
             (*k_names[i] ? std::string(" (") + k_names[i] + ")" : "") + " is " +
             short_text(c.K[i]);
    }
  }
  if (!(c.K[0] > 0.0)) return "K[0] (fx) is " + short_text(c.K[0]) + ", not positive";
  if (!(c.K[4] > 0.0)) return "K[4] (fy) is " + short_text(c.K[4]) + ", not positive";
  if (!(c.K[2] >= 0.0 && c.K[2] < c.width)) {
    return "K[2] (cx) = " + short_text(c.K[2]) + " is outside the image (width " +
           std::to_string(c.width) + ")";
  }
  if (!(c.K[5] >= 0.0 && c.K[5] < c.height)) {
    return "K[5] (cy) = " + short_text(c.K[5]) + " is outside the image (height " +
           std::to_string(c.height) + ")";
  }
  const std::vector<std::size_t> counts = coefficient_counts(c.distortion_model);
  if (counts.empty()) {
    return "distortion_model '" + c.distortion_model +
           "' is not supported (plumb_bob, rational_polynomial, equidistant)";
  }
  if (std::find(counts.begin(), counts.end(), c.D.size()) == counts.end()) {
    std::string takes;
    for (std::size_t i = 0; i < counts.size(); ++i) {
      takes += (i == 0 ? "" : i + 1 == counts.size() ? " or " : ", ") + std::to_string(counts[i]);
    }
    return "D has " + std::to_string(c.D.size()) + " coefficients, " + c.distortion_model +
           " takes " + takes;
  }
  for (std::size_t i = 0; i < c.D.size(); ++i) {
    if (!std::isfinite(c.D[i])) return "D[" + std::to_string(i) + "] is " + short_text(c.D[i]);
  }
  for (int i = 0; i < 9; ++i) {
    if (!std::isfinite(c.R[i])) return "R[" + std::to_string(i) + "] is " + short_text(c.R[i]);
  }
  const cv::Matx33d R(c.R.data());
  if (cv::norm(R * R.t() - cv::Matx33d::eye(), cv::NORM_INF) > 1e-3 || cv::determinant(R) <= 0.0) {
    return "R is not a rotation";
  }
  for (int i = 0; i < 12; ++i) {
    if (!std::isfinite(c.P[i])) return "P[" + std::to_string(i) + "] is " + short_text(c.P[i]);
  }
  if (!(c.P[0] > 0.0)) return "P[0] (fx') is " + short_text(c.P[0]) + ", not positive";
  if (!(c.P[5] > 0.0)) return "P[5] (fy') is " + short_text(c.P[5]) + ", not positive";
  if (!(c.P[2] >= 0.0 && c.P[2] < c.width) || !(c.P[6] >= 0.0 && c.P[6] < c.height)) {
    return "P's principal point (" + short_text(c.P[2]) + ", " + short_text(c.P[6]) +
           ") is outside the image";
  }
  if (c.binning_x < 0 || c.binning_y < 0) {
    return "binning " + std::to_string(c.binning_x) + "x" + std::to_string(c.binning_y) +
           " is negative";
  }
  if (has_roi(c)) {
    if (c.roi.width <= 0 || c.roi.height <= 0 || c.roi.x_offset < 0 || c.roi.y_offset < 0 ||
        c.roi.x_offset + c.roi.width > c.width || c.roi.y_offset + c.roi.height > c.height) {
      return "roi (" + std::to_string(c.roi.x_offset) + ", " + std::to_string(c.roi.y_offset) +
             ", " + std::to_string(c.roi.width) + "x" + std::to_string(c.roi.height) +
             ") does not lie inside the " + std::to_string(c.width) + "x" +
             std::to_string(c.height) + " sensor";
    }
  }
  std::int64_t w = 0, h = 0;
  image_size(c, &w, &h);
  if (w != image_width || h != image_height) {
    return "width x height " + std::to_string(c.width) + "x" + std::to_string(c.height) +
           (c.roi.width > 0 ? " with its roi" : "") +
           (binning(c.binning_x) > 1 || binning(c.binning_y) > 1
                ? " binned " + std::to_string(c.binning_x) + "x" + std::to_string(c.binning_y)
                : "") +
           " gives " + std::to_string(w) + "x" + std::to_string(h) + " images, but they are " +
           std::to_string(image_width) + "x" + std::to_string(image_height);
  }
  return "";
}

bool CameraRectifier::set(const CameraModel& raw, bool image_is_rectified) {
  const CameraModel c = normalized(raw);
  const bool rectifies = !image_is_rectified && !all_zero(c.D);
  const bool changed = !valid_ || rectifies != rectifies_ || c != camera_;
  camera_ = c;
  rectifies_ = rectifies;
  valid_ = true;
  if (!changed) return false;
  map1_.release();
  map2_.release();
  if (rectifies_) {
    // Maps of the whole binned sensor, then cut to the ROI: a raw pixel's
    // place does not depend on which part of the sensor was read out.
    cv::Matx33d K, P;
    binned(c, &K, &P);
    const cv::Size full(static_cast<int>(c.width / binning(c.binning_x)),
                        static_cast<int>(c.height / binning(c.binning_y)));
    const cv::Matx33d R(c.R.data());
    cv::Mat full1, full2;
    if (c.distortion_model == kEquidistant) {
      cv::fisheye::initUndistortRectifyMap(K, c.D, R, P, full, CV_16SC2, full1, full2);
    } else {
      cv::initUndistortRectifyMap(K, c.D, R, P, full, CV_16SC2, full1, full2);
    }
    if (has_roi(c)) {
      const cv::Rect roi(static_cast<int>(c.roi.x_offset / binning(c.binning_x)),
                         static_cast<int>(c.roi.y_offset / binning(c.binning_y)),
                         static_cast<int>(c.roi.width / binning(c.binning_x)),
                         static_cast<int>(c.roi.height / binning(c.binning_y)));
      // map1 holds integer raw positions: moved into the ROI's pixels; map2
      // (the sub-pixel table index) stays.
      cv::subtract(full1(roi), cv::Scalar(roi.x, roi.y), map1_, cv::noArray(), CV_16SC2);
      map2_ = full2(roi).clone();
    } else {
      map1_ = full1;
      map2_ = full2;
    }
  }
  return true;
}

cv::Mat CameraRectifier::prepare(const cv::Mat& image, int interpolation) const {
  if (!rectifies()) return image;
  if (image.size() != map1_.size()) {
    throw std::invalid_argument("CameraRectifier: a " + std::to_string(image.cols) + "x" +
                                std::to_string(image.rows) + " image for a calibration of " +
                                std::to_string(map1_.cols) + "x" + std::to_string(map1_.rows));
  }
  cv::Mat rectified;
  const bool floating = image.depth() == CV_32F || image.depth() == CV_64F;
  cv::remap(image, rectified, map1_, map2_, interpolation, cv::BORDER_CONSTANT,
            cv::Scalar::all(floating ? std::numeric_limits<double>::quiet_NaN() : 0.0));
  return rectified;
}

PinholeIntrinsics CameraRectifier::intrinsics() const {
  PinholeIntrinsics k;
  if (!valid_) return k;
  const double bx = static_cast<double>(binning(camera_.binning_x));
  const double by = static_cast<double>(binning(camera_.binning_y));
  k.fx = camera_.P[0] / bx;
  k.fy = camera_.P[5] / by;
  k.cx = (camera_.P[2] - static_cast<double>(camera_.roi.x_offset)) / bx;
  k.cy = (camera_.P[6] - static_cast<double>(camera_.roi.y_offset)) / by;
  std::int64_t w = 0, h = 0;
  image_size(camera_, &w, &h);
  k.width = static_cast<int>(w);
  k.height = static_cast<int>(h);
  return k;
}

std::string CameraRectifier::describe() const {
  if (!valid_) return "no calibration";
  const PinholeIntrinsics k = intrinsics();
  std::ostringstream s;
  s << "fx " << k.fx << ", fy " << k.fy << ", cx " << k.cx << ", cy " << k.cy << " at " << k.width
    << "x" << k.height << " (P), " << camera_.distortion_model;
  if (rectifies_) {
    s << " distortion [";
    for (std::size_t i = 0; i < camera_.D.size(); ++i) s << (i ? " " : "") << camera_.D[i];
    s << "], images rectified";
  } else {
    s << ", images used as they are";
  }
  if (binning(camera_.binning_x) > 1 || binning(camera_.binning_y) > 1) {
    s << ", binning " << camera_.binning_x << "x" << camera_.binning_y;
  }
  if (camera_.roi.width > 0) {
    s << ", roi " << camera_.roi.width << "x" << camera_.roi.height << "+" << camera_.roi.x_offset
      << "+" << camera_.roi.y_offset;
  }
  return s.str();
}

}  // namespace long3r

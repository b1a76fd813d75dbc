#include "long3r/pipeline/intrinsics.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <vector>

namespace long3r {

const char* to_string(IntrinsicsSource source) {
  switch (source) {
    case IntrinsicsSource::kCalibration:
      return "calibration";
    case IntrinsicsSource::kEstimatedWeiszfeld:
      return "estimated_weiszfeld";
  }
  return "unknown";
}

PinholeIntrinsics scale_intrinsics(const PinholeIntrinsics& source,
                                   const PixelMapping& model_to_source, int model_width,
                                   int model_height) {
  if (!source.valid()) throw std::invalid_argument("scale_intrinsics: invalid source intrinsics");
  // u_src = fx X/Z + cx and u_src = a u_model + b give u_model = (fx/a) X/Z + (cx - b)/a.
  PinholeIntrinsics k;
  k.fx = source.fx / model_to_source.scale_x;
  k.fy = source.fy / model_to_source.scale_y;
  k.cx = (source.cx - model_to_source.offset_x) / model_to_source.scale_x;
  k.cy = (source.cy - model_to_source.offset_y) / model_to_source.scale_y;
  k.width = model_width;
  k.height = model_height;
  return k;
}

std::optional<double> estimate_focal_weiszfeld(const cv::Mat& pts3d, const cv::Mat& conf,
                                               const FocalEstimationOptions& options) {
  if (pts3d.type() != CV_32FC3) {
    throw std::invalid_argument("estimate_focal_weiszfeld: pts3d must be CV_32FC3");
  }
  if (!conf.empty() && (conf.type() != CV_32FC1 || conf.size() != pts3d.size())) {
    throw std::invalid_argument(
        "estimate_focal_weiszfeld: conf must be CV_32FC1 of the pts3d size");
  }
  const int h = pts3d.rows, w = pts3d.cols;
  const double cx = 0.5 * (w - 1), cy = 0.5 * (h - 1);

  // Centred pixels p and normalised rays q = (x, y) / z of the usable pixels.
  std::vector<Eigen::Vector2d> p, q;
  p.reserve(static_cast<size_t>(h) * w);
  q.reserve(static_cast<size_t>(h) * w);
  for (int v = 0; v < h; ++v) {
    const auto* row = pts3d.ptr<cv::Vec3f>(v);
    const float* crow = conf.empty() ? nullptr : conf.ptr<float>(v);
    for (int u = 0; u < w; ++u) {
      const double x = row[u][0], y = row[u][1], z = row[u][2];
      if (!std::isfinite(x) || !std::isfinite(y) || !std::isfinite(z) || !(z > 0.0)) continue;
      if (crow && !(crow[u] >= options.conf_threshold)) continue;
      p.emplace_back(u - cx, v - cy);
      q.emplace_back(x / z, y / z);
    }
  }
  if (static_cast<int>(p.size()) < std::max(1, options.min_points)) return std::nullopt;

  const size_t n = p.size();
  std::vector<double> dot_qp(n), dot_qq(n);
  double sum_qp = 0.0, sum_qq = 0.0;
  for (size_t i = 0; i < n; ++i) {
    dot_qp[i] = q[i].dot(p[i]);
    dot_qq[i] = q[i].squaredNorm();
    sum_qp += dot_qp[i];
    sum_qq += dot_qq[i];
  }
  if (!(sum_qq > 0.0)) return std::nullopt;  // every ray on the optical axis
  double focal = sum_qp / sum_qq;
  for (int it = 0; it < options.iterations; ++it) {
    double num = 0.0, den = 0.0;
    for (size_t i = 0; i < n; ++i) {
      const double wi = 1.0 / std::max((p[i] - focal * q[i]).norm(), 1e-8);
      num += wi * dot_qp[i];
      den += wi * dot_qq[i];
    }
    if (!(den > 0.0)) break;
    focal = num / den;
  }
  if (!std::isfinite(focal)) return std::nullopt;
  const double focal_base = std::max(h, w) / (2.0 * std::tan(M_PI / 6.0));
  return std::clamp(focal, options.min_focal_ratio * focal_base,
                    options.max_focal_ratio * focal_base);
}

std::optional<PinholeIntrinsics> estimate_intrinsics(const cv::Mat& pts3d, const cv::Mat& conf,
                                                     const FocalEstimationOptions& options) {
  const std::optional<double> focal = estimate_focal_weiszfeld(pts3d, conf, options);
  if (!focal) return std::nullopt;
  PinholeIntrinsics k;
  k.fx = k.fy = *focal;
  k.cx = 0.5 * (pts3d.cols - 1);
  k.cy = 0.5 * (pts3d.rows - 1);
  k.width = pts3d.cols;
  k.height = pts3d.rows;
  return k;
}

std::optional<ResolvedIntrinsics> resolve_intrinsics(
    const std::optional<PinholeIntrinsics>& calibration, const PreprocessedImage& frame0,
    const cv::Mat& frame0_pts3d, const cv::Mat& frame0_conf,
    const FocalEstimationOptions& options) {
  if (calibration) {
    const PinholeIntrinsics& c = *calibration;
    if ((c.width != 0 || c.height != 0) &&
        (c.width != frame0.source_width || c.height != frame0.source_height)) {
      throw std::invalid_argument("resolve_intrinsics: calibration is for " +
                                  std::to_string(c.width) + "x" + std::to_string(c.height) +
                                  " images, the input is " + std::to_string(frame0.source_width) +
                                  "x" + std::to_string(frame0.source_height));
    }
    return ResolvedIntrinsics{
        scale_intrinsics(c, frame0.model_to_source, frame0.width, frame0.height),
        IntrinsicsSource::kCalibration};
  }
  if (frame0_pts3d.cols != frame0.width || frame0_pts3d.rows != frame0.height) {
    throw std::invalid_argument("resolve_intrinsics: pointmap size differs from the model size");
  }
  const std::optional<PinholeIntrinsics> k =
      estimate_intrinsics(frame0_pts3d, frame0_conf, options);
  if (!k) return std::nullopt;
  return ResolvedIntrinsics{*k, IntrinsicsSource::kEstimatedWeiszfeld};
}

}  // namespace long3r

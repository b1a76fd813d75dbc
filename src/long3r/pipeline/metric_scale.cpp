// Metric scale estimation; see include/long3r/pipeline/metric_scale.hpp.
#include "long3r/pipeline/metric_scale.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "long3r/geometry/statistics.hpp"

namespace long3r {

namespace {

// MAD to the standard deviation of a Gaussian; and the median's standard
// error over the mean's for Gaussian samples (sqrt(pi / 2)).
constexpr double kMadToSigma = 1.4826;
constexpr double kMedianEfficiency = 1.2533;

}  // namespace

void MetricScaleConfig::validate(const config::FieldCheck& check) const {
  check.require(std::isfinite(fixed_scale) && fixed_scale > 0.0, "m_per_unit", "must be > 0");
  check.require(std::isfinite(min_baseline_m) && min_baseline_m > 0.0, "min_baseline_m",
                "must be > 0");
  check.require(min_samples >= 1, "min_samples", "must be >= 1");
  check.require(max_rel_stddev > 0.0, "max_rel_stddev", "must be > 0");
  check.require(update_rel_change >= 0.0, "update_rel_change", "must be >= 0");
  check.require(max_samples >= static_cast<std::size_t>(min_samples), "max_samples",
                "must be >= min_samples");
}

ScaleEstimate robust_scale(const std::vector<double>& samples, const MetricScaleConfig& config) {
  ScaleEstimate e;
  std::vector<double> good;
  for (double s : samples) {
    if (std::isfinite(s) && s > 0.0) good.push_back(s);
  }
  e.rejected = static_cast<int>(samples.size() - good.size());
  if (good.empty()) return e;
  double m = median(good);
  std::vector<double> dev;
  for (double s : good) dev.push_back(std::abs(s - m));
  const double sigma = kMadToSigma * median(dev);
  if (sigma > 0.0) {
    std::vector<double> kept;
    for (double s : good) {
      if (std::abs(s - m) <= 3.0 * sigma) kept.push_back(s);
    }
    e.rejected += static_cast<int>(good.size() - kept.size());
    good.swap(kept);
    m = median(good);
    dev.clear();
    for (double s : good) dev.push_back(std::abs(s - m));
  }
  e.scale = m;
  e.samples = static_cast<int>(good.size());
  e.stddev =
      kMedianEfficiency * kMadToSigma * median(dev) / std::sqrt(static_cast<double>(e.samples));
  e.converged = e.samples >= config.min_samples && e.stddev <= config.max_rel_stddev * e.scale;
  return e;
}

std::optional<double> OdometryScaleSampler::add(const Eigen::Vector3d& odom_position_m,
                                                const Eigen::Vector3d& model_position) {
  if (!odom_position_m.allFinite() || !model_position.allFinite()) return std::nullopt;
  if (!anchor_) {
    anchor_ = Anchor{odom_position_m, model_position};
    return std::nullopt;
  }
  const double odom = (odom_position_m - anchor_->odom).norm();
  if (odom < config_.min_baseline_m) return std::nullopt;
  const double model = (model_position - anchor_->model).norm();
  anchor_ = Anchor{odom_position_m, model_position};
  if (!(model > 0.0)) return std::nullopt;  // the model did not move: no ratio
  return odom / model;
}

std::optional<double> depth_scale_sample(const cv::Mat& predicted_z, const cv::Mat& measured_m,
                                         const cv::Mat& conf, float conf_threshold,
                                         int min_pixels) {
  if (predicted_z.type() != CV_32FC1 || measured_m.type() != CV_32FC1 ||
      predicted_z.size() != measured_m.size() ||
      (!conf.empty() && (conf.type() != CV_32FC1 || conf.size() != predicted_z.size()))) {
    throw std::invalid_argument(
        "depth_scale_sample: expected CV_32FC1 predicted depth, measured depth and confidence "
        "of one size");
  }
  std::vector<double> ratios;
  for (int v = 0; v < predicted_z.rows; ++v) {
    const float* p = predicted_z.ptr<float>(v);
    const float* m = measured_m.ptr<float>(v);
    const float* c = conf.empty() ? nullptr : conf.ptr<float>(v);
    for (int u = 0; u < predicted_z.cols; ++u) {
      if (c && !(c[u] >= conf_threshold)) continue;
      if (std::isfinite(p[u]) && std::isfinite(m[u]) && p[u] > 0.0f && m[u] > 0.0f) {
        ratios.push_back(static_cast<double>(m[u]) / p[u]);
      }
    }
  }
  if (static_cast<int>(ratios.size()) < min_pixels) return std::nullopt;
  return median(std::move(ratios));
}

cv::Mat depth_at_model_pixels(const cv::Mat& depth_m, const PixelMapping& model_to_source,
                              int model_width, int model_height) {
  if (depth_m.type() != CV_32FC1) {
    throw std::invalid_argument("depth_at_model_pixels: expected a CV_32FC1 depth image");
  }
  cv::Mat out(model_height, model_width, CV_32FC1);
  for (int v = 0; v < model_height; ++v) {
    float* o = out.ptr<float>(v);
    for (int u = 0; u < model_width; ++u) {
      const Eigen::Vector2d s = model_to_source.apply(Eigen::Vector2d(u, v));
      const long x = std::lround(s.x()), y = std::lround(s.y());
      o[u] = x >= 0 && y >= 0 && x < depth_m.cols && y < depth_m.rows
                 ? depth_m.at<float>(static_cast<int>(y), static_cast<int>(x))
                 : std::numeric_limits<float>::quiet_NaN();
    }
  }
  return out;
}

ScalePolicy::ScalePolicy(const MetricScaleConfig& config) : config_(config) { reset(); }

void ScalePolicy::reset() {
  samples_.clear();
  estimate_ = ScaleEstimate();
  const bool fixed = config_.source == ScaleSource::kFixed;
  applied_ = fixed ? config_.fixed_scale : 1.0;
  metric_ = fixed;
}

void ScalePolicy::restore(const State& state) {
  samples_.assign(state.samples.begin(), state.samples.end());
  while (samples_.size() > config_.max_samples) samples_.pop_front();
  estimate_ = samples_.empty() ? ScaleEstimate()
                               : robust_scale({samples_.begin(), samples_.end()}, config_);
  applied_ = state.applied;
  metric_ = state.metric;
}

void ScalePolicy::add_sample(double ratio) {
  samples_.push_back(ratio);
  while (samples_.size() > config_.max_samples) samples_.pop_front();
  estimate_ = robust_scale({samples_.begin(), samples_.end()}, config_);
}

std::optional<double> ScalePolicy::scale_to_apply() {
  if (config_.source == ScaleSource::kNone || config_.source == ScaleSource::kFixed) {
    return std::nullopt;
  }
  if (!estimate_.converged) return std::nullopt;
  if (metric_) {
    if (config_.freeze) return std::nullopt;
    const double change = std::abs(estimate_.scale - applied_);
    if (change <= config_.update_rel_change * applied_ || change <= 2.0 * estimate_.stddev) {
      return std::nullopt;
    }
  }
  applied_ = estimate_.scale;
  metric_ = true;
  return applied_;
}

}  // namespace long3r

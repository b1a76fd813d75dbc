// Metric scale of the model's reconstruction: metres per model unit.
//
// A monocular model reconstructs up to an unknown scale. The pipeline
// multiplies everything it outputs (pointmaps, poses, map) by one scale s
// (Reconstruction::set_scale); this file estimates s online from one of
// two metric references, robustly, with its uncertainty:
//
//   odometry  the ratio between the odometry's and the model's camera
//             displacements: each time the odometry camera has moved at
//             least min_baseline_m since the last anchor frame, one sample
//             |d_odom| / |d_model| over that segment;
//   depth     a registered depth image (RGB-D): per frame the median over
//             valid pixels of measured / predicted depth, one sample.
//
// The estimate is the median of the samples, after rejecting those beyond
// 3 scaled MADs of it; its standard error is 1.2533 * 1.4826 MAD / sqrt(n)
// (the median's efficiency for Gaussian samples). It is usable once
// n >= min_samples and stderr / scale <= max_rel_stddev (converged).
//
// Policy (ScalePolicy): the scale is applied when the estimate first
// converges; the map and path built before are rescaled then, once. With
// freeze (the default) it stays for the rest of the stream; otherwise it is
// re-applied whenever the converged estimate moves from the applied value by
// more than update_rel_change and by more than 2 standard errors. A new
// stream starts over.
#pragma once

#include <Eigen/Core>
#include <opencv2/core/mat.hpp>

#include <array>
#include <cstddef>
#include <deque>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "long3r/config/config_fields.hpp"
#include "long3r/pipeline/preprocess.hpp"

namespace long3r {

// none: model units (scale 1); fixed: MetricScaleConfig::fixed_scale (field m_per_unit).
enum class ScaleSource { kNone, kOdometry, kDepth, kFixed };
inline const std::array<std::pair<ScaleSource, const char*>, 4>& enum_names(ScaleSource) {
  static const std::array<std::pair<ScaleSource, const char*>, 4> names{
      {{ScaleSource::kNone, "none"},
       {ScaleSource::kOdometry, "odometry"},
       {ScaleSource::kDepth, "depth"},
       {ScaleSource::kFixed, "fixed"}}};
  return names;
}

struct MetricScaleConfig {
  ScaleSource source = ScaleSource::kNone;
  double fixed_scale = 1.0;         // metres per model unit, source fixed
  double min_baseline_m = 0.10;     // odometry: camera travel per sample
  int min_samples = 5;              // before the estimate counts as converged
  double max_rel_stddev = 0.03;     // standard error / scale at convergence
  bool freeze = true;               // keep the first applied scale for the stream
  double update_rel_change = 0.02;  // without freeze: re-apply beyond this change
  std::size_t max_samples = 500;    // the oldest samples are forgotten beyond this

  // Throws ConfigError naming the field.
  void validate(const config::FieldCheck& check) const;
};

template <class S, class V>
config::FieldsOf<S, MetricScaleConfig> visit_fields(S& s, V& v) {
  v("source", s.source);
  v("m_per_unit", s.fixed_scale);
  v("min_baseline_m", s.min_baseline_m);
  v("min_samples", s.min_samples);
  v("max_rel_stddev", s.max_rel_stddev);
  v("freeze", s.freeze);
  v("update_rel_change", s.update_rel_change);
  v("max_samples", s.max_samples);
}

struct ScaleEstimate {
  double scale = 1.0;   // metres per model unit
  double stddev = 0.0;  // standard error of scale
  int samples = 0;      // after outlier rejection
  int rejected = 0;
  bool converged = false;
};

// Median / MAD estimate of a set of ratio samples (see the file comment).
ScaleEstimate robust_scale(const std::vector<double>& samples, const MetricScaleConfig& config);

// Samples from camera displacements. Positions of the same camera: from the
// odometry (metres) and from the model's poses (model units, unscaled).
class OdometryScaleSampler {
 public:
  explicit OdometryScaleSampler(const MetricScaleConfig& config) : config_(config) {}
  // Returns the new sample, if this frame closed a segment.
  std::optional<double> add(const Eigen::Vector3d& odom_position_m,
                            const Eigen::Vector3d& model_position);
  void reset() { anchor_.reset(); }

 private:
  struct Anchor {
    Eigen::Vector3d odom, model;
  };
  MetricScaleConfig config_;
  std::optional<Anchor> anchor_;
};

// One depth sample: the median of measured / predicted depth over the pixels
// where both are finite and positive and conf >= conf_threshold; nullopt when
// fewer than min_pixels are. predicted_z: CV_32FC1 model-unit depth (z of
// the pointmap in the camera frame); measured_m: CV_32FC1 metres, the same
// size; conf: CV_32FC1 or empty.
std::optional<double> depth_scale_sample(const cv::Mat& predicted_z, const cv::Mat& measured_m,
                                         const cv::Mat& conf, float conf_threshold,
                                         int min_pixels = 100);

// A registered depth image (CV_32FC1 metres, the source image's size) seen at
// the model's pixels: each model pixel takes the depth of the source pixel
// nearest to where it maps (model_to_source, preprocess.hpp); depth is not
// interpolated across edges. NaN outside the source image.
cv::Mat depth_at_model_pixels(const cv::Mat& depth_m, const PixelMapping& model_to_source,
                              int model_width, int model_height);

// Collects samples and decides when the pipeline's scale changes.
class ScalePolicy {
 public:
  explicit ScalePolicy(const MetricScaleConfig& config);
  void add_sample(double ratio);
  // The scale to apply now, when it should change (first convergence, or an
  // update allowed by the policy); nullopt otherwise.
  std::optional<double> scale_to_apply();
  const ScaleEstimate& estimate() const { return estimate_; }
  // The scale in use (1 until the first application; fixed_scale for fixed).
  double applied() const { return applied_; }
  bool metric() const { return metric_; }
  void reset();

  // What the policy carries (sessions): the samples and the scale applied.
  struct State {
    std::vector<double> samples;
    double applied = 1.0;
    bool metric = false;
  };
  State state() const { return {{samples_.begin(), samples_.end()}, applied_, metric_}; }
  // The estimate is recomputed from the samples (the newest max_samples).
  void restore(const State& state);

 private:
  MetricScaleConfig config_;
  std::deque<double> samples_;
  ScaleEstimate estimate_;
  double applied_ = 1.0;
  bool metric_ = false;
};

}  // namespace long3r

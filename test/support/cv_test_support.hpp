// Fixtures of the OpenCV-side tests (long3r_cv_tests only): synthetic
// pointmaps of a pinhole camera, a generated sequence with a model that
// returns its ground-truth pointmaps (the pipeline's plumbing checked exactly),
// and the checks of the dataset-layout readers against their writers' frames.
#pragma once

#include <Eigen/Geometry>
#include <opencv2/core/mat.hpp>

#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "long3r/geometry/pinhole_intrinsics.hpp"
#include "long3r/model/network/streaming.hpp"
#include "long3r/pipeline/reconstruction.hpp"
#include "long3r/synth/cv/dataset_layouts.hpp"
#include "long3r/synth/generate.hpp"
#include "long3r/train/cv/datasets/dataset_io.hpp"
#include "long3r/train/train_config.hpp"
#include "long3r/train/train_data.hpp"

namespace long3r::test {

// CV_32FC3 [k.height, k.width]: pixel (u, v) at z-depth depth(u, v) in the
// camera, mapped by T (camera to the target frame); NaN where the depth is not
// > 0. depth is called row by row, left to right.
cv::Mat pointmap_from_depth(const PinholeIntrinsics& k, const Eigen::Isometry3d& T,
                            const std::function<double(int u, int v)>& depth);

// A generated sequence's configuration: seed, trajectory kind and length,
// a w x h pinhole camera with a 70 degree horizontal field of view.
synth::SequenceConfig sequence_config(std::uint64_t seed, synth::TrajectoryType type, int frames,
                                      int w = 96, int h = 72);

// A test image (CV_8UC3): two gradients and, in the third channel, a smooth
// egg-crate pattern (period 24 px) whose steep slopes make a shift of a
// pixel visible while bilinear resampling stays nearly exact.
cv::Mat egg_crate_image(int width, int height);

// A generated sequence at kGtSize x kGtSize: images and ground-truth
// pointmaps in camera 0's frame.
constexpr int kGtSize = 64;
struct GtSequence {
  synth::Sequence seq;
  std::vector<cv::Mat> bgr;
  std::vector<cv::Mat> pts_W0;  // CV_32FC3 in camera 0's frame
  std::vector<Eigen::Isometry3d> T_0_k;
};
GtSequence make_sequence(int frames);

// Returns the ground-truth pointmaps (confidence 10 where finite, else 1)
// with the models' one-frame latency.
// The pipeline's config for GtSequence: model input kGtSize, PnP and map
// thresholds that the exact pointmaps pass.
ReconstructionConfig gt_reconstruction_config();

class FakeModel : public StreamingModel {
 public:
  explicit FakeModel(const std::vector<cv::Mat>* pts) : pts_(pts) {}
  std::optional<StreamOutput> push(const at::Tensor& image) override;
  std::optional<StreamOutput> peek_last() override;
  void reset() override { n_ = 0; }
  int64_t frames_pushed() const override { return n_; }
  std::string variant() const override { return "fake"; }
  // Sessions: the frame count is the whole stream; the identity's weights
  // fingerprint is `weights` (empty: a model that cannot save sessions).
  StateDict stream_state() const override;
  void restore_stream_state(const StateDict& state) override;
  ModelIdentity identity() const override { return {variant(), "{\"fake\": 1}", weights}; }
  std::string weights = "fake-weights";

 private:
  StreamOutput output(int64_t k, bool coarse);
  const std::vector<cv::Mat>* pts_;
  int64_t n_ = 0;
};

// ---------------------------------------------------- dataset layouts
// test/train/test_dataset_<layout>.cpp: a layout's writer
// (synth/cv/dataset_layouts.hpp) and reader (train/cv/datasets/dataset_io.hpp)
// against each other.

// How closely a read frame must match the frame its writer was given; each
// layout's encoding sets it.
struct FramePrecision {
  // Depth: |read - true| <= depth_abs_m + depth_rel * true + depth_slack_m at
  // every pixel with depth. The encoding's error (depth_abs_m + depth_rel *
  // true) moves a world point along its ray; beyond that, by point_slack_m.
  double depth_abs_m = 0.0;
  double depth_rel = 0.0;
  double depth_slack_m = 0.0;
  double point_slack_m = 1e-5;
  // Colour: identical, or a mean absolute difference below colour_levels per
  // BGR value or in grey (for JPEG, whose colour is kept at half resolution).
  enum class Colour { kExact, kMeanBgr, kMeanGrey };
  Colour colour = Colour::kExact;
  double colour_levels = 3.0;
};

// The layouts' two kinds of depth: 16-bit millimetres (half a millimetre of
// rounding, and float's), with `colour` and `point_slack_m`; and float depth
// within `depth_rel` relative + 1e-6 m, with JPEG colour within 3 grey levels
// on average.
FramePrecision millimetre_depth_precision(FramePrecision::Colour colour,
                                          double point_slack_m = 1e-5);
FramePrecision relative_depth_precision(double depth_rel);

// `read` against `truth`: sizes; fx, fy, cx, cy within 1e-6 relative (of the
// focal length, and of cx, cy themselves); T_W_C within 1e-6 per entry;
// colour; depth exactly 0 where the truth has none and within `p` elsewhere,
// on more than half the pixels; every pixel's world point.
void expect_frame_matches(const RawFrame& read, const synth::LayoutFrame& truth,
                          const FramePrecision& p);

// Frames 0.. of `seq` against truth[first], truth[first + 1], ...
void expect_sequence_matches(const RecordedSource& seq,
                             const std::vector<synth::LayoutFrame>& truth, const FramePrecision& p,
                             std::size_t first = 0);

// A DatasetSource of `layout` at `root`, and the dataset opened from it
// (datasets::open_dataset).
DatasetSource layout_source(const std::string& layout, const std::string& root,
                            const std::string& split = "train");
datasets::DatasetScan open_layout(const std::string& layout, const std::string& root,
                                  const std::string& split = "train");

// The sequence named `name` (as RecordedSource::name()), or nullptr.
const RecordedSource* find_sequence(const datasets::DatasetScan& scan, const std::string& name);

// `act` throws a RecordedFrameError whose message contains `text` (a path
// that a reader must name).
void expect_error_naming(const std::function<void()>& act, const std::string& text);

// A fixture file broken on purpose: cut to its first `bytes` bytes, or
// removed. Each throws when there is nothing to break, so that a test cannot
// pass by breaking nothing.
void truncate_file(const std::string& path, std::uintmax_t bytes);
void delete_file(const std::string& path);

}  // namespace long3r::test

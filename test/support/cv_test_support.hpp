// Fixtures of the OpenCV-side tests (long3r_cv_tests only): synthetic
// pointmaps of a pinhole camera, and a generated sequence with a model that
// returns its ground-truth pointmaps (the pipeline's plumbing checked exactly).
#pragma once

#include <Eigen/Geometry>
#include <opencv2/core/mat.hpp>

#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "long3r/model/streaming.hpp"
#include "long3r/pipeline/pinhole_intrinsics.hpp"
#include "long3r/pipeline/reconstruction.hpp"
#include "long3r/synth/synth.hpp"

namespace long3r::test {

// CV_32FC3 [k.height, k.width]: pixel (u, v) at z-depth depth(u, v) in the
// camera, mapped by T (camera to the target frame); NaN where the depth is not
// > 0. depth is called row by row, left to right.
cv::Mat pointmap_from_depth(const PinholeIntrinsics& k, const Eigen::Isometry3d& T,
                            const std::function<double(int u, int v)>& depth);

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

}  // namespace long3r::test

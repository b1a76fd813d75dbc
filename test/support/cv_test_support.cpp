#include "support/cv_test_support.hpp"

#include <ATen/core/Tensor.h>
#include <ATen/ops/from_blob.h>
#include <gtest/gtest.h>

#include <cmath>

#include "long3r/synth/sensor_image.hpp"

namespace long3r::test {

cv::Mat pointmap_from_depth(const PinholeIntrinsics& k, const Eigen::Isometry3d& T,
                            const std::function<double(int u, int v)>& depth) {
  cv::Mat pts(k.height, k.width, CV_32FC3, cv::Scalar::all(NAN));
  for (int v = 0; v < k.height; ++v) {
    for (int u = 0; u < k.width; ++u) {
      const double d = depth(u, v);
      if (!(d > 0.0)) continue;
      const Eigen::Vector3d X = T * k.backproject(u, v, d);
      pts.at<cv::Vec3f>(v, u) = cv::Vec3f(static_cast<float>(X.x()), static_cast<float>(X.y()),
                                          static_cast<float>(X.z()));
    }
  }
  return pts;
}

cv::Mat egg_crate_image(int width, int height) {
  cv::Mat img(height, width, CV_8UC3);
  for (int v = 0; v < height; ++v)
    for (int u = 0; u < width; ++u) {
      const double waves = std::sin(2.0 * M_PI * u / 24.0) * std::sin(2.0 * M_PI * v / 24.0);
      img.at<cv::Vec3b>(v, u) =
          cv::Vec3b(static_cast<uchar>(u * 255 / width), static_cast<uchar>(v * 255 / height),
                    cv::saturate_cast<uchar>(128.0 + 110.0 * waves));
    }
  return img;
}

ReconstructionConfig gt_reconstruction_config() {
  ReconstructionConfig c;
  c.preprocess.width = c.preprocess.height = kGtSize;
  c.pnp.min_inliers = 30;
  c.map.voxel_size_m = 0.05;
  return c;
}

GtSequence make_sequence(int frames) {
  synth::SequenceConfig c;
  c.seed = 3;
  c.trajectory.frames = frames;
  c.trajectory.speed = 0.05;
  c.intrinsics = PinholeIntrinsics::from_hfov(kGtSize, kGtSize, 70.0);
  GtSequence g;
  g.seq = synth::generate_sequence(c);
  for (int k = 0; k < frames; ++k) {
    const synth::RenderedFrame f = synth::render_frame(g.seq.scene, g.seq.poses[k], c.intrinsics);
    const Eigen::Isometry3d T = g.seq.poses[0].inverse() * g.seq.poses[k];
    g.bgr.push_back(synth::bgr_image(f));
    const cv::Mat depth = synth::depth_image(f);
    g.pts_W0.push_back(
        pointmap_from_depth(c.intrinsics, T, [&](int u, int v) { return depth.at<float>(v, u); }));
    g.T_0_k.push_back(T);
  }
  return g;
}

std::optional<StreamOutput> FakeModel::push(const at::Tensor& image) {
  EXPECT_EQ(image.dim(), 4);
  EXPECT_EQ(image.size(2), kGtSize);
  EXPECT_EQ(image.size(3), kGtSize);
  const int64_t k = n_++;
  if (k == 0) return std::nullopt;
  return output(k - 1, false);
}

StateDict FakeModel::stream_state() const {
  StateDict state;
  put_int(state, "frames", n_);
  return state;
}

void FakeModel::restore_stream_state(const StateDict& state) {
  n_ = StateReader(state, "fake model state")
           .integer("frames", 0, static_cast<int64_t>(pts_->size()));
}

std::optional<StreamOutput> FakeModel::peek_last() {
  if (n_ == 0) return std::nullopt;
  return output(n_ - 1, true);
}

StreamOutput FakeModel::output(int64_t k, bool coarse) {
  StreamOutput o;
  o.frame_index = k;
  o.from_coarse_head = coarse;
  cv::Mat p = (*pts_)[static_cast<std::size_t>(k)].clone();
  cv::Mat conf(kGtSize, kGtSize, CV_32FC1);
  for (int i = 0; i < kGtSize * kGtSize; ++i) {
    conf.at<float>(i) = std::isfinite(p.at<cv::Vec3f>(i)[2]) ? 10.f : 1.f;
  }
  o.pts3d = at::from_blob(p.data, {1, kGtSize, kGtSize, 3}, at::kFloat).clone();
  o.conf = at::from_blob(conf.data, {1, kGtSize, kGtSize}, at::kFloat).clone();
  o.stats.mem_short_tokens = 7;
  return o;
}

}  // namespace long3r::test

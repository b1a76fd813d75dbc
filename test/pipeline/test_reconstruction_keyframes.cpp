// Reconstruction with pose_method keyframes: 640 x 480 source images, a fake
// model returning the true pointmap at its 64 x 64 input (through the
// pipeline's own resize and crop), so that the plumbing is checked against
// exact ground truth: the tracker's pose and Sim(3) scale reach the result,
// and a frame it cannot track is placed without a jump.
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "long3r/pipeline/preprocess.hpp"
#include "long3r/pipeline/reconstruction.hpp"
#include "long3r/synth/cv/sensor_image.hpp"
#include "long3r/synth/generate.hpp"
#include "long3r/synth/render.hpp"
#include "support/cv_test_support.hpp"

namespace long3r {
namespace {

constexpr int kW = 640, kH = 480;
constexpr int kSize = test::kGtSize;

struct Footage {
  synth::Sequence seq;
  std::vector<cv::Mat> bgr;
  std::vector<cv::Mat> pts_W0;  // at model resolution, in camera 0's frame
  std::vector<Eigen::Isometry3d> T_0_k;
};

// `scale_of(k)` scales frame k's pointmap (a model whose scale wanders).
Footage render(int frames, const std::function<double(int)>& scale_of) {
  synth::SequenceConfig c;
  c.seed = 21;
  c.trajectory.frames = frames;
  c.intrinsics = PinholeIntrinsics::from_hfov(kW, kH, 70.0);
  Footage f;
  f.seq = synth::generate_sequence(c);
  PreprocessConfig pre;
  pre.width = pre.height = kSize;
  const PixelMapping to_source = plan_resize_crop(kW, kH, pre).model_to_source;
  for (int k = 0; k < frames; ++k) {
    const synth::RenderedFrame r = synth::render_frame(f.seq.scene, f.seq.poses[k], c.intrinsics);
    f.bgr.push_back(synth::bgr_image(r));
    const cv::Mat depth = synth::depth_image(r);
    const Eigen::Isometry3d T = f.seq.poses[0].inverse() * f.seq.poses[k];
    cv::Mat pts(kSize, kSize, CV_32FC3);
    for (int v = 0; v < kSize; ++v) {
      for (int u = 0; u < kSize; ++u) {
        const Eigen::Vector2d s = to_source.apply({u, v});
        const float d = depth.at<float>(static_cast<int>(std::lround(s.y())),
                                        static_cast<int>(std::lround(s.x())));
        const Eigen::Vector3d X_C((s.x() - c.intrinsics.cx) / c.intrinsics.fx * d,
                                  (s.y() - c.intrinsics.cy) / c.intrinsics.fy * d, d);
        const Eigen::Vector3d X = (T * X_C) * scale_of(k);
        pts.at<cv::Vec3f>(v, u) =
            d > 0.0f ? cv::Vec3f(X.x(), X.y(), X.z()) : cv::Vec3f(NAN, NAN, NAN);
      }
    }
    f.pts_W0.push_back(pts);
    f.T_0_k.push_back(T);
  }
  return f;
}

ReconstructionConfig keyframes_config() {
  ReconstructionConfig c = test::gt_reconstruction_config();
  c.pose_method = PoseMethod::kKeyframes;
  return c;
}

std::vector<FrameResult> run(Reconstruction& rec, const std::vector<cv::Mat>& images) {
  std::vector<FrameResult> results;
  for (std::size_t k = 0; k < images.size(); ++k) {
    if (auto r = rec.push(images[k], "bgr8", 0.1 * static_cast<double>(k))) {
      results.push_back(std::move(*r));
    }
  }
  results.push_back(*rec.flush());
  return results;
}

TEST(ReconstructionKeyframes, TheTrackersPoseAndScaleReachTheResult) {
  // Frames 3 and 4 come at 0.6 of the stream's scale: their PnP pose and
  // camera points are 0.6 the size; the tracker's Sim(3) brings them back.
  const Footage f = render(6, [](int k) { return k == 3 || k == 4 ? 0.6 : 1.0; });
  Reconstruction rec(std::make_unique<test::FakeModel>(&f.pts_W0), keyframes_config());
  rec.set_calibration(f.seq.config.intrinsics);
  const std::vector<FrameResult> results = run(rec, f.bgr);
  ASSERT_EQ(results.size(), 6u);
  for (std::size_t k = 0; k < results.size(); ++k) {
    const FrameResult& r = results[k];
    ASSERT_TRUE(r.tracking.has_value()) << k;
    ASSERT_TRUE(r.tracking->posed()) << k << ": " << r.tracking->message;
    EXPECT_EQ(r.tracking->status, k == 0 ? TrackStatus::kKeyframe : TrackStatus::kTracked);
    // The keyframe's points come from a 64 x 64 pointmap under 640 x 480
    // features (depth edges blur): about 1-2 cm in 10 cm of travel.
    const Eigen::Isometry3d d = f.T_0_k[k].inverse() * r.pose.T_W_C;
    EXPECT_LT(d.translation().norm(), 0.03) << k;
    EXPECT_LT(Eigen::AngleAxisd(d.rotation()).angle(), 0.01) << k;
    if (k == 3 || k == 4) {
      EXPECT_NEAR(r.tracking->scale, 1.0 / 0.6, 0.05) << k;
      EXPECT_LT((r.model_T_W_C.translation() - 0.6 * f.T_0_k[k].translation()).norm(), 1e-3);
    }
    // The map gets the frame where the tracker put it, in the stream's scale.
    const cv::Vec3f c = r.points_C.at<cv::Vec3f>(kSize / 2, kSize / 2);
    const cv::Vec3f w = r.points_W.at<cv::Vec3f>(kSize / 2, kSize / 2);
    ASSERT_TRUE(std::isfinite(c[2]));
    const Eigen::Vector3d truth = f.T_0_k[k] * Eigen::Vector3d(c[0], c[1], c[2]);
    EXPECT_LT((truth - Eigen::Vector3d(w[0], w[1], w[2])).norm(), 0.02) << k;
    const cv::Vec3f true_w = f.pts_W0[k].at<cv::Vec3f>(kSize / 2, kSize / 2);
    const double s = k == 3 || k == 4 ? 0.6 : 1.0;
    EXPECT_LT(
        (Eigen::Vector3d(w[0], w[1], w[2]) - Eigen::Vector3d(true_w[0], true_w[1], true_w[2]) / s)
            .norm(),
        0.02)
        << k;
  }
}

TEST(ReconstructionKeyframes, AnUntrackedFrameFollowsTheModelsMotionWithoutAJump) {
  // From frame 2 on the model's scale is 0.6: its own poses jump towards
  // the origin, the tracker's do not.
  const Footage f = render(5, [](int k) { return k >= 2 ? 0.6 : 1.0; });
  std::vector<cv::Mat> images = f.bgr;
  images[3] = cv::Mat(kH, kW, CV_8UC3, cv::Scalar(0, 0, 0));  // no features at all
  Reconstruction rec(std::make_unique<test::FakeModel>(&f.pts_W0), keyframes_config());
  rec.set_calibration(f.seq.config.intrinsics);
  const std::vector<FrameResult> results = run(rec, images);
  ASSERT_EQ(results.size(), 5u);
  const FrameResult& dark = results[3];
  ASSERT_TRUE(dark.tracking.has_value());
  EXPECT_EQ(dark.tracking->status, TrackStatus::kTooFewFeatures);
  ASSERT_TRUE(dark.pose.ok());  // the model's PnP still posed it
  const double jump = (dark.model_T_W_C.translation() - f.T_0_k[3].translation()).norm();
  EXPECT_GT(jump, 0.02);  // where the model's own pose would have put it
  // The model's motion from where frame 2 was tracked: closer than a jump,
  // and within two frames' travel of frame 2.
  EXPECT_LT((dark.pose.T_W_C.translation() - f.T_0_k[3].translation()).norm(), jump);
  const double step = (f.T_0_k[3].translation() - f.T_0_k[2].translation()).norm();
  EXPECT_LT((dark.pose.T_W_C.translation() - results[2].pose.T_W_C.translation()).norm(),
            2.0 * step);
  EXPECT_NEAR(dark.tracking->scale, 1.0 / 0.6, 0.05);  // the last tracked frame's
  EXPECT_EQ(results[4].tracking->status, TrackStatus::kTracked);
}

TEST(ReconstructionKeyframes, TheModelsPoseMethodRunsNoTracker) {
  const Footage f = render(3, [](int) { return 1.0; });
  Reconstruction rec(std::make_unique<test::FakeModel>(&f.pts_W0),
                     test::gt_reconstruction_config());
  rec.set_calibration(f.seq.config.intrinsics);
  for (const FrameResult& r : run(rec, f.bgr)) EXPECT_FALSE(r.tracking.has_value());
}

}  // namespace
}  // namespace long3r

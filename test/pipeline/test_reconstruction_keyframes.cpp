// Reconstruction with pose_method keyframes: 640 x 480 source images, a fake
// model returning the true pointmap at its 64 x 64 input (through the
// pipeline's own resize and crop), so that the plumbing is checked against
// exact ground truth: the tracker's pose and Sim(3) scale reach the result,
// and a frame it cannot track is placed without a jump. Relocalisation by
// images: a restored stream (a loaded session) places a frame of the same
// place by its kept keyframes, whatever the model's pose, refuses one of
// another place (not posed, not mapped), and its keyframes survive a
// session file. Frames placed by metric odometry measure the model's scale
// by their images (BaselineScale), whatever the model's own poses.
#include <ATen/ATen.h>
#include <gtest/gtest.h>

#include <cmath>
#include <numeric>
#include <vector>

#include "long3r/pipeline/keyframe_state.hpp"
#include "long3r/pipeline/live_session.hpp"
#include "long3r/pipeline/preprocess.hpp"
#include "long3r/pipeline/reconstruction.hpp"
#include "long3r/synth/cv/sensor_image.hpp"
#include "long3r/synth/generate.hpp"
#include "long3r/synth/render.hpp"
#include "support/cv_test_support.hpp"
#include "support/live_session_support.hpp"
#include "support/test_support.hpp"

namespace long3r {
namespace {

constexpr int kW = 640, kH = 480;
constexpr int kSize = test::kGtSize;

struct Footage {
  synth::Sequence seq;
  std::vector<cv::Mat> bgr;
  std::vector<cv::Mat> pts_W0;  // at model resolution, in camera 0's frame
  std::vector<Eigen::Isometry3d> T_0_k;
  std::vector<cv::Mat> depth;  // metres, at source resolution
};

// `scale_of(k)` scales frame k's pointmap (a model whose scale wanders).
Footage render(int frames, const std::function<double(int)>& scale_of, std::uint64_t seed = 21) {
  synth::SequenceConfig c;
  c.seed = seed;
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
    f.depth.push_back(depth);
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

// A frame of the footage as LiveSession takes it: calibrated, tagged.
LiveFrame live_frame(const Footage& f, const cv::Mat& image, double stamp_s, int tag) {
  LiveFrame frame;
  frame.image = image;
  frame.encoding = "bgr8";
  frame.stamp_s = frame.clock_s = stamp_s;
  frame.camera = camera_model(f.seq.config.intrinsics);
  frame.tag = tag;
  return frame;
}

// The footage with frame 3 black (no features at all): the tracker cannot
// place it, the motion prior does.
std::vector<FrameResult> run_with_frame_3_dark(const Footage& f, MotionPrior prior) {
  std::vector<cv::Mat> images = f.bgr;
  images[3] = cv::Mat(kH, kW, CV_8UC3, cv::Scalar(0, 0, 0));
  ReconstructionConfig config = keyframes_config();
  config.tracker.motion_prior = prior;
  Reconstruction rec(std::make_unique<test::FakeModel>(&f.pts_W0), config);
  rec.set_calibration(f.seq.config.intrinsics);
  return run(rec, images);
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
  const std::vector<FrameResult> results = run_with_frame_3_dark(f, MotionPrior::kModel);
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

// tracker_motion_prior constant_velocity: the untracked frame continues the
// last step of the tracked ones, whatever the model's own pose says.
TEST(ReconstructionKeyframes, AnUntrackedFrameCanContinueTheTrackedMotion) {
  const Footage f = render(5, [](int k) { return k >= 2 ? 0.6 : 1.0; });
  const std::vector<FrameResult> results = run_with_frame_3_dark(f, MotionPrior::kConstantVelocity);
  ASSERT_EQ(results.size(), 5u);
  ASSERT_EQ(results[3].tracking->status, TrackStatus::kTooFewFeatures);
  const Eigen::Isometry3d& T1 = results[1].pose.T_W_C;
  const Eigen::Isometry3d& T2 = results[2].pose.T_W_C;
  const Eigen::Isometry3d expected = T2 * (T1.inverse() * T2);
  const Eigen::Isometry3d d = expected.inverse() * results[3].pose.T_W_C;
  EXPECT_LT(d.translation().norm(), 1e-9);
  EXPECT_LT(Eigen::AngleAxisd(d.rotation()).angle(), 1e-9);
  // The generated path is smooth: continued, the step lands as near the
  // truth as the tracked frames (their bound in the first test).
  EXPECT_LT((results[3].pose.T_W_C.translation() - f.T_0_k[3].translation()).norm(), 0.03);
  EXPECT_EQ(results[4].tracking->status, TrackStatus::kTracked);
}

// tracker_motion_prior odometry: the untracked frame moves from the last
// placed one as the odometry's camera moved: all of that motion in a metric
// stream, only its rotation (and the constant velocity's translation) in
// model units, and the constant velocity where a frame has no odometry.
// The odometry's camera poses for the footage: the true ones in a frame O of
// its own, turned and offset from W, with an error on each step that the
// constant velocity does not have, so that the two priors differ.
std::vector<Eigen::Isometry3d> wobbly_odometry(const Footage& f) {
  Eigen::Isometry3d T_O_W = Eigen::Isometry3d::Identity();
  T_O_W.linear() = Eigen::AngleAxisd(0.7, Eigen::Vector3d(0.2, 1.0, 0.1).normalized()).matrix();
  T_O_W.translation() = Eigen::Vector3d(3.0, -1.0, 0.5);
  std::vector<Eigen::Isometry3d> T_O_C;
  for (std::size_t k = 0; k < f.T_0_k.size(); ++k) {
    Eigen::Isometry3d wobble = Eigen::Isometry3d::Identity();
    wobble.linear() =
        Eigen::AngleAxisd(0.02 * static_cast<double>(k), Eigen::Vector3d::UnitY()).matrix();
    wobble.translation() = Eigen::Vector3d(0.01 * static_cast<double>(k), 0.0, 0.0);
    T_O_C.push_back(T_O_W * f.T_0_k[k] * wobble);
  }
  return T_O_C;
}

TEST(ReconstructionKeyframes, AnUntrackedFrameCanFollowTheOdometry) {
  const Footage f = render(5, [](int) { return 1.0; });
  const std::vector<Eigen::Isometry3d> T_O_C = wobbly_odometry(f);
  std::vector<cv::Mat> images = f.bgr;
  images[3] = cv::Mat(kH, kW, CV_8UC3, cv::Scalar(0, 0, 0));
  auto run_with = [&](bool metric, bool odometry_at_3) {
    ReconstructionConfig config = keyframes_config();
    config.tracker.motion_prior = MotionPrior::kOdometry;
    Reconstruction rec(std::make_unique<test::FakeModel>(&f.pts_W0), config);
    rec.set_calibration(f.seq.config.intrinsics);
    rec.set_odometry_source(
        [&, metric, odometry_at_3](double stamp_s) -> std::optional<Reconstruction::OdometryPose> {
          const int k = static_cast<int>(std::lround(stamp_s / 0.1));
          if (k == 3 && !odometry_at_3) return std::nullopt;
          return Reconstruction::OdometryPose{T_O_C[static_cast<std::size_t>(k)], metric};
        });
    return run(rec, images);
  };
  for (const bool metric : {true, false}) {
    const std::vector<FrameResult> results = run_with(metric, true);
    ASSERT_EQ(results.size(), 5u);
    ASSERT_EQ(results[3].tracking->status, TrackStatus::kTooFewFeatures);
    const Eigen::Isometry3d& T1 = results[1].pose.T_W_C;
    const Eigen::Isometry3d& T2 = results[2].pose.T_W_C;
    const Eigen::Isometry3d odometry_step = T_O_C[2].inverse() * T_O_C[3];
    Eigen::Isometry3d step = T1.inverse() * T2;  // the constant velocity's translation
    step.linear() = odometry_step.linear();
    if (metric) step.translation() = odometry_step.translation();
    const Eigen::Isometry3d d = (T2 * step).inverse() * results[3].pose.T_W_C;
    EXPECT_LT(d.translation().norm(), 1e-9) << metric;
    EXPECT_LT(Eigen::AngleAxisd(d.rotation()).angle(), 1e-9) << metric;
    EXPECT_EQ(results[4].tracking->status, TrackStatus::kTracked) << metric;
  }
  // No odometry for the frame: the constant velocity.
  const std::vector<FrameResult> results = run_with(true, false);
  const std::vector<FrameResult> constant =
      run_with_frame_3_dark(f, MotionPrior::kConstantVelocity);
  const Eigen::Isometry3d d = constant[3].pose.T_W_C.inverse() * results[3].pose.T_W_C;
  EXPECT_LT(d.translation().norm(), 1e-9);
  EXPECT_LT(Eigen::AngleAxisd(d.rotation()).angle(), 1e-9);
}

// A stream whose first frames have too few features (a low-resolution camera
// starting at a blank wall): with constant_velocity nothing has measured a
// velocity yet, so they and the first keyframe stay where frame 0 went
// instead of continuing the model's own first step (here three times too
// long); the model prior follows the model.
TEST(ReconstructionKeyframes, FramesBeforeTheImagesPlaceTwoStayWhereTheFirstWent) {
  const Footage f = render(5, [](int k) { return k == 1 ? 3.0 : 1.0; });
  std::vector<cv::Mat> images = f.bgr;
  images[0] = cv::Mat(kH, kW, CV_8UC3, cv::Scalar(0, 0, 0));
  images[1] = images[0].clone();
  for (MotionPrior prior : {MotionPrior::kConstantVelocity, MotionPrior::kModel}) {
    ReconstructionConfig config = keyframes_config();
    config.tracker.motion_prior = prior;
    Reconstruction rec(std::make_unique<test::FakeModel>(&f.pts_W0), config);
    rec.set_calibration(f.seq.config.intrinsics);
    const std::vector<FrameResult> results = run(rec, images);
    ASSERT_EQ(results.size(), 5u);
    for (int k : {0, 1}) {
      ASSERT_TRUE(results[k].tracking.has_value()) << k;
      EXPECT_EQ(results[k].tracking->status, TrackStatus::kTooFewFeatures) << k;
    }
    ASSERT_EQ(results[2].tracking->status, TrackStatus::kKeyframe);
    const double model_step = results[1].model_T_W_C.translation().norm();
    EXPECT_NEAR(model_step, 3.0 * f.T_0_k[1].translation().norm(), 1e-3);
    if (prior == MotionPrior::kConstantVelocity) {
      for (int k : {1, 2}) {
        EXPECT_LT(results[k].pose.T_W_C.translation().norm(), 1e-9) << k;
        EXPECT_LT(Eigen::AngleAxisd(results[k].pose.T_W_C.rotation()).angle(), 1e-9) << k;
      }
    } else {
      EXPECT_LT((results[1].pose.T_W_C.translation() - results[1].model_T_W_C.translation()).norm(),
                1e-9);
    }
    // The frames after the keyframe are tracked from where it went.
    for (int k : {3, 4}) {
      ASSERT_EQ(results[k].tracking->status, TrackStatus::kTracked) << k;
      const Eigen::Isometry3d truth = f.T_0_k[2].inverse() * f.T_0_k[k];
      const Eigen::Isometry3d d =
          truth.inverse() * (results[2].pose.T_W_C.inverse() * results[k].pose.T_W_C);
      EXPECT_LT(d.translation().norm(), 0.03) << k;
    }
  }
}

// An isolated failure of the model's own pose (a frame with no depth in its
// camera) does not lose the stream: the next frame is tracked against the
// keyframe as before (where lost frames relocalise, it is relocalised; the
// next test).
TEST(ReconstructionKeyframes, AFrameAfterALostModelPoseIsTrackedAsBefore) {
  Footage f = render(6, [](int) { return 1.0; });
  f.pts_W0[3].setTo(cv::Scalar::all(NAN));
  Reconstruction rec(std::make_unique<test::FakeModel>(&f.pts_W0), keyframes_config());
  rec.set_calibration(f.seq.config.intrinsics);
  const std::vector<FrameResult> results = run(rec, f.bgr);
  ASSERT_EQ(results.size(), 6u);
  EXPECT_FALSE(results[3].pose.ok());
  EXPECT_FALSE(results[3].tracking.has_value());
  for (int k : {4, 5}) {
    const FrameResult& r = results[static_cast<std::size_t>(k)];
    ASSERT_TRUE(r.tracking.has_value()) << k;
    EXPECT_EQ(r.tracking->status, TrackStatus::kTracked) << k << ": " << r.tracking->message;
    const Eigen::Isometry3d d = f.T_0_k[static_cast<std::size_t>(k)].inverse() * r.pose.T_W_C;
    EXPECT_LT(d.translation().norm(), 0.03) << k;
    EXPECT_LT(Eigen::AngleAxisd(d.rotation()).angle(), 0.01) << k;
  }
}

// A control's results (b) keep the model's depth in the map's points, as
// the plain run's (a) have it, up to the tracker's scale.
void expect_the_models_depth_mapped(const std::vector<FrameResult>& a,
                                    const std::vector<FrameResult>& b) {
  ASSERT_EQ(a.size(), b.size());
  for (std::size_t k = 1; k < a.size(); ++k) {
    ASSERT_TRUE(a[k].tracking.has_value() && b[k].tracking.has_value()) << k;
    std::vector<float> za, zb;
    for (int v = 0; v < kSize; v += 8) {
      const float da = a[k].points_C.at<cv::Vec3f>(v, kSize / 2)[2];
      const float db = b[k].points_C.at<cv::Vec3f>(v, kSize / 2)[2];
      if (std::isfinite(da) && std::isfinite(db)) {
        za.push_back(da);
        zb.push_back(db / static_cast<float>(b[k].tracking->scale / a[k].tracking->scale));
      }
    }
    ASSERT_FALSE(za.empty());
    for (std::size_t i = 0; i < za.size(); ++i) EXPECT_NEAR(za[i], zb[i], 1e-3 * za[i]) << k;
  }
}

TEST(ReconstructionKeyframes, TheConstantDepthControlReachesOnlyTheTracker) {
  const Footage f = render(4, [](int) { return 1.0; });
  ReconstructionConfig control = keyframes_config();
  control.tracker_constant_depth = true;
  Reconstruction plain(std::make_unique<test::FakeModel>(&f.pts_W0), keyframes_config());
  Reconstruction planar(std::make_unique<test::FakeModel>(&f.pts_W0), control);
  plain.set_calibration(f.seq.config.intrinsics);
  planar.set_calibration(f.seq.config.intrinsics);
  const std::vector<FrameResult> a = run(plain, f.bgr), b = run(planar, f.bgr);
  expect_the_models_depth_mapped(a, b);
  double moved = 0.0;
  for (std::size_t k = 1; k < a.size(); ++k) {
    moved = std::max(moved, (a[k].pose.T_W_C.translation() - b[k].pose.T_W_C.translation()).norm());
  }
  EXPECT_GT(moved, 1e-3);  // the tracker saw another depth
}

TEST(ReconstructionKeyframes, TheTrueDepthControlPlacesFramesByTheGivenDepth) {
  // The model's depth is half the true one: the tracker's path is in its
  // units with the model's depth, in metres with the true depth.
  const Footage f = render(5, [](int) { return 0.5; });
  Reconstruction plain(std::make_unique<test::FakeModel>(&f.pts_W0), keyframes_config());
  Reconstruction given(std::make_unique<test::FakeModel>(&f.pts_W0), keyframes_config());
  plain.set_calibration(f.seq.config.intrinsics);
  given.set_calibration(f.seq.config.intrinsics);
  std::vector<double> asked;
  given.set_tracker_depth_source([&](double stamp_s) {
    asked.push_back(stamp_s);
    return f.depth[static_cast<std::size_t>(std::lround(stamp_s / 0.1))];
  });
  const std::vector<FrameResult> a = run(plain, f.bgr), b = run(given, f.bgr);
  // The map gets the model's shape at the depth images' scale, and the
  // tracker measures no scale of its own.
  ASSERT_EQ(a.size(), b.size());
  for (std::size_t k = 1; k < b.size(); ++k) {
    EXPECT_EQ(b[k].tracking->scale, 1.0) << k;
    int compared = 0;
    for (int v = 0; v < kSize; v += 8) {
      const float model =
          a[k].points_C.at<cv::Vec3f>(v, kSize / 2)[2] / static_cast<float>(a[k].tracking->scale);
      const float mapped = b[k].points_C.at<cv::Vec3f>(v, kSize / 2)[2];
      if (!std::isfinite(model) || !std::isfinite(mapped)) continue;
      EXPECT_NEAR(mapped, 2.0f * model, 1e-3f * mapped) << k;
      ++compared;
    }
    EXPECT_GT(compared, 0) << k;
  }
  EXPECT_EQ(asked.size(), f.bgr.size());  // every frame, the first keyframe too
  // The path's scale against the truth (least squares over the frames):
  // half a metre a unit with the model's depth, metres with the true depth.
  auto path_scale = [&](const std::vector<FrameResult>& r) {
    double num = 0.0, den = 0.0;
    for (std::size_t k = 1; k < r.size(); ++k) {
      EXPECT_EQ(r[k].tracking->status, TrackStatus::kTracked)
          << k << ": " << r[k].tracking->message;
      const Eigen::Vector3d t = r[k].pose.T_W_C.translation(), truth = f.T_0_k[k].translation();
      num += t.dot(truth);
      den += truth.squaredNorm();
    }
    return num / den;
  };
  EXPECT_NEAR(path_scale(a), 0.5, 0.05);
  EXPECT_NEAR(path_scale(b), 1.0, 0.1);
}

TEST(ReconstructionKeyframes, DepthImagesPlaceThePointsWhereTheyHaveDepth) {
  // A depth camera whose depth has another shape than the model's (a ramp
  // across the image), a hole (the top quarter) and garbage (a band of huge,
  // negative, NaN and implausibly near readings): with kPoints each pixel
  // with a plausible depth takes it, and the rest keep the model's depth at
  // the frame's depth-image scale, exactly as kScale maps every pixel.
  const Footage f = render(5, [](int) { return 0.5; });
  std::vector<cv::Mat> camera;
  for (const cv::Mat& d : f.depth) {
    cv::Mat c = d.clone();
    for (int y = 0; y < c.rows; ++y) {
      for (int x = 0; x < c.cols; ++x) {
        const float ramped = c.at<float>(y, x) * (1.0f + 0.3f * x / kW);
        const float garbage[] = {1e30f, -2.0f, NAN, 0.1f * ramped};
        c.at<float>(y, x) = y < kH / 4                       ? 0.0f
                            : y >= kH / 2 && y < kH / 2 + 40 ? garbage[x % 4]
                                                             : ramped;
      }
    }
    camera.push_back(c);
  }
  auto source = [&](double stamp_s) {
    return camera[static_cast<std::size_t>(std::lround(stamp_s / 0.1))];
  };
  Reconstruction points(std::make_unique<test::FakeModel>(&f.pts_W0), keyframes_config());
  Reconstruction scaled(std::make_unique<test::FakeModel>(&f.pts_W0), keyframes_config());
  points.set_calibration(f.seq.config.intrinsics);
  scaled.set_calibration(f.seq.config.intrinsics);
  points.set_tracker_depth_source(source, Reconstruction::DepthImageUse::kPoints);
  scaled.set_tracker_depth_source(source);  // kScale, the default
  const std::vector<FrameResult> a = run(points, f.bgr), b = run(scaled, f.bgr);
  ASSERT_EQ(a.size(), b.size());
  PreprocessConfig pre;
  pre.width = pre.height = kSize;
  const PixelMapping to_source = plan_resize_crop(kW, kH, pre).model_to_source;
  for (std::size_t k = 1; k < a.size(); ++k) {
    ASSERT_TRUE(a[k].pose.ok() && b[k].pose.ok()) << k;
    EXPECT_TRUE(a[k].pose.T_W_C.isApprox(b[k].pose.T_W_C, 1e-9)) << k;  // one tracker
    const cv::Mat measured = depth_at_model_pixels(camera[k], to_source, kSize, kSize);
    const cv::Mat truth = depth_at_model_pixels(f.depth[k], to_source, kSize, kSize);
    int from_camera = 0, from_model = 0, reshaped = 0, garbage = 0;
    for (int v = 0; v < kSize; ++v) {
      for (int u = 0; u < kSize; ++u) {
        const cv::Vec3f p = a[k].points_C.at<cv::Vec3f>(v, u),
                        q = b[k].points_C.at<cv::Vec3f>(v, u);
        const float m = measured.at<float>(v, u);
        if (!std::isfinite(q[2])) continue;  // no model depth here
        const float t = truth.at<float>(v, u);
        if (m > 0.0f && m <= 1.5f * t && m >= 0.5f * t) {  // the ramp: at most 1.3x
          EXPECT_NEAR(p[2], m, 1e-5f * m) << k << " " << u << "," << v;
          EXPECT_NEAR(p[0] / p[2], q[0] / q[2], 1e-5f) << k;  // the model's ray
          if (std::abs(p[2] - q[2]) > 0.02f * m) ++reshaped;
          ++from_camera;
        } else {
          EXPECT_NEAR(cv::norm(p - q), 0.0, 1e-6 * cv::norm(q)) << k << " " << u << "," << v;
          ++from_model;
          if (m != 0.0f) ++garbage;
        }
      }
    }
    EXPECT_GT(from_camera, kSize * kSize / 2) << k;
    EXPECT_GT(from_model, kSize * kSize / 8) << k;
    EXPECT_GT(garbage, kSize * 3) << k;         // the band's rows, each reading but the zeros
    EXPECT_GT(reshaped, from_camera / 4) << k;  // not one scale for the frame
  }
}

TEST(ReconstructionKeyframes, TheTrueDepthControlRefusesADepthImageOfAnotherSize) {
  const Footage f = render(3, [](int) { return 1.0; });
  Reconstruction rec(std::make_unique<test::FakeModel>(&f.pts_W0), keyframes_config());
  rec.set_calibration(f.seq.config.intrinsics);
  rec.set_tracker_depth_source([](double) { return cv::Mat(10, 10, CV_32FC1, cv::Scalar(1.0f)); });
  try {
    run(rec, f.bgr);
    FAIL() << "no error";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("10x10 is not registered"), std::string::npos) << e.what();
  }
}

TEST(ReconstructionKeyframes, TheModelsPoseMethodRunsNoTracker) {
  const Footage f = render(3, [](int) { return 1.0; });
  Reconstruction rec(std::make_unique<test::FakeModel>(&f.pts_W0),
                     test::gt_reconstruction_config());
  rec.set_calibration(f.seq.config.intrinsics);
  for (const FrameResult& r : run(rec, f.bgr)) EXPECT_FALSE(r.tracking.has_value());
}

// ------------------------------------------------------------ relocalisation

double one(int) { return 1.0; }

// Pointmaps as a model would give them in another world: `T` times the truth.
std::vector<cv::Mat> moved(const std::vector<cv::Mat>& pts, const Eigen::Isometry3d& T) {
  std::vector<cv::Mat> out;
  const Eigen::Isometry3f Tf = T.cast<float>();
  for (const cv::Mat& p : pts) {
    cv::Mat q = p.clone();
    for (int i = 0; i < q.rows * q.cols; ++i) {
      cv::Vec3f& x = q.at<cv::Vec3f>(i);
      if (!std::isfinite(x[2])) continue;
      const Eigen::Vector3f y = Tf * Eigen::Vector3f(x[0], x[1], x[2]);
      x = cv::Vec3f(y.x(), y.y(), y.z());
    }
    out.push_back(q);
  }
  return out;
}

// A far-off world: the model's own pose of a revisited frame is 1 m and 25
// degrees from the truth.
Eigen::Isometry3d wrong_world() {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = Eigen::AngleAxisd(25.0 * M_PI / 180.0, Eigen::Vector3d::UnitY()).toRotationMatrix();
  T.translation() = Eigen::Vector3d(1.0, -0.3, 0.5);
  return T;
}

constexpr int kSaved = 12;  // frames of the saved stream

// The saved stream: frames 0..kSaved-1 of `a`; the model then returns
// `after` for the frames pushed after the restore.
struct Restored {
  std::vector<cv::Mat> pts;
  std::unique_ptr<Reconstruction> rec;
  StateDict saved;
};
std::unique_ptr<Restored> restored(const Footage& a, const std::vector<cv::Mat>& after) {
  auto out = std::make_unique<Restored>();
  out->pts.assign(a.pts_W0.begin(), a.pts_W0.begin() + kSaved);
  out->pts.insert(out->pts.end(), after.begin(), after.end());
  Reconstruction first(std::make_unique<test::FakeModel>(&out->pts), keyframes_config());
  first.set_calibration(a.seq.config.intrinsics);
  run(first, std::vector<cv::Mat>(a.bgr.begin(), a.bgr.begin() + kSaved));
  out->saved = first.state();
  out->rec = std::make_unique<Reconstruction>(std::make_unique<test::FakeModel>(&out->pts),
                                              keyframes_config());
  out->rec->set_calibration(a.seq.config.intrinsics);
  out->rec->restore(out->saved);
  return out;
}

// The results of `images` pushed after the restore (the first push returns
// the saved stream's last frame again, which the reconstruction drops).
std::vector<FrameResult> continue_with(Reconstruction& rec, const std::vector<cv::Mat>& images) {
  std::vector<FrameResult> results;
  for (std::size_t k = 0; k < images.size(); ++k) {
    if (auto r = rec.push(images[k], "bgr8", 10.0 + 0.1 * static_cast<double>(k))) {
      results.push_back(std::move(*r));
    }
  }
  results.push_back(*rec.flush());
  return results;
}

TEST(Relocalisation, ARestoredStreamPlacesTheSamePlaceByItsImagesNotByTheModel) {
  const Footage a = render(kSaved, one);
  // Frames 4..9 again, the model's pointmaps in a world 1 m and 25 degrees off.
  const std::vector<int> revisit{4, 5, 6, 7, 8, 9};
  std::vector<cv::Mat> pts, images;
  for (int k : revisit) {
    pts.push_back(a.pts_W0[static_cast<std::size_t>(k)]);
    images.push_back(a.bgr[static_cast<std::size_t>(k)]);
  }
  auto r = restored(a, moved(pts, wrong_world()));
  const std::size_t kept = read_keyframes(StateReader(r->saved, "saved", "keyframes.")).size();
  EXPECT_GE(kept, 2u);
  const std::size_t map_before = r->rec->map().size();
  const std::vector<FrameResult> results = continue_with(*r->rec, images);
  ASSERT_EQ(results.size(), revisit.size());
  for (std::size_t i = 0; i < results.size(); ++i) {
    const FrameResult& f = results[i];
    ASSERT_TRUE(f.tracking.has_value()) << i;
    ASSERT_TRUE(f.pose.ok()) << i << ": " << f.pose.message;
    EXPECT_EQ(f.tracking->status, i == 0 ? TrackStatus::kRelocalised : TrackStatus::kTracked) << i;
    const Eigen::Isometry3d truth = a.T_0_k[static_cast<std::size_t>(revisit[i])];
    // The model's own pose is where its world put it; the images' is the truth.
    EXPECT_GT((f.model_T_W_C.translation() - truth.translation()).norm(), 0.5) << i;
    // Where the saved stream put the same frame (its own drift reaches
    // 2.6 cm and 0.7 degrees by frame 9 of the truth): the path goes on in
    // the saved map.
    const Eigen::Isometry3d saved =
        r->rec->trajectory()[static_cast<std::size_t>(revisit[i])].second;
    const Eigen::Isometry3d d = saved.inverse() * f.pose.T_W_C;
    EXPECT_LT(d.translation().norm(), 0.03) << i;
    EXPECT_LT(Eigen::AngleAxisd(d.rotation()).angle(), 0.01) << i;
    const Eigen::Isometry3d e = truth.inverse() * f.pose.T_W_C;
    EXPECT_LT(e.translation().norm(), 0.04) << i;
    EXPECT_LT(Eigen::AngleAxisd(e.rotation()).angle(), 0.015) << i;
    EXPECT_TRUE(f.added_to_map) << i;
  }
  EXPECT_GT(results[0].tracking->inliers, keyframes_config().tracker.relocalisation_min_inliers);
  EXPECT_LT(results[0].tracking->depth_error, 0.05);
  EXPECT_GT(r->rec->map().size(), map_before);
}

TEST(Relocalisation, AFrameAfterALostPoseIsRelocalisedByTheImages) {
  Footage f = render(6, one);
  f.pts_W0[3].setTo(cv::Scalar::all(NAN));  // the model's pose fails on frame 3
  ReconstructionConfig config = keyframes_config();
  config.tracker.when_lost = WhenLost::kRelocalise;
  Reconstruction rec(std::make_unique<test::FakeModel>(&f.pts_W0), config);
  rec.set_calibration(f.seq.config.intrinsics);
  const std::vector<FrameResult> results = run(rec, f.bgr);
  ASSERT_EQ(results.size(), 6u);
  EXPECT_FALSE(results[3].pose.ok());
  EXPECT_FALSE(results[3].tracking.has_value());
  ASSERT_TRUE(results[4].tracking.has_value());
  EXPECT_EQ(results[4].tracking->status, TrackStatus::kRelocalised);
  EXPECT_EQ(results[5].tracking->status, TrackStatus::kTracked);
  for (int k : {4, 5}) {
    const Eigen::Isometry3d d = f.T_0_k[static_cast<std::size_t>(k)].inverse() *
                                results[static_cast<std::size_t>(k)].pose.T_W_C;
    EXPECT_LT(d.translation().norm(), 0.03) << k;
    EXPECT_LT(Eigen::AngleAxisd(d.rotation()).angle(), 0.01) << k;
  }
}

// A cut to another scene mid-stream (tracker_when_lost relocalise): its
// frames are neither posed nor mapped and the path does not
// move; back in the first scene the images place the stream again.
TEST(Relocalisation, ACutToAnotherSceneNeitherMovesThePathNorTheMap) {
  const Footage a = render(8, one);
  const Footage b = render(4, one, /*seed=*/77);
  std::vector<cv::Mat> images, points;
  auto add = [&](const Footage& f, int from, int to) {
    for (int k = from; k < to; ++k) {
      images.push_back(f.bgr[static_cast<std::size_t>(k)]);
      points.push_back(f.pts_W0[static_cast<std::size_t>(k)]);
    }
  };
  add(a, 0, 6);
  add(b, 0, 4);
  add(a, 6, 8);
  ReconstructionConfig config = keyframes_config();
  config.tracker.when_lost = WhenLost::kRelocalise;
  Reconstruction rec(std::make_unique<test::FakeModel>(&points), config);
  rec.set_calibration(a.seq.config.intrinsics);
  const std::vector<FrameResult> results = run(rec, images);
  ASSERT_EQ(results.size(), 12u);
  ASSERT_TRUE(results[6].tracking.has_value());
  EXPECT_EQ(results[6].tracking->status, TrackStatus::kLost) << results[6].tracking->message;
  EXPECT_NE(results[6].pose.message.find("tracking lost: "), std::string::npos);
  for (int k = 6; k < 10; ++k) {
    const FrameResult& f = results[static_cast<std::size_t>(k)];
    if (k > 6) {
      EXPECT_EQ(f.tracking->status, TrackStatus::kRefused) << k;
    }
    EXPECT_EQ(f.pose.status, PnpStatus::kNotRelocalised) << k;
    EXPECT_FALSE(f.added_to_map) << k;
  }
  EXPECT_EQ(results[10].tracking->status, TrackStatus::kRelocalised)
      << results[10].tracking->message;
  EXPECT_EQ(results[11].tracking->status, TrackStatus::kTracked);
  // The path: a's 8 frames, each where it is.
  const auto path = rec.trajectory();
  ASSERT_EQ(path.size(), 8u);
  for (std::size_t i = 0; i < path.size(); ++i) {
    EXPECT_LT((path[i].second.translation() - a.T_0_k[i].translation()).norm(), 0.03) << i;
  }
}

TEST(Relocalisation, AnotherPlaceIsRefusedNotPostedAndNotMapped) {
  const Footage a = render(kSaved, one);
  const Footage b = render(6, one, /*seed=*/77);
  auto r = restored(a, b.pts_W0);  // the model poses b in its own world
  const std::size_t map_before = r->rec->map().size();
  const std::size_t path_before = r->rec->trajectory().size();
  std::vector<cv::Mat> images = b.bgr;
  images[2] = cv::Mat(kH, kW, CV_8UC3, cv::Scalar(0, 0, 0));  // no features: refused too
  const std::vector<FrameResult> results = continue_with(*r->rec, images);
  ASSERT_EQ(results.size(), b.bgr.size());
  for (const FrameResult& f : results) {
    ASSERT_TRUE(f.tracking.has_value());
    EXPECT_EQ(f.tracking->status, TrackStatus::kRefused) << f.tracking->message;
    EXPECT_EQ(f.pose.status, PnpStatus::kNotRelocalised);
    EXPECT_FALSE(f.posed());
    EXPECT_FALSE(f.added_to_map);
    EXPECT_NE(f.pose.message.find(f.frame_index == kSaved + 2
                                      ? "relocalisation refused: 0 features in the image"
                                      : "relocalisation refused: not placed against"),
              std::string::npos)
        << f.pose.message;
    EXPECT_TRUE(f.points_C.empty());
  }
  EXPECT_EQ(r->rec->map().size(), map_before);
  EXPECT_EQ(r->rec->trajectory().size(), path_before);
}

TEST(Relocalisation, AStreamWithoutKeptKeyframesStartsAKeyframeWhereTheModelPutsIt) {
  // A session saved before the keyframes were kept (or by pose_method
  // model): the next frame starts a keyframe at the model's pose.
  const Footage a = render(kSaved + 3, one);
  auto r = restored(a, std::vector<cv::Mat>(a.pts_W0.begin() + kSaved, a.pts_W0.end()));
  StateDict older = r->saved;
  for (auto it = older.begin(); it != older.end();) {
    it = it->first.rfind("keyframes.", 0) == 0 ? older.erase(it) : std::next(it);
  }
  r->rec->restore(older);
  const std::vector<FrameResult> results =
      continue_with(*r->rec, std::vector<cv::Mat>(a.bgr.begin() + kSaved, a.bgr.end()));
  ASSERT_EQ(results.size(), 3u);
  EXPECT_EQ(results[0].tracking->status, TrackStatus::kKeyframe);
  EXPECT_EQ(results[1].tracking->status, TrackStatus::kTracked);
}

TEST(Relocalisation, KeptKeyframesRoundTripAndDamageIsRefusedByName) {
  const Footage a = render(kSaved, one);
  auto r = restored(a, {});
  const StateReader reader(r->saved, "saved reconstruction", "keyframes.");
  const std::vector<KeptKeyframe> kept = read_keyframes(reader);
  ASSERT_FALSE(kept.empty());
  // Written again, read again: the same keyframes (float32 points and rays).
  StateDict again;
  put_keyframes(again, "", std::deque<KeptKeyframe>(kept.begin(), kept.end()));
  const std::vector<KeptKeyframe> back = read_keyframes(StateReader(again, "again"));
  ASSERT_EQ(back.size(), kept.size());
  for (std::size_t i = 0; i < kept.size(); ++i) {
    ASSERT_EQ(back[i].pixels.size(), kept[i].pixels.size());
    EXPECT_TRUE(back[i].T_W_K.isApprox(kept[i].T_W_K, 0.0));
    EXPECT_EQ(cv::norm(back[i].descriptors, kept[i].descriptors, cv::NORM_HAMMING), 0.0);
    EXPECT_DOUBLE_EQ(back[i].median_depth, kept[i].median_depth);
    for (std::size_t j = 0; j < kept[i].pixels.size(); ++j) {
      EXPECT_EQ(back[i].pixels[j], kept[i].pixels[j]);
      ASSERT_EQ(back[i].points[j].has_value(), kept[i].points[j].has_value());
    }
  }

  auto refused = [&](const std::string& key, const at::Tensor& t, const std::string& expect) {
    StateDict bad = r->saved;
    bad["keyframes." + key] = t;
    Reconstruction other(std::make_unique<test::FakeModel>(&a.pts_W0), keyframes_config());
    try {
      other.restore(bad);
      ADD_FAILURE() << key << ": not refused";
    } catch (const StateError& e) {
      EXPECT_NE(std::string(e.what()).find(expect), std::string::npos) << e.what();
    }
    EXPECT_EQ(other.frames_pushed(), 0);  // nothing changed
  };
  const at::Tensor& offsets = r->saved.at("keyframes.offsets");
  refused("version", at::full({}, 2, at::kLong), "keyframes.version");
  at::Tensor down = offsets.clone();
  down[1] = offsets[offsets.size(0) - 1] + 1;
  refused("offsets", down, "keyframes.offsets");
  at::Tensor rays = r->saved.at("keyframes.bearings").clone();
  rays[0] *= 2.0;
  refused("bearings", rays, "keyframes.bearings: feature 0: not a unit ray");
  at::Tensor points = r->saved.at("keyframes.points").clone();
  points[0][0] = std::nanf("");
  points[0][1] = 1.0f;
  points[0][2] = 1.0f;
  refused("points", points, "keyframes.points: feature 0");
  const int64_t n = r->saved.at("keyframes.descriptors").size(0);
  refused("descriptors", at::zeros({n, 16}, at::kByte), "keyframes.descriptors");
  at::Tensor poses = r->saved.at("keyframes.T_W_K").clone();
  poses[0][0][0] = 2.0;
  refused("T_W_K", poses, "keyframes.T_W_K: keyframe 0: not a rigid transform");
}

TEST(Relocalisation, ASavedSessionRelocalisesByImagesAndCountsWhatItRefuses) {
  // Through LiveSession's session files: the keyframes are saved and read
  // back; a frame of another place is refused and counted, then the same
  // place is found again.
  const Footage a = render(kSaved, one);
  const Footage b = render(3, one, /*seed=*/77);
  std::vector<cv::Mat> pts(a.pts_W0.begin(), a.pts_W0.end());
  pts.insert(pts.end(), b.pts_W0.begin(), b.pts_W0.end());
  for (int k : {6, 7, 8}) pts.push_back(a.pts_W0[static_cast<std::size_t>(k)]);
  const std::string path = test::scratch_dir("relocalisation") + "/site.l3s";
  auto push = [&](LiveSession& s, const cv::Mat& image, double stamp, int tag) {
    s.push(live_frame(a, image, stamp, tag));
  };
  {
    test::Recorder client;
    LiveSession s(std::make_unique<test::FakeModel>(&pts), keyframes_config(), {}, client);
    for (int k = 0; k < kSaved; ++k) push(s, a.bgr[static_cast<std::size_t>(k)], 1.0 + 0.1 * k, k);
    s.save(path);
  }
  test::Recorder client;
  LiveSession s(std::make_unique<test::FakeModel>(&pts), keyframes_config(), {}, client);
  s.load(path);
  int tag = kSaved;
  for (const cv::Mat& image : b.bgr) push(s, image, 20.0 + 0.1 * tag, tag), ++tag;
  for (int k : {6, 7, 8}) push(s, a.bgr[static_cast<std::size_t>(k)], 20.0 + 0.1 * tag, tag), ++tag;
  s.flush();
  const LiveStatus st = s.status();
  EXPECT_EQ(st.relocalisations_refused, 3u);
  EXPECT_EQ(st.relocalisations, 1u);
  EXPECT_EQ(st.relocalisation_attempts, 4u);
  EXPECT_EQ(st.tracking, "ok");
  EXPECT_NE(client.event("relocalised at frame 15 by the images"), nullptr);
  EXPECT_NE(client.event("relocalisation refused: not placed against"), nullptr);
  EXPECT_EQ(st.streams, 2u);  // the first and the loaded one, which went on
  EXPECT_EQ(client.results.size(), 6u);
}

// ------------------------------------------------------- odometry for the tracker's prior

// Answers the odometry's camera poses, but for `missing`.
struct OdometryClient : test::Recorder {
  std::vector<Eigen::Isometry3d> T_O_C;
  int missing = -1;
  std::vector<int> asked;
  Eigen::Isometry3d odometry_camera_m(const std::any& tag) override {
    const int k = std::any_cast<int>(tag);
    asked.push_back(k);
    if (k == missing) throw Unavailable("tf odometry", "no odometry at frame " + std::to_string(k));
    return T_O_C[static_cast<std::size_t>(k)];
  }
};

TEST(ReconstructionKeyframes, LiveSessionGivesTheTrackerItsClientsOdometry) {
  // tracker_motion_prior odometry through LiveSession: a dark frame moves
  // from the last placed one as the client's odometry did, whole in a
  // metric stream (scale_source fixed), by its rotation only in model
  // units; a frame the client has no odometry for is named in a warning
  // and costs only that frame's odometry.
  const Footage f = render(6, one);
  std::vector<cv::Mat> images = f.bgr;
  images[3] = cv::Mat(kH, kW, CV_8UC3, cv::Scalar(0, 0, 0));
  ReconstructionConfig config = keyframes_config();
  config.tracker.motion_prior = MotionPrior::kOdometry;
  for (const ScaleSource source : {ScaleSource::kFixed, ScaleSource::kNone}) {
    OdometryClient client;
    client.T_O_C = wobbly_odometry(f);
    client.missing = 1;
    LiveSessionConfig session;
    session.scale.source = source;
    LiveSession s(std::make_unique<test::FakeModel>(&f.pts_W0), config, session, client);
    for (int k = 0; k < static_cast<int>(images.size()); ++k) {
      s.push(live_frame(f, images[static_cast<std::size_t>(k)], 1.0 + 0.1 * k, k));
    }
    s.flush();
    ASSERT_EQ(client.results.size(), images.size());
    const FrameResult& dark = client.results[3].frame;
    ASSERT_TRUE(dark.tracking.has_value());
    ASSERT_EQ(dark.tracking->status, TrackStatus::kTooFewFeatures);
    const Eigen::Isometry3d& T1 = client.results[1].frame.pose.T_W_C;
    const Eigen::Isometry3d& T2 = client.results[2].frame.pose.T_W_C;
    const Eigen::Isometry3d odometry_step = client.T_O_C[2].inverse() * client.T_O_C[3];
    Eigen::Isometry3d step = T1.inverse() * T2;
    step.linear() = odometry_step.linear();
    if (source == ScaleSource::kFixed) step.translation() = odometry_step.translation();
    const Eigen::Isometry3d d = (T2 * step).inverse() * dark.pose.T_W_C;
    EXPECT_LT(d.translation().norm(), 1e-9);
    EXPECT_LT(Eigen::AngleAxisd(d.rotation()).angle(), 1e-9);
    const LiveEvent* missing = client.event("no odometry at frame 1");
    ASSERT_NE(missing, nullptr);
    EXPECT_EQ(missing->kind, "tf odometry");
    EXPECT_NE(missing->message.find("tracker_motion_prior odometry"), std::string::npos);
    EXPECT_FALSE(missing->frame_dropped);
    for (int k : {1, 2, 4, 5}) {
      EXPECT_TRUE(client.results[static_cast<std::size_t>(k)].frame.tracking->posed()) << k;
    }
  }
}

// With scale_source odometry as well, the odometry the prior asked for also
// gives the frame's scale sample: one question a frame, but where the client
// had no answer (asked again for the scale, and warned again).
TEST(ReconstructionKeyframes, TheOdometryPriorAndScaleAskOnceAFrame) {
  const Footage f = render(6, one);
  ReconstructionConfig config = keyframes_config();
  config.tracker.motion_prior = MotionPrior::kOdometry;
  OdometryClient client;
  client.T_O_C = wobbly_odometry(f);
  client.missing = 1;
  LiveSessionConfig session;
  session.scale.source = ScaleSource::kOdometry;
  LiveSession s(std::make_unique<test::FakeModel>(&f.pts_W0), config, session, client);
  for (int k = 0; k < static_cast<int>(f.bgr.size()); ++k) {
    s.push(live_frame(f, f.bgr[static_cast<std::size_t>(k)], 1.0 + 0.1 * k, k));
  }
  s.flush();
  ASSERT_EQ(client.results.size(), f.bgr.size());
  EXPECT_EQ(client.asked, (std::vector<int>{0, 1, 1, 2, 3, 4, 5}));
}

// ------------------------------------------------------- a depth camera for the tracker

// Answers depth from the footage's depth images (metres), but for `missing`.
struct DepthClient : test::Recorder {
  const Footage* footage = nullptr;
  std::vector<int> asked;
  int missing = -1;
  cv::Mat depth(const std::any& tag) override {
    const int k = std::any_cast<int>(tag);
    asked.push_back(k);
    if (k == missing)
      throw Unavailable("depth missing", "no depth image for frame " + std::to_string(k));
    return footage->depth[static_cast<std::size_t>(k)];
  }
};

void push_footage(LiveSession& s, const Footage& f) {
  for (int k = 0; k < static_cast<int>(f.bgr.size()); ++k) {
    s.push(live_frame(f, f.bgr[static_cast<std::size_t>(k)], 1.0 + 0.1 * k, k));
  }
  s.flush();
}

// The model's scale wanders by 15 % from frame to frame about half a metre
// a unit.
double wandering(int k) { return 0.5 * (1.0 + 0.15 * std::sin(1.3 * k)); }

TEST(DepthCameraTracking, TheDepthImagesPlaceAndScaleEveryFrameFromTheFirst) {
  // An RGB-D camera (scale_source depth) with pose_method keyframes: the
  // stream is metric from frame 0's result, the tracker lifts the later
  // frames by their depth images (no scale of its own), and the map gets
  // each frame's points at its own depth image's scale, in metres.
  const Footage f = render(12, wandering);
  DepthClient client;
  client.footage = &f;
  LiveSessionConfig config;
  config.scale.source = ScaleSource::kDepth;
  LiveSession s(std::make_unique<test::FakeModel>(&f.pts_W0), keyframes_config(), config, client);
  ASSERT_NE(client.event("lifts its features by the depth images"), nullptr);
  push_footage(s, f);
  const LiveStatus st = s.status();
  ASSERT_TRUE(st.scale_metric);
  EXPECT_NEAR(st.scale, 1.0 / wandering(0), 1e-3);  // frame 0's, kept
  EXPECT_EQ(st.scale_estimate.samples, 1);
  ASSERT_EQ(client.results.size(), f.bgr.size());
  std::vector<int> once(f.bgr.size());
  std::iota(once.begin(), once.end(), 0);
  EXPECT_EQ(client.asked, once);  // one depth image a frame, for the scale and the tracker
  for (const LiveResult& r : client.results) {
    const int k = std::any_cast<int>(r.tag);
    const std::size_t i = static_cast<std::size_t>(k);
    ASSERT_TRUE(r.frame.tracking && r.frame.tracking->posed()) << k;
    EXPECT_EQ(r.frame.scale, st.scale) << k;  // metric from the first result
    if (k > 0) {
      EXPECT_EQ(r.frame.tracking->scale, 1.0) << k;  // lifted by its depth image
    }
    // In metres; within the tracker's error on this footage (about 15 % of
    // the travel, as with the true depth above).
    const Eigen::Vector3d truth = f.T_0_k[i].translation(), t = r.frame.pose.T_W_C.translation();
    EXPECT_LT((t - truth).norm(), 0.01 + 0.15 * truth.norm()) << k;
    if (truth.norm() > 0.1) {
      EXPECT_NEAR(t.norm() / truth.norm(), 1.0, 0.1) << k;
    }
    ASSERT_TRUE(r.frame.added_to_map) << k;
    const cv::Vec3f w = r.frame.points_W.at<cv::Vec3f>(kSize / 2, kSize / 2);
    const cv::Vec3f m = f.pts_W0[i].at<cv::Vec3f>(kSize / 2, kSize / 2);
    const Eigen::Vector3d expected = Eigen::Vector3d(m[0], m[1], m[2]) / wandering(k);
    EXPECT_LT((Eigen::Vector3d(w[0], w[1], w[2]) - expected).norm(), 0.01 + 0.01 * expected.norm())
        << k;
  }
  EXPECT_GT(s.reconstruction().map().size(), 0u);

  // The same stream without the depth images for the tracker: it measures
  // each frame's scale against the keyframe's, as for a monocular camera.
  DepthClient monocular;
  monocular.footage = &f;
  config.tracker_depth_images = false;
  LiveSession m(std::make_unique<test::FakeModel>(&f.pts_W0), keyframes_config(), config,
                monocular);
  EXPECT_EQ(monocular.event("lifts its features by the depth images"), nullptr);
  push_footage(m, f);
  int measured = 0, in_model_units = 0;
  for (const LiveResult& r : monocular.results) {
    if (r.frame.tracking && r.frame.tracking->scale_measured && r.frame.tracking->scale != 1.0) {
      ++measured;
    }
    if (!r.scale_changed && r.frame.scale == 1.0) ++in_model_units;
  }
  EXPECT_GE(measured, 8);
  EXPECT_GE(in_model_units, 3);  // until scale_min_samples depth samples agree
}

TEST(DepthCameraTracking, TheMapTakesTheDepthImagesDepthUnlessTurnedOff) {
  // A depth camera whose depth grows across the image against the model's:
  // with map_depth_images (the default) each pixel is at the camera's depth;
  // without it, at the model's depth times the frame's one depth ratio.
  const Footage f = render(6, wandering);
  Footage ramped = f;
  for (cv::Mat& d : ramped.depth) {
    d = d.clone();
    for (int y = 0; y < d.rows; ++y) {
      for (int x = 0; x < d.cols; ++x) d.at<float>(y, x) *= 1.0f + 0.3f * x / kW;
    }
  }
  PreprocessConfig pre;
  pre.width = pre.height = kSize;
  const PixelMapping to_source = plan_resize_crop(kW, kH, pre).model_to_source;
  for (const bool map_depth : {true, false}) {
    DepthClient client;
    client.footage = &ramped;
    LiveSessionConfig config;
    config.scale.source = ScaleSource::kDepth;
    config.map_depth_images = map_depth;
    LiveSession s(std::make_unique<test::FakeModel>(&f.pts_W0), keyframes_config(), config, client);
    push_footage(s, f);
    ASSERT_EQ(client.results.size(), f.bgr.size()) << map_depth;
    for (const LiveResult& r : client.results) {
      const int k = std::any_cast<int>(r.tag);
      ASSERT_TRUE(r.frame.added_to_map) << k;
      // Frame 0 makes the stream metric: it is mapped before its depth
      // image's scale is known, so at that scale, as without the option.
      if (k == 0) continue;
      const cv::Mat measured =
          depth_at_model_pixels(ramped.depth[static_cast<std::size_t>(k)], to_source, kSize, kSize);
      for (const int u : {4, kSize - 4}) {  // the ramp's two ends
        const float m = measured.at<float>(kSize / 2, u);
        const float z = r.frame.points_C.at<cv::Vec3f>(kSize / 2, u)[2];
        ASSERT_GT(m, 0.0f) << k;
        if (map_depth) {
          EXPECT_NEAR(z, m, 1e-4f * m) << k << " " << u;
        } else {
          EXPECT_GT(std::abs(z - m), 0.03f * m) << k << " " << u;
        }
      }
    }
  }
}

TEST(DepthCameraTracking, AFrameWithoutItsDepthImageIsTrackedByTheModelsDepth) {
  const Footage f = render(10, wandering);
  DepthClient client;
  client.footage = &f;
  client.missing = 6;
  LiveSessionConfig config;
  config.scale.source = ScaleSource::kDepth;
  LiveSession s(std::make_unique<test::FakeModel>(&f.pts_W0), keyframes_config(), config, client);
  push_footage(s, f);
  const LiveEvent* e = client.event("no depth image for frame 6");
  ASSERT_NE(e, nullptr);
  EXPECT_EQ(e->kind, "depth missing");
  ASSERT_EQ(client.results.size(), f.bgr.size());
  const LiveResult& r = client.results[6];
  ASSERT_TRUE(r.frame.tracking && r.frame.tracking->posed()) << r.frame.tracking->message;
  // Its scale against the stream's, measured by the tracker at its matches.
  EXPECT_TRUE(r.frame.tracking->scale_measured);
  EXPECT_NEAR(r.frame.tracking->scale * wandering(6) * s.status().scale, 1.0, 0.03);
  for (const LiveResult& q : client.results) {
    const int k = std::any_cast<int>(q.tag);
    const Eigen::Vector3d truth = f.T_0_k[static_cast<std::size_t>(k)].translation();
    EXPECT_LT((q.frame.pose.T_W_C.translation() - truth).norm(), 0.01 + 0.15 * truth.norm()) << k;
  }
}

// ------------------------------------------------------- scale from odometry

TEST(ScaleFromOdometry, FramesPlacedByOdometryMeasureTheScaleByTheirImages) {
  // A monocular camera placed by metric odometry (pose_source odometry,
  // scale_source odometry); the model's units are half a metre and its own
  // poses useless (a world 1 m and 25 degrees off after frame 0): the scale
  // comes from the images over the odometry's baseline, and the map fills.
  const Footage f = render(24, [](int) { return 0.5; });
  std::vector<cv::Mat> pts = f.pts_W0;
  const std::vector<cv::Mat> off = moved(pts, wrong_world());
  std::copy(off.begin() + 1, off.end(), pts.begin() + 1);
  test::Recorder client;
  client.placer = [&](int k) { return f.T_0_k[static_cast<std::size_t>(k)]; };
  LiveSessionConfig config;
  config.scale.source = ScaleSource::kOdometry;
  ReconstructionConfig recon = test::gt_reconstruction_config();  // the model's poses
  LiveSession s(std::make_unique<test::FakeModel>(&pts), recon, config, client);
  int metric_from = -1;
  for (int k = 0; k < static_cast<int>(f.bgr.size()); ++k) {
    s.push(live_frame(f, f.bgr[static_cast<std::size_t>(k)], 1.0 + 0.1 * k, k));
    if (metric_from < 0 && s.status().scale_metric) metric_from = k;
  }
  s.flush();
  const LiveStatus st = s.status();
  ASSERT_TRUE(st.scale_metric) << st.scale_estimate.samples << " samples";
  EXPECT_LE(metric_from, 20);
  EXPECT_NEAR(st.scale, 2.0, 0.06);  // metres per model unit
  EXPECT_GT(s.reconstruction().map().size(), 0u);
  // Each result after the scale is mapped, where the odometry put it.
  int mapped = 0;
  for (const LiveResult& r : client.results) {
    const int k = std::any_cast<int>(r.tag);
    if (!r.frame.added_to_map) continue;
    ++mapped;
    const cv::Vec3f w = r.frame.points_W.at<cv::Vec3f>(kSize / 2, kSize / 2);
    const cv::Vec3f truth =
        f.pts_W0[static_cast<std::size_t>(k)].at<cv::Vec3f>(kSize / 2, kSize / 2);
    ASSERT_TRUE(std::isfinite(w[2]));
    EXPECT_LT(
        (Eigen::Vector3d(w[0], w[1], w[2]) - Eigen::Vector3d(truth[0], truth[1], truth[2]) / 0.5)
            .norm(),
        0.06)
        << k;
  }
  EXPECT_GE(mapped, 3);
}

}  // namespace
}  // namespace long3r

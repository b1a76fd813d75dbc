// PinholeIntrinsics: calibration through resize + crop, and the Weiszfeld focal
// estimate from a pointmap.
#include <gtest/gtest.h>

#include <opencv2/core.hpp>

#include <cmath>
#include <limits>
#include <stdexcept>

#include "long3r/pipeline/intrinsics.hpp"
#include "support/cv_test_support.hpp"

namespace long3r {
namespace {

// Pointmap of a camera with focal f and principal point at the image centre,
// random depths in [1, 5]; conf 5 everywhere.
void make_pointmap(int w, int h, double f, uint64_t seed, cv::Mat& pts, cv::Mat& conf) {
  const PinholeIntrinsics k{f, f, 0.5 * (w - 1), 0.5 * (h - 1), w, h};
  cv::RNG rng(seed);
  pts = test::pointmap_from_depth(k, Eigen::Isometry3d::Identity(),
                                  [&](int, int) { return rng.uniform(1.0, 5.0); });
  conf = cv::Mat(h, w, CV_32FC1, cv::Scalar(5.0f));
}

// A TUM-like 640 x 480 calibration.
PinholeIntrinsics source_camera() { return {525.0, 523.5, 319.5, 239.5, 640, 480}; }

TEST(PinholeIntrinsics, CalibrationThroughResizeAndCropIsExact) {
  const PinholeIntrinsics src = source_camera();
  cv::RNG rng(7);
  for (const auto& [tw, th] : {std::pair{224, 224}, {512, 384}, {320, 160}, {160, 320}}) {
    PreprocessConfig config;
    config.width = tw;
    config.height = th;
    const ResizeCropPlan plan = plan_resize_crop(src.width, src.height, config);
    const PinholeIntrinsics k = scale_intrinsics(src, plan.model_to_source, tw, th);
    EXPECT_EQ(k.width, tw);
    EXPECT_EQ(k.height, th);
    for (int i = 0; i < 50; ++i) {
      const Eigen::Vector3d X(rng.uniform(-2.0, 2.0), rng.uniform(-1.5, 1.5),
                              rng.uniform(0.5, 6.0));
      const Eigen::Vector2d u_src = src.project(X);
      const Eigen::Vector2d u_model = k.project(X);
      EXPECT_LT((plan.model_to_source.apply(u_model) - u_src).norm(), 1e-9);
      EXPECT_LT((plan.model_to_source.inverse().apply(u_src) - u_model).norm(), 1e-9);
    }
  }
}

TEST(PinholeIntrinsics, ScaledCalibrationMatchesThePreprocessedImage) {
  // A blob drawn where a 3D point projects in the source image lands where the
  // scaled intrinsics project it in the model image.
  const PinholeIntrinsics src = source_camera();
  const Eigen::Vector3d X(0.31, -0.17, 2.0);
  const Eigen::Vector2d s = src.project(X);
  cv::Mat img(src.height, src.width, CV_8UC3);
  for (int v = 0; v < img.rows; ++v) {
    for (int u = 0; u < img.cols; ++u) {
      const double r2 = (u - s.x()) * (u - s.x()) + (v - s.y()) * (v - s.y());
      const auto g = cv::saturate_cast<uchar>(255.0 * std::exp(-r2 / (2 * 10.0 * 10.0)));
      img.at<cv::Vec3b>(v, u) = cv::Vec3b(g, g, g);
    }
  }
  const PreprocessedImage pre = preprocess_image(img, ImageEncoding::kRgb8);
  const std::optional<ResolvedIntrinsics> r = resolve_intrinsics(src, pre, cv::Mat(), cv::Mat());
  ASSERT_TRUE(r.has_value());
  EXPECT_EQ(r->source, IntrinsicsSource::kCalibration);
  double sx = 0, sy = 0, sw = 0;
  for (int v = 0; v < pre.rgb.rows; ++v) {
    for (int u = 0; u < pre.rgb.cols; ++u) {
      const double w = pre.rgb.at<cv::Vec3b>(v, u)[0];
      sx += w * u;
      sy += w * v;
      sw += w;
    }
  }
  const Eigen::Vector2d expected = r->intrinsics.project(X);
  EXPECT_NEAR(sx / sw, expected.x(), 0.02);
  EXPECT_NEAR(sy / sw, expected.y(), 0.02);
}

TEST(PinholeIntrinsics, CalibrationOfAnotherSizeIsRejected) {
  PinholeIntrinsics k = source_camera();
  k.width = 1280;
  k.height = 960;
  const PreprocessedImage pre =
      preprocess_image(cv::Mat(480, 640, CV_8UC3, cv::Scalar::all(9)), ImageEncoding::kRgb8);
  EXPECT_THROW(resolve_intrinsics(k, pre, cv::Mat(), cv::Mat()), std::invalid_argument);
  PinholeIntrinsics bad;
  EXPECT_THROW(scale_intrinsics(bad, PixelMapping{}, 224, 224), std::invalid_argument);
}

TEST(PinholeIntrinsics, WeiszfeldRecoversAKnownFocal) {
  for (const auto& [w, h, f] :
       {std::tuple{224, 224, 250.0}, {512, 384, 400.0}, {160, 224, 130.0}}) {
    cv::Mat pts, conf;
    make_pointmap(w, h, f, 11, pts, conf);
    const std::optional<double> est = estimate_focal_weiszfeld(pts, conf);
    ASSERT_TRUE(est.has_value());
    EXPECT_NEAR(*est, f, 1e-7 * f) << w << "x" << h;
    const std::optional<PinholeIntrinsics> k = estimate_intrinsics(pts, conf);
    ASSERT_TRUE(k.has_value());
    EXPECT_EQ(k->fx, *est);
    EXPECT_EQ(k->fy, *est);
    EXPECT_DOUBLE_EQ(k->cx, 0.5 * (w - 1));
    EXPECT_DOUBLE_EQ(k->cy, 0.5 * (h - 1));
    EXPECT_EQ(k->width, w);
    EXPECT_EQ(k->height, h);
  }
}

// Gross outliers pull the L2 start away; the Weiszfeld iterations (an L1
// fit) bring the focal back close to the truth.
TEST(PinholeIntrinsics, WeiszfeldIsRobustToOutliers) {
  const double f = 250.0;
  cv::Mat pts, conf;
  make_pointmap(224, 224, f, 12, pts, conf);
  cv::RNG rng(13);
  for (int v = 0; v < pts.rows; ++v) {
    for (int u = 0; u < pts.cols; ++u) {
      if (rng.uniform(0.0, 1.0) < 0.2) {
        // Rays twice as wide as the truth: a focal of f / 2 for these pixels.
        cv::Vec3f& p = pts.at<cv::Vec3f>(v, u);
        p[0] *= 2.0f;
        p[1] *= 2.0f;
        conf.at<float>(v, u) = 1.0f;
      }
    }
  }
  FocalEstimationOptions l2;
  l2.iterations = 0;
  const double f_l2 = *estimate_focal_weiszfeld(pts, conf, l2);
  const double f_w = *estimate_focal_weiszfeld(pts, conf);
  EXPECT_GT(std::abs(f_l2 - f), 0.05 * f);  // the outliers matter for L2
  EXPECT_LT(std::abs(f_w - f), 0.002 * f);
  EXPECT_LT(std::abs(f_w - f), 0.01 * std::abs(f_l2 - f));
  // Excluding the outliers by confidence recovers the focal exactly.
  FocalEstimationOptions confident;
  confident.conf_threshold = 2.0f;
  EXPECT_NEAR(*estimate_focal_weiszfeld(pts, conf, confident), f, 1e-7 * f);
}

TEST(PinholeIntrinsics, FocalIsClippedAndNeedsPoints) {
  cv::Mat pts, conf;
  make_pointmap(224, 224, 5000.0, 14, pts, conf);  // very narrow field of view
  const double base = 224 / (2.0 * std::tan(M_PI / 6.0));
  EXPECT_NEAR(*estimate_focal_weiszfeld(pts, conf), 3.5 * base, 1e-9);

  make_pointmap(224, 224, 250.0, 15, pts, conf);
  FocalEstimationOptions options;
  options.conf_threshold = 6.0f;  // nothing passes
  EXPECT_FALSE(estimate_focal_weiszfeld(pts, conf, options).has_value());
  pts.setTo(cv::Scalar::all(std::numeric_limits<float>::quiet_NaN()));
  EXPECT_FALSE(estimate_focal_weiszfeld(pts, cv::Mat()).has_value());
  EXPECT_THROW(estimate_focal_weiszfeld(cv::Mat(4, 4, CV_32FC1), cv::Mat()), std::invalid_argument);
}

TEST(PinholeIntrinsics, ResolveWithoutCalibrationEstimates) {
  cv::Mat pts, conf;
  make_pointmap(224, 224, 180.0, 16, pts, conf);
  const PreprocessedImage pre =
      preprocess_image(cv::Mat(480, 640, CV_8UC3, cv::Scalar::all(9)), ImageEncoding::kRgb8);
  const std::optional<ResolvedIntrinsics> r = resolve_intrinsics(std::nullopt, pre, pts, conf);
  ASSERT_TRUE(r.has_value());
  EXPECT_EQ(r->source, IntrinsicsSource::kEstimatedWeiszfeld);
  EXPECT_STREQ(to_string(r->source), "estimated_weiszfeld");
  EXPECT_NEAR(r->intrinsics.fx, 180.0, 1e-7 * 180.0);
  EXPECT_DOUBLE_EQ(r->intrinsics.cx, 111.5);
  // A pointmap of the wrong size is a caller bug.
  EXPECT_THROW(resolve_intrinsics(std::nullopt, pre, cv::Mat(10, 10, CV_32FC3), conf),
               std::invalid_argument);
}

}  // namespace
}  // namespace long3r

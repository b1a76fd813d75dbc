// Camera calibration without ROS: every field of a CameraModel (camera_info's
// fields) validated and named, binning and ROI, and rectification of each
// distortion model checked against OpenCV's own distortion.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include "long3r/pipeline/camera_rectifier.hpp"
#include "support/cv_test_support.hpp"

namespace long3r {
namespace {

constexpr int kW = 160, kH = 120;

CameraModel info(double fx = 120.0, double fy = 121.0, double cx = 79.5, double cy = 59.5) {
  CameraModel m;
  m.width = kW;
  m.height = kH;
  m.distortion_model = "plumb_bob";
  m.D = {0, 0, 0, 0, 0};
  m.K = {fx, 0, cx, 0, fy, cy, 0, 0, 1};
  m.R = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  m.P = {fx, 0, cx, 0, 0, fy, cy, 0, 0, 0, 1, 0};
  return m;
}

std::string problem(const CameraModel& m, int w = kW, int h = kH) {
  return CameraRectifier::problem(m, w, h);
}

TEST(CameraRectifier, AcceptsAGoodCalibrationAndUsesP) {
  CameraModel m = info();
  EXPECT_EQ(problem(m), "");
  m.P[0] = 118.0;  // rectified image's own focal length
  CameraRectifier c;
  EXPECT_TRUE(c.set(m, false));
  EXPECT_FALSE(c.set(m, false));  // unchanged
  EXPECT_FALSE(c.rectifies());    // no distortion: nothing to remap
  const PinholeIntrinsics k = c.intrinsics();
  EXPECT_DOUBLE_EQ(k.fx, 118.0);
  EXPECT_DOUBLE_EQ(k.fy, 121.0);
  EXPECT_EQ(k.width, kW);
  const cv::Mat img = test::egg_crate_image(kW, kH);
  EXPECT_EQ(c.prepare(img).data, img.data);  // the same image, not a copy
}

TEST(CameraRectifier, NamesEveryBadField) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  auto with = [](auto edit) {
    CameraModel m = info();
    edit(m);
    return m;
  };
  EXPECT_EQ(problem(with([&](auto& m) { m.K[0] = nan; })), "K[0] (fx) is nan");
  EXPECT_EQ(problem(with([&](auto& m) { m.K[2] = inf; })), "K[2] (cx) is inf");
  EXPECT_EQ(problem(with([&](auto& m) { m.K[5] = -inf; })), "K[5] (cy) is -inf");
  EXPECT_EQ(problem(with([&](auto& m) { m.K[4] = -3.0; })), "K[4] (fy) is -3, not positive");
  EXPECT_EQ(problem(with([&](auto& m) { m.K[2] = 500.0; })),
            "K[2] (cx) = 500 is outside the image (width 160)");
  EXPECT_EQ(problem(with([&](auto& m) {
              m.D = {0.1, 0.0, 0.0};
            })),
            "D has 3 coefficients, plumb_bob takes 4, 5 or 8");
  EXPECT_EQ(problem(with([&](auto& m) { m.D[1] = nan; })), "D[1] is nan");
  EXPECT_EQ(problem(with([&](auto& m) { m.distortion_model = "fisheye62"; })),
            "distortion_model 'fisheye62' is not supported (plumb_bob, rational_polynomial, "
            "equidistant)");
  EXPECT_EQ(problem(with([&](auto& m) { m.R[0] = 2.0; })), "R is not a rotation");
  EXPECT_EQ(problem(with([&](auto& m) { m.P[5] = 0.0; })), "P[5] (fy') is 0, not positive");
  EXPECT_EQ(problem(with([&](auto& m) { m.width = 0; })), "width x height is 0x120");
  EXPECT_EQ(problem(with([&](auto& m) { m.width = 320; })),
            "width x height 320x120 gives 320x120 images, but they are 160x120");
  EXPECT_NE(problem(with([&](auto& m) {
              m.roi.x_offset = 100;
              m.roi.width = 100;
              m.roi.height = 50;
            })).find("does not lie inside"),
            std::string::npos);
}

TEST(CameraRectifier, ReadsEmptyFieldsAsDriversMeanThem) {
  CameraModel m = info();
  m.P.fill(0.0);
  m.R.fill(0.0);
  m.distortion_model.clear();
  m.D.clear();
  EXPECT_EQ(problem(m), "");
  CameraRectifier c;
  c.set(m, false);
  EXPECT_DOUBLE_EQ(c.intrinsics().fx, 120.0);  // P taken as [K | 0]
  EXPECT_FALSE(c.rectifies());
}

TEST(CameraRectifier, BinningAndRoiGiveTheIntrinsicsOfTheImage) {
  CameraModel m = info();
  m.width = 2 * kW;
  m.height = 2 * kH;
  m.K = {240, 0, 159.5, 0, 242, 119.5, 0, 0, 1};
  m.P = {240, 0, 159.5, 0, 0, 242, 119.5, 0, 0, 0, 1, 0};
  m.binning_x = m.binning_y = 2;
  ASSERT_EQ(problem(m), "");
  CameraRectifier c;
  c.set(m, false);
  EXPECT_NEAR(c.intrinsics().fx, 120.0, 1e-12);
  EXPECT_EQ(c.intrinsics().width, kW);
  // A 160x120 window at (40, 30) of the 320x240 sensor, unbinned.
  CameraModel r = m;
  r.binning_x = r.binning_y = 0;
  r.roi.x_offset = 40;
  r.roi.y_offset = 30;
  r.roi.width = kW;
  r.roi.height = kH;
  ASSERT_EQ(problem(r), "");
  c.set(r, false);
  EXPECT_NEAR(c.intrinsics().cx, 159.5 - 40, 1e-12);
  EXPECT_NEAR(c.intrinsics().cy, 119.5 - 30, 1e-12);
  EXPECT_EQ(c.intrinsics().height, kH);
}

// A distorted image, rectified, matches the undistorted render:
// distort a pattern with OpenCV's model, rectify it back, compare inside.
TEST(CameraRectifier, RectifiesEachDistortionModel) {
  const cv::Matx33d K(120, 0, 79.5, 0, 121, 59.5, 0, 0, 1);
  struct Case {
    std::string model;
    std::vector<double> D;
  };
  for (const Case& cs : {Case{"plumb_bob", {-0.12, 0.03, 0.001, -0.001, 0.0}},
                         Case{"rational_polynomial", {-0.1, 0.02, 0.0, 0.0, 0.0, 0.01, 0.0, 0.0}},
                         Case{"equidistant", {0.05, -0.01, 0.002, 0.0}}}) {
    SCOPED_TRACE(cs.model);
    const cv::Mat undistorted = test::egg_crate_image(kW, kH);
    // The distorted image: each raw pixel looks up where its ray lands undistorted.
    cv::Mat map_x(kH, kW, CV_32FC1), map_y(kH, kW, CV_32FC1);
    std::vector<cv::Point2f> raw, ideal;
    for (int v = 0; v < kH; ++v)
      for (int u = 0; u < kW; ++u) raw.emplace_back(u, v);
    if (cs.model == "equidistant") {
      cv::fisheye::undistortPoints(raw, ideal, K, cs.D, cv::noArray(), K);
    } else {  // iterated to convergence: the default 5 iterations leave a visible error
      cv::undistortPoints(
          raw, ideal, K, cs.D, cv::noArray(), K,
          cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 100, 1e-9));
    }
    for (int i = 0; i < kW * kH; ++i) {
      map_x.at<float>(i) = ideal[i].x;
      map_y.at<float>(i) = ideal[i].y;
    }
    cv::Mat distorted;
    cv::remap(undistorted, distorted, map_x, map_y, cv::INTER_LINEAR);

    CameraModel m = info(120, 121, 79.5, 59.5);
    m.distortion_model = cs.model;
    m.D = cs.D;
    ASSERT_EQ(problem(m), "");
    CameraRectifier c;
    c.set(m, false);
    ASSERT_TRUE(c.rectifies());
    const cv::Mat rectified = c.prepare(distorted);
    ASSERT_EQ(rectified.size(), undistorted.size());
    // On the egg-crate channel, away from the border: the distortion moves
    // the pattern visibly; after rectification only the rounding of two
    // bilinear resamplings is left.
    const cv::Rect inner(20, 15, kW - 40, kH - 30);
    auto pattern_error = [&](const cv::Mat& img) {
      cv::Mat diff;
      cv::absdiff(img(inner), undistorted(inner), diff);
      return cv::mean(diff)[2];
    };
    const double before = pattern_error(distorted), after = pattern_error(rectified);
    EXPECT_GT(before, 5.0);  // grey levels: the distortion is visible
    EXPECT_LT(after, 0.2 * before) << before;

    // Rectified input is used as it is.
    CameraRectifier as_is;
    as_is.set(m, true);
    EXPECT_FALSE(as_is.rectifies());
  }
}

}  // namespace
}  // namespace long3r

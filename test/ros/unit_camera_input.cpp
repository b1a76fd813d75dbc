// The node's input side without a master: camera_info validation and
// rectification (CameraCalibration), image decoding (decodeInput), per-kind
// log throttling and the diagnostics' sliding window.
#include <gtest/gtest.h>

#include <sensor_msgs/distortion_models.h>
#include <sensor_msgs/image_encodings.h>
#include <boost/make_shared.hpp>

#include <cmath>
#include <limits>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "long3r_ros/camera_calibration.hpp"
#include "long3r_ros/image_input.hpp"
#include "long3r_ros/log_throttle.hpp"
#include "long3r_ros/window_stats.hpp"

using namespace long3r_ros;

namespace {

constexpr int kW = 160, kH = 120;

sensor_msgs::CameraInfo info(double fx = 120.0, double fy = 121.0, double cx = 79.5,
                             double cy = 59.5) {
  sensor_msgs::CameraInfo m;
  m.width = kW;
  m.height = kH;
  m.distortion_model = sensor_msgs::distortion_models::PLUMB_BOB;
  m.D = {0, 0, 0, 0, 0};
  m.K = {fx, 0, cx, 0, fy, cy, 0, 0, 1};
  m.R = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  m.P = {fx, 0, cx, 0, 0, fy, cy, 0, 0, 0, 1, 0};
  return m;
}

// A test image: two gradients and, in the third channel, a smooth egg-crate
// pattern (period 24 px) whose steep slopes make a shift of a pixel visible
// while bilinear resampling stays nearly exact.
cv::Mat pattern(int w = kW, int h = kH) {
  cv::Mat img(h, w, CV_8UC3);
  for (int v = 0; v < h; ++v)
    for (int u = 0; u < w; ++u) {
      const double waves = std::sin(2.0 * M_PI * u / 24.0) * std::sin(2.0 * M_PI * v / 24.0);
      img.at<cv::Vec3b>(v, u) =
          cv::Vec3b(static_cast<uchar>(u * 255 / w), static_cast<uchar>(v * 255 / h),
                    cv::saturate_cast<uchar>(128.0 + 110.0 * waves));
    }
  return img;
}

std::string problem(const sensor_msgs::CameraInfo& m, int w = kW, int h = kH) {
  return CameraCalibration::problem(m, w, h);
}

}  // namespace

TEST(CameraCalibration, AcceptsAGoodCalibrationAndUsesP) {
  sensor_msgs::CameraInfo m = info();
  EXPECT_EQ(problem(m), "");
  m.P[0] = 118.0;  // rectified image's own focal length
  CameraCalibration c;
  EXPECT_TRUE(c.set(m, false));
  EXPECT_FALSE(c.set(m, false));  // unchanged
  EXPECT_FALSE(c.rectifies());    // no distortion: nothing to remap
  const long3r::PinholeIntrinsics k = c.intrinsics();
  EXPECT_DOUBLE_EQ(k.fx, 118.0);
  EXPECT_DOUBLE_EQ(k.fy, 121.0);
  EXPECT_EQ(k.width, kW);
  const cv::Mat img = pattern();
  EXPECT_EQ(c.prepare(img).data, img.data);  // the same image, not a copy
}

TEST(CameraCalibration, NamesEveryBadField) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  auto with = [](auto edit) {
    sensor_msgs::CameraInfo m = info();
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

TEST(CameraCalibration, ReadsEmptyFieldsAsDriversMeanThem) {
  sensor_msgs::CameraInfo m = info();
  m.P.fill(0.0);
  m.R.fill(0.0);
  m.distortion_model.clear();
  m.D.clear();
  EXPECT_EQ(problem(m), "");
  CameraCalibration c;
  c.set(m, false);
  EXPECT_DOUBLE_EQ(c.intrinsics().fx, 120.0);  // P taken as [K | 0]
  EXPECT_FALSE(c.rectifies());
}

TEST(CameraCalibration, BinningAndRoiGiveTheIntrinsicsOfTheImage) {
  sensor_msgs::CameraInfo m = info();
  m.width = 2 * kW;
  m.height = 2 * kH;
  m.K = {240, 0, 159.5, 0, 242, 119.5, 0, 0, 1};
  m.P = {240, 0, 159.5, 0, 0, 242, 119.5, 0, 0, 0, 1, 0};
  m.binning_x = m.binning_y = 2;
  ASSERT_EQ(problem(m), "");
  CameraCalibration c;
  c.set(m, false);
  EXPECT_NEAR(c.intrinsics().fx, 120.0, 1e-12);
  EXPECT_EQ(c.intrinsics().width, kW);
  // A 160x120 window at (40, 30) of the 320x240 sensor, unbinned.
  sensor_msgs::CameraInfo r = m;
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

// A distorted image rectified by the node matches the undistorted render:
// distort a pattern with OpenCV's model, rectify it back, compare inside.
TEST(CameraCalibration, RectifiesEachDistortionModel) {
  const cv::Matx33d K(120, 0, 79.5, 0, 121, 59.5, 0, 0, 1);
  struct Case {
    std::string model;
    std::vector<double> D;
  };
  for (const Case& cs : {Case{"plumb_bob", {-0.12, 0.03, 0.001, -0.001, 0.0}},
                         Case{"rational_polynomial", {-0.1, 0.02, 0.0, 0.0, 0.0, 0.01, 0.0, 0.0}},
                         Case{"equidistant", {0.05, -0.01, 0.002, 0.0}}}) {
    SCOPED_TRACE(cs.model);
    const cv::Mat undistorted = pattern();
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

    sensor_msgs::CameraInfo m = info(120, 121, 79.5, 59.5);
    m.distortion_model = cs.model;
    m.D = cs.D;
    ASSERT_EQ(problem(m), "");
    CameraCalibration c;
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
    CameraCalibration as_is;
    as_is.set(m, true);
    EXPECT_FALSE(as_is.rectifies());
  }
}

TEST(ImageInput, DecodesRawConvertibleAndCompressedImages) {
  const cv::Mat bgr = pattern();
  auto raw = [&](const std::string& enc, const cv::Mat& m) {
    auto msg = boost::make_shared<sensor_msgs::Image>();
    msg->width = static_cast<std::uint32_t>(m.cols);
    msg->height = static_cast<std::uint32_t>(m.rows);
    msg->encoding = enc;
    msg->step = static_cast<std::uint32_t>(m.cols * m.elemSize());
    msg->data.assign(m.data, m.data + m.total() * m.elemSize());
    return InputFrame{msg, nullptr, ros::Time()};
  };
  DecodedImage d = decodeInput(raw("bgr8", bgr), 1 << 20);
  EXPECT_EQ(d.encoding, "bgr8");
  EXPECT_EQ(cv::norm(d.image, bgr, cv::NORM_INF), 0.0);

  cv::Mat bayer(kH, kW, CV_8UC1);  // RGGB mosaic of the pattern
  for (int v = 0; v < kH; ++v)
    for (int u = 0; u < kW; ++u) {
      const cv::Vec3b p = bgr.at<cv::Vec3b>(v, u);
      bayer.at<uchar>(v, u) =
          (v % 2 == 0) ? (u % 2 == 0 ? p[2] : p[1]) : (u % 2 == 0 ? p[1] : p[0]);
    }
  d = decodeInput(raw("bayer_rggb8", bayer), 1 << 20);
  EXPECT_EQ(d.encoding, "rgb8");
  EXPECT_EQ(d.image.type(), CV_8UC3);
  cv::Mat rgb;
  cv::cvtColor(bgr, rgb, cv::COLOR_BGR2RGB);
  cv::Mat diff;
  cv::absdiff(d.image, rgb, diff);
  EXPECT_LT(cv::mean(diff)[0], 20.0);  // demosaicking, not exact

  std::vector<uchar> png;
  cv::imencode(".png", bgr, png);
  auto compressed = boost::make_shared<sensor_msgs::CompressedImage>();
  compressed->format = "rgb8; png compressed bgr8";
  compressed->data = png;
  d = decodeInput(InputFrame{nullptr, compressed, ros::Time()}, 1 << 20);
  EXPECT_EQ(d.encoding, "bgr8");
  EXPECT_EQ(cv::norm(d.image, bgr, cv::NORM_INF), 0.0);
}

TEST(ImageInput, NamesWhatCannotBeDecoded) {
  auto expect_error = [](const InputFrame& f, const std::string& kind, const std::string& text,
                         std::uint64_t max_pixels = 1 << 20) {
    try {
      decodeInput(f, max_pixels);
      ADD_FAILURE() << "no error, expected " << text;
    } catch (const InputError& e) {
      EXPECT_EQ(e.kind(), kind);
      EXPECT_NE(std::string(e.what()).find(text), std::string::npos) << e.what();
    }
  };
  auto image = [](const std::string& enc, std::uint32_t w, std::uint32_t h, std::uint32_t step,
                  std::size_t bytes) {
    auto msg = boost::make_shared<sensor_msgs::Image>();
    msg->width = w;
    msg->height = h;
    msg->encoding = enc;
    msg->step = step;
    msg->data.assign(bytes, 0);
    return InputFrame{msg, nullptr, ros::Time()};
  };
  expect_error(image("yuv444", 4, 4, 12, 48), "encoding 'yuv444'", "cannot be converted");
  expect_error(image("32FC1", 4, 4, 16, 64), "encoding '32FC1'", "cannot be converted");
  expect_error(image("rgb8", 4, 4, 3, 48), "malformed", "malformed image message");
  expect_error(image("rgb8", 4, 4, 12, 20), "malformed", "malformed image message");
  expect_error(image("rgb8", 0, 4, 0, 0), "empty", "empty image");
  expect_error(image("rgb8", 2000, 1000, 6000, 6000000), "size", "larger than max_image_pixels",
               1000000);
  auto junk = boost::make_shared<sensor_msgs::CompressedImage>();
  junk->format = "jpeg";
  junk->data = {1, 2, 3, 4, 5};
  expect_error(InputFrame{nullptr, junk, ros::Time()}, "compressed", "does not decode");
}

TEST(LogThrottle, ThrottlesEachKindOnItsOwn) {
  LogThrottle t(5.0);
  std::uint64_t repeats = 99;
  EXPECT_TRUE(t.ready("encoding 'yuv444'", 0.0, &repeats));
  EXPECT_EQ(repeats, 0u);
  EXPECT_TRUE(t.ready("encoding '32FC1'", 0.5));  // another kind, at once
  EXPECT_FALSE(t.ready("encoding 'yuv444'", 1.0));
  EXPECT_FALSE(t.ready("encoding 'yuv444'", 4.9));
  EXPECT_TRUE(t.ready("encoding 'yuv444'", 5.1, &repeats));
  EXPECT_EQ(repeats, 2u);
  // Hostile streams of distinct keys stay bounded and keep working.
  for (int i = 0; i < 10000; ++i) EXPECT_TRUE(t.ready("k" + std::to_string(i), 10.0));
}

TEST(WindowStats, CountsOverTheLastPeriodsOnly) {
  WindowStats w(3);
  w.received();
  w.dropped(2);
  w.processed(0.5);
  w.rotate();
  w.processed(0.1);
  w.failed();
  WindowStats::Counts c = w.window();
  EXPECT_EQ(c.received, 1u);
  EXPECT_EQ(c.dropped, 2u);
  EXPECT_EQ(c.failed, 1u);
  EXPECT_EQ(c.processed, 2u);
  EXPECT_DOUBLE_EQ(c.latency_min_s, 0.1);
  EXPECT_DOUBLE_EQ(c.latency_max_s, 0.5);
  EXPECT_DOUBLE_EQ(c.latencyMean(), 0.3);
  w.rotate();
  w.rotate();  // the first period leaves the window
  c = w.window();
  EXPECT_EQ(c.dropped, 0u);
  EXPECT_EQ(c.processed, 1u);
  EXPECT_DOUBLE_EQ(c.latency_max_s, 0.1);
  w.rotate();
  EXPECT_EQ(w.window().processed, 0u);
}

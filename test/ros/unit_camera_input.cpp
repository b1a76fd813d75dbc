// The node's input side without a master: camera_info into the core's
// calibration (toCameraModel), image decoding (decodeInput), per-kind log
// throttling and the diagnostics' sliding window.
#include <gtest/gtest.h>

#include <sensor_msgs/distortion_models.h>
#include <sensor_msgs/image_encodings.h>
#include <boost/make_shared.hpp>

#include <cmath>
#include <limits>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "long3r/pipeline/camera_rectifier.hpp"
#include "long3r_ros/conversions.hpp"
#include "long3r_ros/image_input.hpp"
#include "long3r_ros/log_throttle.hpp"
#include "long3r_ros/stamped_inputs.hpp"
#include "long3r_ros/window_stats.hpp"
#include "support/cv_test_support.hpp"

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

}  // namespace

TEST(CameraInfo, EveryFieldReachesTheCoreCalibration) {
  sensor_msgs::CameraInfo m = info();
  m.distortion_model = sensor_msgs::distortion_models::EQUIDISTANT;
  m.D = {0.05, -0.01, 0.002, 0.0};
  m.binning_x = 2;
  m.binning_y = 3;
  m.roi.x_offset = 4;
  m.roi.y_offset = 5;
  m.roi.width = 6;
  m.roi.height = 7;
  m.R = {0, -1, 0, 1, 0, 0, 0, 0, 1};
  const long3r::CameraModel c = toCameraModel(m);
  EXPECT_EQ(c.width, kW);
  EXPECT_EQ(c.height, kH);
  EXPECT_EQ(c.distortion_model, "equidistant");
  EXPECT_EQ(c.D, m.D);
  for (int i = 0; i < 9; ++i) EXPECT_EQ(c.K[i], m.K[i]) << i;
  for (int i = 0; i < 9; ++i) EXPECT_EQ(c.R[i], m.R[i]) << i;
  for (int i = 0; i < 12; ++i) EXPECT_EQ(c.P[i], m.P[i]) << i;
  EXPECT_EQ(c.binning_x, 2);
  EXPECT_EQ(c.binning_y, 3);
  EXPECT_EQ(c.roi.x_offset, 4);
  EXPECT_EQ(c.roi.y_offset, 5);
  EXPECT_EQ(c.roi.width, 6);
  EXPECT_EQ(c.roi.height, 7);
  // A camera_info the core refuses is named in camera_info's terms.
  m.K[0] = std::numeric_limits<double>::quiet_NaN();
  EXPECT_EQ(long3r::CameraRectifier::problem(toCameraModel(m), 3, 2), "K[0] (fx) is nan");
}

TEST(CameraInfo, PairedByStampWithinTheBound) {
  ros::Time::init();  // the cache reads the clock; no master here
  message_filters::Cache<sensor_msgs::CameraInfo> cache(10);
  for (double t : {10.0, 10.5, 11.0}) {
    auto m = boost::make_shared<sensor_msgs::CameraInfo>(info(100.0 + t));
    m->header.stamp = ros::Time(t);
    cache.add(m);
  }
  auto fx = [&](double t, double max_dt_s) {
    const auto m = cameraInfoFor(cache, ros::Time(t), max_dt_s);
    return m ? m->K[0] : -1.0;
  };
  EXPECT_EQ(fx(10.5, 0.0), 110.5);   // its own stamp
  EXPECT_EQ(fx(10.56, 0.1), 110.5);  // the nearest within the bound
  EXPECT_EQ(fx(10.94, 0.1), 111.0);
  EXPECT_EQ(fx(10.75, 0.25), 110.5);  // a tie: the earlier
  EXPECT_EQ(fx(10.7, 0.1), -1.0);     // none within it: the last calibration stands
  EXPECT_EQ(fx(10.56, 0.0), -1.0);
  EXPECT_EQ(fx(12.0, 0.5), -1.0);  // no unbounded "latest before"
  EXPECT_EQ(fx(9.0, 0.5), -1.0);   // nor "first after"
}

TEST(ImageInput, DecodesRawConvertibleAndCompressedImages) {
  const cv::Mat bgr = long3r::test::egg_crate_image(kW, kH);
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

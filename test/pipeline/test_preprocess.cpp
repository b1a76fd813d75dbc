// Preprocessing: encodings, normalisation, resize + crop geometry and the
// model -> source pixel mapping.
#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>

#include <cmath>
#include <stdexcept>
#include <string>

#include "long3r/pipeline/preprocess.hpp"

namespace long3r {
namespace {

cv::Mat random_rgb(int w, int h, uint64_t seed) {
  cv::Mat img(h, w, CV_8UC3);
  cv::RNG rng(seed);
  rng.fill(img, cv::RNG::UNIFORM, 0, 256);
  return img;
}

// Intensity-weighted centroid of channel 0.
Eigen::Vector2d centroid(const cv::Mat& rgb) {
  double sx = 0, sy = 0, s = 0;
  for (int v = 0; v < rgb.rows; ++v) {
    for (int u = 0; u < rgb.cols; ++u) {
      const double w = rgb.at<cv::Vec3b>(v, u)[0];
      sx += w * u;
      sy += w * v;
      s += w;
    }
  }
  return {sx / s, sy / s};
}

cv::Mat gaussian_blob(int w, int h, double cx, double cy, double sigma) {
  cv::Mat img(h, w, CV_8UC3);
  for (int v = 0; v < h; ++v) {
    for (int u = 0; u < w; ++u) {
      const double r2 = (u - cx) * (u - cx) + (v - cy) * (v - cy);
      const auto g = cv::saturate_cast<uchar>(255.0 * std::exp(-0.5 * r2 / (sigma * sigma)));
      img.at<cv::Vec3b>(v, u) = cv::Vec3b(g, g, g);
    }
  }
  return img;
}

TEST(Preprocess, ColourEncodingsGiveTheSameImage) {
  const cv::Mat rgb = random_rgb(97, 61, 1);
  cv::Mat bgr, rgba, bgra;
  cv::cvtColor(rgb, bgr, cv::COLOR_RGB2BGR);
  cv::cvtColor(rgb, rgba, cv::COLOR_RGB2RGBA);
  cv::cvtColor(rgb, bgra, cv::COLOR_RGB2BGRA);
  // Alpha must be ignored.
  cv::RNG rng(2);
  for (cv::Mat* m : {&rgba, &bgra}) {
    for (int v = 0; v < m->rows; ++v) {
      for (int u = 0; u < m->cols; ++u) m->at<cv::Vec4b>(v, u)[3] = rng.uniform(0, 256);
    }
  }
  const PreprocessedImage ref = preprocess_image(rgb, "rgb8");
  ASSERT_EQ(ref.chw.size(), 3u * 224 * 224);
  for (const auto& [img, enc] : {std::pair{bgr, "bgr8"}, {rgba, "rgba8"}, {bgra, "bgra8"}}) {
    const PreprocessedImage out = preprocess_image(img, enc);
    EXPECT_EQ(out.chw, ref.chw) << enc;
    EXPECT_EQ(cv::norm(out.rgb, ref.rgb, cv::NORM_INF), 0.0) << enc;
  }
}

TEST(Preprocess, GreyEncodingsGiveTheSameImage) {
  cv::Mat grey(53, 88, CV_8UC1);
  cv::RNG(3).fill(grey, cv::RNG::UNIFORM, 0, 256);
  grey.at<uchar>(0, 0) = 255;  // so that the image-max scaling of mono16 is exact
  cv::Mat rgb, mono16;
  cv::cvtColor(grey, rgb, cv::COLOR_GRAY2RGB);
  grey.convertTo(mono16, CV_16U, 256.0);
  PreprocessConfig config;
  config.width = 128;
  config.height = 96;
  const PreprocessedImage ref = preprocess_image(rgb, ImageEncoding::kRgb8, config);
  const PreprocessedImage m8 = preprocess_image(grey, ImageEncoding::kMono8, config);
  EXPECT_EQ(m8.chw, ref.chw);
  for (Mono16Scaling s : {Mono16Scaling::kImageMax, Mono16Scaling::kDiv256}) {
    config.mono16 = s;
    const PreprocessedImage m16 = preprocess_image(mono16, ImageEncoding::kMono16, config);
    EXPECT_EQ(m16.chw, ref.chw) << static_cast<int>(s);
  }
}

TEST(Preprocess, Mono16Scalings) {
  cv::Mat img(16, 16, CV_16UC1, cv::Scalar(1000));
  img.at<uint16_t>(3, 4) = 2000;
  const cv::Mat by_max = to_rgb8(img, ImageEncoding::kMono16, Mono16Scaling::kImageMax);
  EXPECT_EQ(by_max.at<cv::Vec3b>(3, 4), cv::Vec3b(255, 255, 255));
  EXPECT_EQ(by_max.at<cv::Vec3b>(0, 0), cv::Vec3b(128, 128, 128));  // 127.5 rounds to even
  const cv::Mat by_256 = to_rgb8(img, ImageEncoding::kMono16, Mono16Scaling::kDiv256);
  EXPECT_EQ(by_256.at<cv::Vec3b>(3, 4)[0], 8);  // 7.8125
  EXPECT_EQ(by_256.at<cv::Vec3b>(0, 0)[0], 4);  // 3.90625
  const cv::Mat zero = to_rgb8(cv::Mat(4, 4, CV_16UC1, cv::Scalar(0)), ImageEncoding::kMono16);
  EXPECT_EQ(cv::countNonZero(zero.reshape(1)), 0);
}

TEST(Preprocess, NormalisationAndPlanarLayout) {
  const cv::Mat img(240, 320, CV_8UC3, cv::Scalar(0, 128, 255));  // R=0, G=128, B=255
  const PreprocessedImage out = preprocess_image(img, ImageEncoding::kRgb8);
  const size_t plane = 224 * 224;
  const float g = (128.0f / 255.0f - 0.5f) / 0.5f;
  for (size_t i = 0; i < plane; i += 37) {
    EXPECT_EQ(out.chw[i], -1.0f);
    EXPECT_EQ(out.chw[plane + i], g);
    EXPECT_EQ(out.chw[2 * plane + i], 1.0f);
  }
  EXPECT_EQ(out.rgb.type(), CV_8UC3);
  EXPECT_EQ(out.rgb.at<cv::Vec3b>(100, 50), cv::Vec3b(0, 128, 255));
}

TEST(Preprocess, UnsupportedEncodingThrowsNamingIt) {
  const cv::Mat img(32, 32, CV_8UC3, cv::Scalar(1, 2, 3));
  for (const std::string enc : {"yuv422", "bayer_rggb8", "16UC1", "RGB8", ""}) {
    try {
      preprocess_image(img, enc);
      FAIL() << "no exception for '" << enc << "'";
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find("'" + enc + "'"), std::string::npos) << e.what();
    }
  }
  // Mat type that contradicts the encoding.
  EXPECT_THROW(preprocess_image(img, "mono8"), std::invalid_argument);
  EXPECT_THROW(preprocess_image(img, "rgba8"), std::invalid_argument);
  EXPECT_THROW(preprocess_image(cv::Mat(), "rgb8"), std::invalid_argument);
}

TEST(Preprocess, BadModelSizeThrows) {
  const cv::Mat img(32, 32, CV_8UC3, cv::Scalar(1, 2, 3));
  PreprocessConfig config;
  config.width = 100;
  config.height = 224;
  EXPECT_THROW(preprocess_image(img, ImageEncoding::kRgb8, config), std::invalid_argument);
  config.width = 0;  // one size left to the checkpoint, the other given
  EXPECT_THROW(preprocess_image(img, ImageEncoding::kRgb8, config), std::invalid_argument);
  EXPECT_THROW(config.validate({"preprocess", ""}), ConfigError);
}

// 0 x 0 follows the checkpoint: its recorded size, else 224 x 224 (also
// where no checkpoint is known, as in preprocess_image alone).
TEST(Preprocess, SizeFollowsTheCheckpoint) {
  PreprocessConfig config;
  EXPECT_TRUE(config.follows_checkpoint());
  EXPECT_NO_THROW(config.validate({"preprocess", ""}));
  EXPECT_EQ(config.resolved(64, 48).width, 64);
  EXPECT_EQ(config.resolved(64, 48).height, 48);
  EXPECT_EQ(config.resolved().width, kDefaultModelInputSide);
  EXPECT_EQ(config.resolved().height, kDefaultModelInputSide);
  const PreprocessedImage out =
      preprocess_image(cv::Mat(480, 640, CV_8UC3, cv::Scalar::all(9)), ImageEncoding::kRgb8);
  EXPECT_EQ(out.width, kDefaultModelInputSide);
  config.width = 320;
  config.height = 240;
  EXPECT_EQ(config.resolved(64, 48).width, 320);  // a named size wins
  EXPECT_EQ(config.resolved(64, 48).height, 240);
}

TEST(Preprocess, ResizeCropPlans) {
  // 640x480 -> 224: short side to 224, width round(298.67) = 299, centred crop.
  ResizeCropPlan p = plan_resize_crop(640, 480);
  EXPECT_EQ(p.resized_width, 299);
  EXPECT_EQ(p.resized_height, 224);
  EXPECT_EQ(p.crop_x, 37);
  EXPECT_EQ(p.crop_y, 0);
  // Portrait.
  p = plan_resize_crop(480, 640);
  EXPECT_EQ(p.resized_width, 224);
  EXPECT_EQ(p.resized_height, 299);
  EXPECT_EQ(p.crop_x, 0);
  EXPECT_EQ(p.crop_y, 37);
  // 512x384 from 640x480: same aspect, pure scale by 0.8.
  PreprocessConfig c;
  c.width = 512;
  c.height = 384;
  p = plan_resize_crop(640, 480, c);
  EXPECT_EQ(p.resized_width, 512);
  EXPECT_EQ(p.resized_height, 384);
  EXPECT_EQ(p.crop_x, 0);
  EXPECT_EQ(p.crop_y, 0);
  EXPECT_DOUBLE_EQ(p.model_to_source.scale_x, 1.25);
  EXPECT_DOUBLE_EQ(p.model_to_source.offset_x, 0.125);  // (0 + 0.5) * 1.25 - 0.5
  // Wide target from a 4:3 source: the width decides, the height is cropped.
  c.width = 320;
  c.height = 160;
  p = plan_resize_crop(640, 480, c);
  EXPECT_EQ(p.resized_width, 320);
  EXPECT_EQ(p.resized_height, 240);
  EXPECT_EQ(p.crop_y, 40);
  EXPECT_DOUBLE_EQ(p.model_to_source.offset_y, 40.5 * 2.0 - 0.5);

  const PreprocessedImage out = preprocess_image(random_rgb(640, 480, 4), ImageEncoding::kRgb8, c);
  EXPECT_EQ(out.width, 320);
  EXPECT_EQ(out.height, 160);
  EXPECT_EQ(out.rgb.cols, 320);
  EXPECT_EQ(out.rgb.rows, 160);
  EXPECT_EQ(out.source_width, 640);
  EXPECT_EQ(out.source_height, 480);
  EXPECT_EQ(out.chw.size(), 3u * 320 * 160);
}

TEST(Preprocess, MappingInverse) {
  const ResizeCropPlan p = plan_resize_crop(1241, 376);
  const PixelMapping inv = p.model_to_source.inverse();
  for (const Eigen::Vector2d& m :
       {Eigen::Vector2d(0, 0), Eigen::Vector2d(223, 223), Eigen::Vector2d(17.25, 101.5)}) {
    EXPECT_LT((inv.apply(p.model_to_source.apply(m)) - m).norm(), 1e-12);
  }
  EXPECT_LT((p.model_to_source.matrix() * inv.matrix() - Eigen::Matrix3d::Identity()).norm(),
            1e-12);
}

// The mapping describes what the image resampling did: a blob's centroid in
// the model image maps onto its centroid in the source image. A half-pixel
// convention slip would be off by about half a pixel times the scale.
TEST(Preprocess, MappingMatchesTheImage) {
  struct Case {
    int w, h, tw, th;
    double bx, by, sigma;
  };
  for (const Case& c : {Case{640, 480, 224, 224, 301.3, 207.8, 9.0},    // shrink, crop x
                        Case{480, 640, 224, 224, 231.6, 355.2, 9.0},    // portrait, crop y
                        Case{1280, 720, 512, 384, 701.7, 333.3, 12.0},  // shrink, crop x
                        Case{150, 100, 224, 224, 71.4, 52.7, 4.0}}) {   // enlarge
    PreprocessConfig config;
    config.width = c.tw;
    config.height = c.th;
    const cv::Mat src = gaussian_blob(c.w, c.h, c.bx, c.by, c.sigma);
    const PreprocessedImage out = preprocess_image(src, ImageEncoding::kRgb8, config);
    const Eigen::Vector2d src_centroid = centroid(src);
    const Eigen::Vector2d mapped = out.model_to_source.apply(centroid(out.rgb));
    EXPECT_LT((mapped - src_centroid).norm(), 0.03 * out.model_to_source.scale_x)
        << c.w << "x" << c.h << " -> " << c.tw << "x" << c.th << ": mapped (" << mapped.x() << ", "
        << mapped.y() << ") vs (" << src_centroid.x() << ", " << src_centroid.y() << ")";
    EXPECT_LT((out.source_to_model.apply(src_centroid) - centroid(out.rgb)).norm(), 0.03);
  }
}

}  // namespace
}  // namespace long3r

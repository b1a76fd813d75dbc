#include "long3r/pipeline/preprocess.hpp"

#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace long3r {

void PreprocessConfig::validate(const config::FieldCheck& check) const {
  if (follows_checkpoint()) return;
  const auto multiple_of_16 = [](int v) { return v >= 16 && v <= 4096 && v % 16 == 0; };
  const char* what =
      "must be a multiple of 16 in [16, 4096], or 0 with the other size 0 too (the checkpoint's "
      "input size)";
  check.require(multiple_of_16(width), "width", what);
  check.require(multiple_of_16(height), "height", what);
}

PreprocessConfig PreprocessConfig::resolved(int recorded_width, int recorded_height) const {
  PreprocessConfig out = *this;
  if (!follows_checkpoint()) return out;
  const bool recorded = recorded_width > 0 && recorded_height > 0;
  out.width = recorded ? recorded_width : kDefaultModelInputSide;
  out.height = recorded ? recorded_height : kDefaultModelInputSide;
  return out;
}

namespace {

constexpr const char* kSupported = "rgb8, bgr8, rgba8, bgra8, mono8, mono16";

int expected_type(ImageEncoding encoding) {
  switch (encoding) {
    case ImageEncoding::kRgb8:
    case ImageEncoding::kBgr8:
      return CV_8UC3;
    case ImageEncoding::kRgba8:
    case ImageEncoding::kBgra8:
      return CV_8UC4;
    case ImageEncoding::kMono8:
      return CV_8UC1;
    case ImageEncoding::kMono16:
      return CV_16UC1;
  }
  throw std::invalid_argument("unknown ImageEncoding value");
}

void check_config(const PreprocessConfig& config) {
  if (config.width <= 0 || config.height <= 0 || config.width % 16 != 0 ||
      config.height % 16 != 0) {
    throw std::invalid_argument("preprocess: model size " + std::to_string(config.width) + "x" +
                                std::to_string(config.height) +
                                " is not a positive multiple of 16 in both dimensions");
  }
}

}  // namespace

ImageEncoding parse_image_encoding(const std::string& name) {
  if (name == "rgb8") return ImageEncoding::kRgb8;
  if (name == "bgr8") return ImageEncoding::kBgr8;
  if (name == "rgba8") return ImageEncoding::kRgba8;
  if (name == "bgra8") return ImageEncoding::kBgra8;
  if (name == "mono8") return ImageEncoding::kMono8;
  if (name == "mono16") return ImageEncoding::kMono16;
  throw std::invalid_argument("unsupported image encoding '" + name +
                              "' (supported: " + kSupported + ")");
}

const char* to_string(ImageEncoding encoding) {
  switch (encoding) {
    case ImageEncoding::kRgb8:
      return "rgb8";
    case ImageEncoding::kBgr8:
      return "bgr8";
    case ImageEncoding::kRgba8:
      return "rgba8";
    case ImageEncoding::kBgra8:
      return "bgra8";
    case ImageEncoding::kMono8:
      return "mono8";
    case ImageEncoding::kMono16:
      return "mono16";
  }
  return "unknown";
}

cv::Mat to_rgb8(const cv::Mat& image, ImageEncoding encoding, Mono16Scaling mono16) {
  if (image.empty()) throw std::invalid_argument("preprocess: empty image");
  const int type = expected_type(encoding);
  if (image.type() != type) {
    throw std::invalid_argument(std::string("preprocess: encoding ") + to_string(encoding) +
                                " expects a cv::Mat of type " + cv::typeToString(type) + ", got " +
                                cv::typeToString(image.type()));
  }
  cv::Mat rgb;
  switch (encoding) {
    case ImageEncoding::kRgb8:
      rgb = image.clone();
      break;
    case ImageEncoding::kBgr8:
      cv::cvtColor(image, rgb, cv::COLOR_BGR2RGB);
      break;
    case ImageEncoding::kRgba8:
      cv::cvtColor(image, rgb, cv::COLOR_RGBA2RGB);
      break;
    case ImageEncoding::kBgra8:
      cv::cvtColor(image, rgb, cv::COLOR_BGRA2RGB);
      break;
    case ImageEncoding::kMono8:
      cv::cvtColor(image, rgb, cv::COLOR_GRAY2RGB);
      break;
    case ImageEncoding::kMono16: {
      double scale = 1.0 / 256.0;
      if (mono16 == Mono16Scaling::kImageMax) {
        double max_value = 0.0;
        cv::minMaxLoc(image, nullptr, &max_value);
        scale = max_value > 0.0 ? 255.0 / max_value : 0.0;
      }
      cv::Mat grey;
      image.convertTo(grey, CV_8U, scale);  // rounds to nearest, saturates
      cv::cvtColor(grey, rgb, cv::COLOR_GRAY2RGB);
      break;
    }
  }
  return rgb;
}

ResizeCropPlan plan_resize_crop(int source_width, int source_height,
                                const PreprocessConfig& requested) {
  const PreprocessConfig config = requested.resolved();
  check_config(config);
  if (source_width <= 0 || source_height <= 0) {
    throw std::invalid_argument("preprocess: empty source image");
  }
  const double scale = std::max(static_cast<double>(config.width) / source_width,
                                static_cast<double>(config.height) / source_height);
  ResizeCropPlan plan;
  // Each side is >= its target before rounding; max() guards the rounding.
  plan.resized_width = std::max(config.width, static_cast<int>(std::lround(source_width * scale)));
  plan.resized_height =
      std::max(config.height, static_cast<int>(std::lround(source_height * scale)));
  plan.crop_x = (plan.resized_width - config.width) / 2;
  plan.crop_y = (plan.resized_height - config.height) / 2;
  // cv::resize maps pixel centres: src = (dst + 0.5) * (src_size / dst_size) - 0.5,
  // and dst = model + crop.
  PixelMapping& m = plan.model_to_source;
  m.scale_x = static_cast<double>(source_width) / plan.resized_width;
  m.scale_y = static_cast<double>(source_height) / plan.resized_height;
  m.offset_x = (plan.crop_x + 0.5) * m.scale_x - 0.5;
  m.offset_y = (plan.crop_y + 0.5) * m.scale_y - 0.5;
  return plan;
}

PreprocessedImage preprocess_image(const cv::Mat& image, ImageEncoding encoding,
                                   const PreprocessConfig& requested) {
  const PreprocessConfig config = requested.resolved();
  check_config(config);
  const cv::Mat rgb_src = to_rgb8(image, encoding, config.mono16);
  const ResizeCropPlan plan = plan_resize_crop(rgb_src.cols, rgb_src.rows, config);

  cv::Mat resized;
  if (plan.resized_width == rgb_src.cols && plan.resized_height == rgb_src.rows) {
    resized = rgb_src;
  } else {
    // Area averaging avoids aliasing when shrinking; cubic when enlarging.
    const bool shrinking = plan.resized_width < rgb_src.cols || plan.resized_height < rgb_src.rows;
    cv::resize(rgb_src, resized, cv::Size(plan.resized_width, plan.resized_height), 0.0, 0.0,
               shrinking ? cv::INTER_AREA : cv::INTER_CUBIC);
  }

  PreprocessedImage out;
  out.width = config.width;
  out.height = config.height;
  out.source_width = rgb_src.cols;
  out.source_height = rgb_src.rows;
  out.rgb = resized(cv::Rect(plan.crop_x, plan.crop_y, config.width, config.height)).clone();
  out.model_to_source = plan.model_to_source;
  out.source_to_model = plan.model_to_source.inverse();

  const size_t plane = static_cast<size_t>(config.width) * config.height;
  out.chw.resize(3 * plane);
  for (int v = 0; v < config.height; ++v) {
    const auto* row = out.rgb.ptr<cv::Vec3b>(v);
    for (int u = 0; u < config.width; ++u) {
      const size_t i = static_cast<size_t>(v) * config.width + u;
      for (int c = 0; c < 3; ++c) {
        out.chw[c * plane + i] = (static_cast<float>(row[u][c]) / 255.0f - 0.5f) / 0.5f;
      }
    }
  }
  return out;
}

PreprocessedImage preprocess_image(const cv::Mat& image, const std::string& encoding,
                                   const PreprocessConfig& config) {
  return preprocess_image(image, parse_image_encoding(encoding), config);
}

}  // namespace long3r

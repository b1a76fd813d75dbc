// Image preprocessing for the model: any input size and common encodings to
// the model resolution, normalised as the model expects.
//
// Geometry: the source image is scaled so that it covers the target (the
// short side becomes the target size for a square target; for a W x H target,
// scale = max(W / W_src, H / H_src)), resized to an integer size with
// cv::resize (INTER_AREA when shrinking, INTER_CUBIC when enlarging), then
// centre-cropped to the target. The resized size is rounded to whole pixels,
// so the two axes may differ in scale by well under 0.5 %; the mapping below
// keeps both scales and is exact for what was done.
//
// Pixel convention (the same as PinholeIntrinsics): integer pixel coordinates
// are pixel centres, (0, 0) is the centre of the top-left pixel. A model pixel
// (u, v) then maps to the source pixel (scale_x * u + offset_x,
// scale_y * v + offset_y).
#pragma once

#include <Eigen/Core>
#include <opencv2/core/mat.hpp>

#include <string>
#include <vector>

#include "long3r/config/config_fields.hpp"

namespace long3r {

// Encodings named as sensor_msgs/image_encodings names them.
enum class ImageEncoding { kRgb8, kBgr8, kRgba8, kBgra8, kMono8, kMono16 };

// "rgb8", "bgr8", "rgba8", "bgra8", "mono8", "mono16" (exact, lower case).
// Anything else throws std::invalid_argument naming the encoding.
ImageEncoding parse_image_encoding(const std::string& name);
const char* to_string(ImageEncoding encoding);

// How 16-bit grey values become 8-bit before the model sees them.
enum class Mono16Scaling {
  kImageMax,  // v * 255 / max(image); an all-zero image stays zero
  kDiv256,    // v / 256 (the high byte, rounded): fixed, frame-independent
};

// The model input side when neither the configuration nor the checkpoint
// gives a size (the size the official Spann3R runs at).
constexpr int kDefaultModelInputSide = 224;

struct PreprocessConfig {
  // Model input size, positive multiples of 16. 0 x 0 (the default) follows
  // the checkpoint: the size it was trained at where it records one
  // (ModelConfig::input_width / input_height), else 224 x 224. A model runs
  // well only at the size it was trained at.
  int width = 0;
  int height = 0;
  Mono16Scaling mono16 = Mono16Scaling::kImageMax;

  // Both sizes or neither. Throws ConfigError naming the field.
  void validate(const config::FieldCheck& check) const;
  bool follows_checkpoint() const { return width == 0 && height == 0; }
  // This configuration with a 0 x 0 size replaced by the checkpoint's
  // recorded size, or by 224 x 224 where there is none (recorded 0 x 0).
  PreprocessConfig resolved(int recorded_width = 0, int recorded_height = 0) const;
};

// mono16 is the input's to choose (a TUM depth-like mono16 camera), not a setting.
template <class S, class V>
config::FieldsOf<S, PreprocessConfig> visit_fields(S& s, V& v) {
  v("width", s.width);
  v("height", s.height);
}

// Per-axis affine pixel mapping: to = scale * from + offset (pixel centres).
struct PixelMapping {
  double scale_x = 1.0, scale_y = 1.0;
  double offset_x = 0.0, offset_y = 0.0;

  Eigen::Vector2d apply(const Eigen::Vector2d& p) const {
    return {scale_x * p.x() + offset_x, scale_y * p.y() + offset_y};
  }
  PixelMapping inverse() const {
    return {1.0 / scale_x, 1.0 / scale_y, -offset_x / scale_x, -offset_y / scale_y};
  }
  // Homogeneous 3x3 form.
  Eigen::Matrix3d matrix() const {
    Eigen::Matrix3d m;
    m << scale_x, 0.0, offset_x, 0.0, scale_y, offset_y, 0.0, 0.0, 1.0;
    return m;
  }
};

struct PreprocessedImage {
  int width = 0, height = 0;                // model resolution
  int source_width = 0, source_height = 0;  // input resolution
  // 3 x height x width float32, planes R, G, B, values (rgb / 255 - 0.5) / 0.5
  // in [-1, 1]; ready to become a [1, 3, H, W] tensor.
  std::vector<float> chw;
  cv::Mat rgb;                   // CV_8UC3, height x width, RGB order (map colours)
  PixelMapping model_to_source;  // model pixel -> source pixel
  PixelMapping source_to_model;  // its inverse
};

// A config that follows the checkpoint (0 x 0) gives 224 x 224 here, where no
// checkpoint is known: resolve it first (Reconstruction does).
// Throws std::invalid_argument for a bad config, an empty image, or a cv::Mat
// whose type does not match the encoding (rgb8/bgr8: CV_8UC3, rgba8/bgra8:
// CV_8UC4, mono8: CV_8UC1, mono16: CV_16UC1).
PreprocessedImage preprocess_image(const cv::Mat& image, ImageEncoding encoding,
                                   const PreprocessConfig& config = {});
// Same, with the encoding by name (unsupported names throw, see above).
PreprocessedImage preprocess_image(const cv::Mat& image, const std::string& encoding,
                                   const PreprocessConfig& config = {});

// The source image as CV_8UC3 RGB at its own resolution (the first step of
// preprocess_image, exposed for callers that want the colour image itself).
cv::Mat to_rgb8(const cv::Mat& image, ImageEncoding encoding,
                Mono16Scaling mono16 = Mono16Scaling::kImageMax);

// The resize + crop geometry preprocess_image uses for a source of this size:
// the integer resized size and the crop's top-left corner in it.
struct ResizeCropPlan {
  int resized_width = 0, resized_height = 0;
  int crop_x = 0, crop_y = 0;
  PixelMapping model_to_source;
};
ResizeCropPlan plan_resize_crop(int source_width, int source_height,
                                const PreprocessConfig& config = {});

}  // namespace long3r

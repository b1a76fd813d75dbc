// The node's input frames: raw sensor_msgs/Image or sensor_msgs/CompressedImage
// as they arrive (callbacks only enqueue them), decoded by the worker into an
// image the pipeline reads.
//
// Raw images in the pipeline's encodings (rgb8, bgr8, rgba8, bgra8, mono8,
// mono16) pass as they are; any other encoding cv_bridge can turn into colour
// (bayer_*, yuv422, 16-bit colour, ...) is converted to rgb8. Compressed
// images are decoded with OpenCV (jpeg, png), so compressed input works where
// the compressed image_transport plugin is not installed (Debian has none).
#pragma once

#include <ros/time.h>
#include <sensor_msgs/CompressedImage.h>
#include <sensor_msgs/Image.h>

#include <cstdint>
#include <memory>
#include <opencv2/core/mat.hpp>
#include <stdexcept>
#include <string>

namespace long3r_ros {

struct InputFrame {
  sensor_msgs::ImageConstPtr image;                 // raw input, or
  sensor_msgs::CompressedImageConstPtr compressed;  // compressed input
  ros::Time arrival;                                // the clock when it arrived

  const std_msgs::Header& header() const { return image ? image->header : compressed->header; }
};

// Why a frame could not be decoded. `kind` groups messages for throttling
// (one kind's flood does not hide another's), e.g. "encoding 'yuv444'".
class InputError : public std::runtime_error {
 public:
  InputError(std::string kind, const std::string& what)
      : std::runtime_error(what), kind_(std::move(kind)) {}
  const std::string& kind() const { return kind_; }

 private:
  std::string kind_;
};

struct DecodedImage {
  cv::Mat image;         // rows x cols of the encoding's cv type
  std::string encoding;  // one of the pipeline's encodings
  // What `image` may point into (the message's buffer, shared, not copied).
  std::shared_ptr<const void> owner;
};

// Decodes a frame. Throws InputError naming the problem: an encoding that
// cannot be converted, a malformed message (step, data size), an image of
// more than max_pixels pixels, a compressed image that does not decode.
DecodedImage decodeInput(const InputFrame& frame, std::uint64_t max_pixels);

}  // namespace long3r_ros

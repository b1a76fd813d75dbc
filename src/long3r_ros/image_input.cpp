#include "long3r_ros/image_input.hpp"

#include <cv_bridge/cv_bridge.h>
#include <sensor_msgs/image_encodings.h>

#include <opencv2/imgcodecs.hpp>

#include "long3r/pipeline/preprocess.hpp"

namespace long3r_ros {

namespace {

void checkSize(std::uint64_t width, std::uint64_t height, std::uint64_t max_pixels) {
  if (width == 0 || height == 0) throw InputError("empty", "empty image (0 pixels)");
  if (width * height > max_pixels) {
    throw InputError("size", "image of " + std::to_string(width) + "x" + std::to_string(height) +
                                 " pixels is larger than max_image_pixels (" +
                                 std::to_string(max_pixels) + ")");
  }
}

bool pipelineReads(const std::string& encoding) {
  try {
    long3r::parse_image_encoding(encoding);
    return true;
  } catch (const std::invalid_argument&) {
    return false;
  }
}

DecodedImage decodeRaw(const sensor_msgs::ImageConstPtr& msg, std::uint64_t max_pixels) {
  checkSize(msg->width, msg->height, max_pixels);
  try {
    if (pipelineReads(msg->encoding)) {
      // Shares the message's buffer; cv_bridge checks step and data size.
      cv_bridge::CvImageConstPtr shared = cv_bridge::toCvShare(msg);
      // The std::shared_ptr owns a copy of the boost one, keeping the message alive.
      return {shared->image, msg->encoding,
              std::shared_ptr<const void>(shared.get(), [shared](const void*) {})};
    }
    // bayer_*, yuv422, 16-bit colour, ...: whatever cv_bridge turns into colour.
    return {cv_bridge::toCvCopy(msg, sensor_msgs::image_encodings::RGB8)->image,
            sensor_msgs::image_encodings::RGB8, nullptr};
  } catch (const cv_bridge::Exception& e) {
    if (!pipelineReads(msg->encoding)) {
      throw InputError("encoding '" + msg->encoding + "'", "image encoding '" + msg->encoding +
                                                               "' cannot be converted to colour (" +
                                                               e.what() + ")");
    }
    throw InputError("malformed", std::string("malformed image message: ") + e.what());
  } catch (const cv::Exception& e) {
    throw InputError("malformed", std::string("malformed image message: ") + e.what());
  }
}

DecodedImage decodeCompressed(const sensor_msgs::CompressedImageConstPtr& msg,
                              std::uint64_t max_pixels) {
  if (msg->data.empty()) throw InputError("compressed", "compressed image without data");
  cv::Mat decoded;
  try {
    const cv::Mat buffer(1, static_cast<int>(msg->data.size()), CV_8UC1,
                         const_cast<std::uint8_t*>(msg->data.data()));
    decoded = cv::imdecode(buffer, cv::IMREAD_ANYDEPTH | cv::IMREAD_ANYCOLOR);
  } catch (const cv::Exception& e) {
    throw InputError("compressed",
                     "compressed image ('" + msg->format + "') does not decode: " + e.what());
  }
  if (decoded.empty()) {
    throw InputError("compressed", "compressed image ('" + msg->format + "') does not decode");
  }
  checkSize(static_cast<std::uint64_t>(decoded.cols), static_cast<std::uint64_t>(decoded.rows),
            max_pixels);
  namespace enc = sensor_msgs::image_encodings;
  if (decoded.type() == CV_8UC1) return {decoded, enc::MONO8, nullptr};
  if (decoded.type() == CV_16UC1) return {decoded, enc::MONO16, nullptr};
  if (decoded.type() == CV_8UC3) return {decoded, enc::BGR8, nullptr};  // OpenCV decodes to BGR
  if (decoded.type() == CV_8UC4) return {decoded, enc::BGRA8, nullptr};
  throw InputError("compressed", "compressed image ('" + msg->format + "') decodes to " +
                                     cv::typeToString(decoded.type()) +
                                     ", not 8-bit colour or 8/16-bit grey");
}

}  // namespace

DecodedImage decodeInput(const InputFrame& frame, std::uint64_t max_pixels) {
  return frame.image ? decodeRaw(frame.image, max_pixels)
                     : decodeCompressed(frame.compressed, max_pixels);
}

}  // namespace long3r_ros

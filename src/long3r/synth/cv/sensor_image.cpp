// What the image sensor adds to the rendered image, and rendered frames as
// OpenCV images.
#include "long3r/synth/cv/sensor_image.hpp"

#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>

namespace long3r::synth {

namespace {

// derived_seed stream of the noise (an arbitrary constant, + frame index).
constexpr uint64_t kNoiseStream = 0x6e6f697365000000ull;  // "noise"

cv::Mat copy_of(const at::Tensor& t, int type) {
  const at::Tensor c = t.contiguous();
  return cv::Mat(static_cast<int>(c.size(0)), static_cast<int>(c.size(1)), type, c.data_ptr())
      .clone();
}

}  // namespace

cv::Mat bgr_image(const RenderedFrame& frame) { return copy_of(frame.bgr, CV_8UC3); }
cv::Mat depth_image(const RenderedFrame& frame) { return copy_of(frame.depth, CV_32FC1); }
cv::Mat surface_id_image(const RenderedFrame& frame) { return copy_of(frame.surface_id, CV_32SC1); }

cv::Mat apply_sensor(const cv::Mat& bgr, const SensorConfig& sensor, uint64_t seed, int index) {
  if (!sensor.mono && !sensor.noise()) return bgr;
  cv::Mat out;
  if (sensor.mono) {
    cv::cvtColor(bgr, out, cv::COLOR_BGR2GRAY);
  } else {
    out = bgr.clone();
  }
  if (sensor.noise()) {
    Rng rng(derived_seed(seed, kNoiseStream + static_cast<uint64_t>(index)));
    const double read2 = sensor.read_noise * sensor.read_noise;
    const int values = out.cols * out.channels();
    for (int r = 0; r < out.rows; ++r) {
      uint8_t* p = out.ptr<uint8_t>(r);
      for (int i = 0; i < values; ++i) {
        const double sigma = std::sqrt(read2 + sensor.shot_noise * p[i]);
        const double noisy = p[i] + sigma * rng.normal();
        p[i] = static_cast<uint8_t>(std::clamp(std::lround(noisy), 0L, 255L));
      }
    }
  }
  return out;
}

}  // namespace long3r::synth

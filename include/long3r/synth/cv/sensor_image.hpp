// The generator's images as OpenCV sees them (library long3r_synth_cv): a
// rendered frame's tensors as cv::Mat, and what the image sensor adds to the
// rendered image (mono output, noise; see SensorConfig in generate.hpp).
#pragma once

#include <opencv2/core.hpp>

#include <cstdint>

#include "long3r/synth/generate.hpp"
#include "long3r/synth/render.hpp"

namespace long3r::synth {

// Copies of a rendered frame's images (they outlive the frame):
cv::Mat bgr_image(const RenderedFrame& frame);         // CV_8UC3, BGR
cv::Mat depth_image(const RenderedFrame& frame);       // CV_32FC1, metres
cv::Mat surface_id_image(const RenderedFrame& frame);  // CV_32SC1

// The image the sensor writes for frame `index`: `bgr` (rendered with the
// frame's exposure gain) made grey when sensor.mono, then noise added (seeded
// by derived_seed(seed, index)). Returns `bgr` itself when neither applies.
cv::Mat apply_sensor(const cv::Mat& bgr, const SensorConfig& sensor, uint64_t seed, int index);

}  // namespace long3r::synth

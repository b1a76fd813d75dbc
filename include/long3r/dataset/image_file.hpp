// Image files written atomically (plots, rendered frames): encoded in memory
// by OpenCV, then written through AtomicFile (long3r/io/atomic_file.hpp).
#pragma once

#include <opencv2/core.hpp>

#include <string>
#include <vector>

namespace long3r {

// Format from the extension (.png, .jpg, ...), `params` as cv::imwrite's.
// Throws std::runtime_error when OpenCV cannot encode the image,
// AtomicWriteError when the write fails.
void write_image_atomically(const std::string& path, const cv::Mat& image,
                            const std::vector<int>& params = {});

}  // namespace long3r

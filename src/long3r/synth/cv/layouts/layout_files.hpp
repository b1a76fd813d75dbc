// The file-writing pieces that the dataset-layout writers share
// (src/long3r/synth/cv/layouts/<layout>_writer.cpp; internal to long3r_synth_cv).
// Each throws std::runtime_error naming the path that cannot be written, as
// the writers promise (include/long3r/synth/cv/dataset_layouts.hpp).
#pragma once

#include <opencv2/core.hpp>

#include <string>
#include <vector>

namespace long3r::synth::layouts {

// The folder and its parents, created where absent.
void make_dirs(const std::string& dir);

// `text` as the whole file (bytes as given: no newline translation).
void write_text(const std::string& path, const std::string& text);

// An image through cv::imwrite (`params` as it takes them); OpenCV's own
// exceptions become std::runtime_error, so that every writer throws one kind.
void write_image(const std::string& path, const cv::Mat& image,
                 const std::vector<int>& params = {});

// `name` appended as a line of the split list `path` (created with its
// folder) unless a line says it already: writing a sequence again lists it
// once.
void list_once(const std::string& path, const std::string& name);

// Metric depth (CV_32F) as 16-bit millimetres (CV_16U), the datasets'
// common encoding: rounded, 0 where no depth, beyond 65.535 m clipped.
cv::Mat depth_mm(const cv::Mat& depth_m);

}  // namespace long3r::synth::layouts

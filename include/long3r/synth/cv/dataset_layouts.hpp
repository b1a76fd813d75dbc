// Generated scenes written in the public datasets' preprocessed layouts
// (library long3r_synth_cv): small folders that the layout readers
// (train/cv/datasets/dataset_io.hpp) read like the real datasets, each frame's
// ground truth known. Each writer takes frames of one sequence and writes
// them with that dataset's file names, image and depth encodings, intrinsics
// and pose conventions (docs/training.md, "Datasets").
#pragma once

#include <Eigen/Geometry>
#include <opencv2/core.hpp>

#include <cstdint>
#include <string>
#include <vector>

#include "long3r/geometry/pinhole_intrinsics.hpp"

namespace long3r::synth {

// One frame with its ground truth: colour, z-depth in metres (0 where no
// surface), intrinsics (OpenCV pixel convention) and T_W_C (OpenCV axes).
struct LayoutFrame {
  cv::Mat bgr;      // CV_8UC3
  cv::Mat depth_m;  // CV_32F
  PinholeIntrinsics intrinsics;
  Eigen::Isometry3d T_W_C = Eigen::Isometry3d::Identity();
};

// `frames` frames of a generated room (scene `seed`, a walk), width x height,
// an off-centre principal point so that conventions about it show.
std::vector<LayoutFrame> render_layout_frames(uint64_t seed, int frames, int width, int height);

// The writers, one per file (src/long3r/synth/cv/layouts/<layout>_writer.cpp).
// `root` is the dataset's root as a reader's DatasetSource::root names it;
// each call adds one sequence (`name`) to the "train" split, creating or
// extending the dataset's index files. Throws std::runtime_error when a file
// cannot be written.
void write_scannet_sequence(const std::string& root, const std::string& name,
                            const std::vector<LayoutFrame>& frames);
void write_scannetpp_sequence(const std::string& root, const std::string& name,
                              const std::vector<LayoutFrame>& frames);
void write_arkitscenes_sequence(const std::string& root, const std::string& name,
                                const std::vector<LayoutFrame>& frames);
void write_co3d_sequence(const std::string& root, const std::string& name,
                         const std::vector<LayoutFrame>& frames);
void write_blendedmvs_sequence(const std::string& root, const std::string& name,
                               const std::vector<LayoutFrame>& frames);
void write_habitat_sequence(const std::string& root, const std::string& name,
                            const std::vector<LayoutFrame>& frames);

}  // namespace long3r::synth

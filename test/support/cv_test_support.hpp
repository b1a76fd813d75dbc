// Fixtures of the OpenCV-side tests (long3r_cv_tests only): synthetic
// pointmaps of a pinhole camera.
#pragma once

#include <Eigen/Geometry>
#include <opencv2/core/mat.hpp>

#include <functional>

#include "long3r/pipeline/pinhole_intrinsics.hpp"

namespace long3r::test {

// CV_32FC3 [k.height, k.width]: pixel (u, v) at z-depth depth(u, v) in the
// camera, mapped by T (camera to the target frame); NaN where the depth is not
// > 0. depth is called row by row, left to right.
cv::Mat pointmap_from_depth(const PinholeIntrinsics& k, const Eigen::Isometry3d& T,
                            const std::function<double(int u, int v)>& depth);

}  // namespace long3r::test

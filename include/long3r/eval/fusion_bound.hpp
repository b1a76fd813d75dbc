// What fusing views can remove from a map's error, measured with ground truth.
//
// Each frame's predicted points (camera frame C, metres) are paired with the
// true surface points of the same pixels (true depth along the pixel's ray),
// and both are placed in the world W by the frame's true pose T_W_C. The true
// points are binned into voxels of W; the predictions that fell on one true
// voxel, from all the frames that saw it, are averaged. That average is what
// an ideal fusion of the views makes of the surface: its error is the part no
// averaging of views removes (the depth's overall scale, tilt, a shape bias
// every view shares); the rest of a single view's error varies from view to
// view and fusion can average it away. Run the averaged cloud and the point
// map through long3r_eval with the same options to read the split in Acc.
//
// Per frame it also reports the depth ratio (median of predicted over true
// depth): its spread over the frames is scale error that varies per view, its
// median the scale error they share. A second average divides each frame's
// points by its own ratio first: what is left in it is shape alone (tilt,
// curvature, edges), with no scale error at all.
#pragma once

#include <Eigen/Geometry>
#include <opencv2/core/mat.hpp>

#include <cstddef>
#include <cstdint>
#include <unordered_map>
#include <vector>

#include "long3r/eval/eval.hpp"
#include "long3r/geometry/pinhole_intrinsics.hpp"

namespace long3r {

// True camera-frame points (CV_32FC3, NaN where the depth has none) at the
// pixels of an image with intrinsics `model_K` (model resolution), from a
// true depth image (CV_32FC1 metres, 0 or NaN = none) of an undistorted camera
// with intrinsics `depth_K`: each pixel's ray is followed into the depth
// image (nearest pixel, so depth edges are not blended) and the point is at
// that depth along the ray. Throws std::invalid_argument for an empty or
// non-float depth image or intrinsics without a focal length.
cv::Mat true_points_at_pixels(const cv::Mat& depth_m, const PinholeIntrinsics& depth_K,
                              const PinholeIntrinsics& model_K, cv::Size model_size);

struct FusionBoundSummary {
  std::size_t frames = 0;
  std::size_t pairs = 0;   // pixels with a prediction and a true point
  std::size_t voxels = 0;  // true voxels seen
  double mean_views = 0;   // frames per voxel, averaged over the voxels
  // Correspondence error ||prediction - truth||, metres, per voxel: the mean
  // of its single views' errors; its average's error (all views averaged);
  // that of its average with each frame's depth ratio divided out.
  ErrorStatistics single_view_m, averaged_m, averaged_rescaled_m;
  // Per frame, median predicted / true depth over its pairs.
  std::vector<double> depth_ratio;
  double depth_ratio_median = 0, depth_ratio_mad = 0;  // over the frames
};

class FusionBound {
 public:
  // voxel_size_m > 0: the true surface's bins (the map's voxel size, so that
  // the averaged cloud is as dense as the point map). Throws
  // std::invalid_argument otherwise.
  explicit FusionBound(double voxel_size_m);

  // One frame: predicted and true points in its camera frame (CV_32FC3 of one
  // size, metres; non-finite or z <= 0 entries skipped), its true pose.
  // Throws std::invalid_argument for mismatched or non-CV_32FC3 images.
  void add(const cv::Mat& predicted_C, const cv::Mat& true_C, const Eigen::Isometry3d& T_W_C);

  // Each true voxel's averaged prediction, in W; rescaled: each frame's
  // points divided by its depth ratio before they are averaged.
  std::vector<Eigen::Vector3f> averaged_points(bool rescaled = false) const;
  FusionBoundSummary summary() const;

 private:
  struct Voxel {
    Eigen::Vector3d sum_predicted = Eigen::Vector3d::Zero();
    Eigen::Vector3d sum_rescaled = Eigen::Vector3d::Zero();
    Eigen::Vector3d sum_true = Eigen::Vector3d::Zero();
    double sum_error = 0;
    std::uint32_t pairs = 0;
    std::uint32_t views = 0;
    std::int64_t last_frame = -1;
  };
  double voxel_size_m_;
  std::unordered_map<std::uint64_t, Voxel> voxels_;
  std::vector<double> depth_ratios_;
  std::int64_t frames_ = 0;
  std::size_t pairs_ = 0;
};

}  // namespace long3r

// Camera intrinsics at model resolution: from a calibration of the source
// camera carried through the preprocessing resize + crop, or, without one,
// estimated from the first frame's pointmap (DUSt3R's reprojection method
// with Weiszfeld iterations).
//
// Pixel convention (PinholeIntrinsics): integer pixel coordinates are pixel
// centres, (0, 0) is the centre of the top-left pixel; a camera-frame point
// (x right, y down, z forward) projects to (fx x / z + cx, fy y / z + cy).
// The image centre of a W x H image is therefore ((W - 1) / 2, (H - 1) / 2).
#pragma once

#include <opencv2/core/mat.hpp>

#include <optional>
#include <string>

#include "long3r/geometry/pinhole_intrinsics.hpp"
#include "long3r/pipeline/preprocess.hpp"

namespace long3r {

enum class IntrinsicsSource {
  kCalibration,         // scaled from a calibration of the source camera
  kEstimatedWeiszfeld,  // focal estimated from frame 0's pointmap
};
const char* to_string(IntrinsicsSource source);

// The calibration of the source image (source pixels) seen through the
// preprocessing: for model_to_source = (a, b) per axis,
//   fx' = fx / a_x, cx' = (cx - b_x) / a_x (same for y),
// so projecting through the result and mapping the pixel with
// model_to_source gives the source camera's projection exactly.
// Throws std::invalid_argument if `source` is not valid().
PinholeIntrinsics scale_intrinsics(const PinholeIntrinsics& source,
                                   const PixelMapping& model_to_source, int model_width,
                                   int model_height);

struct FocalEstimationOptions {
  // Pixels used: finite points with z > 0 and conf >= conf_threshold (conf is
  // the model's confidence, >= 1; 0 uses every pixel, as DUSt3R does).
  float conf_threshold = 0.0f;
  int iterations = 10;  // Weiszfeld (IRLS) iterations after the L2 start; 0 = L2 only
  // Result clipped to [min, max] x focal_base, focal_base =
  // max(W, H) / (2 tan(30 deg)) (a 60 degree field of view), as DUSt3R does.
  double min_focal_ratio = 0.5;
  double max_focal_ratio = 3.5;
  int min_points = 16;  // fewer usable pixels -> no estimate
};

// Focal length (square pixels) of the camera that saw the pointmap, with the
// principal point at the image centre: minimises sum_i |p_i - f (x_i, y_i) / z_i|
// (p_i = pixel - centre) by iteratively re-weighted least squares started at
// the L2 solution f0 = sum(q.p) / sum(q.q), q = (x, y) / z, each step
// f = sum(w q.p) / sum(w q.q) with w = 1 / max(|p - f q|, 1e-8).
// (DUSt3R puts the principal point at (W/2, H/2) of its integer grid, half a
// pixel from the centre in the convention above; the centre is used here.)
// pts3d: CV_32FC3 [H, W] in the camera frame of the image (for frame 0 of a
// stream the model's output frame); conf: CV_32FC1 [H, W] or empty.
// Returns nullopt when fewer than min_points pixels are usable.
std::optional<double> estimate_focal_weiszfeld(const cv::Mat& pts3d, const cv::Mat& conf,
                                               const FocalEstimationOptions& options = {});

// The intrinsics the model's pointmap implies: fx = fy = the focal above,
// (cx, cy) at the image centre, width/height from the pointmap.
std::optional<PinholeIntrinsics> estimate_intrinsics(const cv::Mat& pts3d, const cv::Mat& conf,
                                                     const FocalEstimationOptions& options = {});

struct ResolvedIntrinsics {
  PinholeIntrinsics intrinsics;  // at model resolution
  IntrinsicsSource source = IntrinsicsSource::kCalibration;
};

// The calibration, if given, scaled to model resolution (its width/height, if
// set, must equal the source image's: std::invalid_argument otherwise);
// otherwise the estimate from frame 0's pointmap. nullopt only when there is
// no calibration and the estimate fails (too few usable pixels).
std::optional<ResolvedIntrinsics> resolve_intrinsics(
    const std::optional<PinholeIntrinsics>& calibration, const PreprocessedImage& frame0,
    const cv::Mat& frame0_pts3d, const cv::Mat& frame0_conf,
    const FocalEstimationOptions& options = {});

}  // namespace long3r

// The blind control (train/blind_control.cpp): how much of a model's
// placement of a frame comes from its reference view (docs/model_card.md,
// "The blind control").
#pragma once

#include <ATen/core/Tensor.h>

#include <cstdint>
#include <limits>
#include <vector>

#include "long3r/model/network/long3r_model.hpp"
#include "long3r/train/prediction.hpp"
#include "long3r/train/train_data.hpp"

namespace long3r {

// What blind_control (below) measures.
struct BlindControl {
  static constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
  double reg_true = kNaN, reg_blind = kNaN;  // means over the frames scored
  double blind_ratio = kNaN;                 // reg_true / reg_blind
  // Mean over the frames of the true run's error after aligning each
  // frame's prediction to its ground truth by a Sim(3) of its own
  // (shape_error): what is left when the frame's placement is perfect, the
  // floor of reg_true.
  double shape_err = kNaN;
  double rot_err_deg = kNaN;   // mean angle between applied and true relative rotation
  double rot_true_deg = kNaN;  // mean true relative rotation (a model that never turns scores this)
  double motion_px = kNaN;  // mean over frames of the median image motion of their points, pixels
  int64_t frames = 0;       // frames scored
  int64_t unplaced = 0;     // frames left out: a non-finite or collapsed prediction
};

// The error of a frame's shape alone: the prediction p ([H, W, 3], any
// coordinates) aligned to the ground truth g by the Sim(3) that fits it best
// over the valid pixels (Umeyama), then mean || p' - g || divided by the mean
// distance of g's valid points to the origin, the normalisation of
// frame_placement_error's ground truth. NaN when the fit fails (fewer than
// three points, a collapsed or non-finite prediction).
double frame_shape_error(const at::Tensor& pred, const at::Tensor& gt, const at::Tensor& valid);

// The blind control: does the model place a frame using its reference view?
// For every frame k >= 1 of each sequence, the placement error of frame k in
// the reference's (camera 0's) coordinates (frame_placement_error) when the
// model runs on the true sequence (reg_true), and when it is given frame k
// itself as its reference, i.e. the pair (frame k, frame k), whose second
// view is placed by the head that places a pair's second view (reg_blind).
// blind_ratio = reg_true / reg_blind: about 1 for a model that does not
// register (it predicts each frame in its own camera, wherever the reference
// was), 0 for perfect registration. Also the shape error of the true run's
// frames (frame_shape_error), the rotation the true run applies to
// each frame (Umeyama of the frame's ground-truth points in its own camera
// onto its prediction) against the true relative rotation, and the median image
// motion of the frames' points relative to camera 0 (ground truth).
//
// Sequences of one length >= 2 (e.g. validation_sequence); runs in inference
// mode (switched and switched back), batched.
BlindControl blind_control(Long3rModel& model, const std::vector<SequenceSample>& sequences);

// The scoring half of blind_control, for any predictor: truth[s] and blind[s]
// hold the N pointmaps of sequence s in camera 0's frame, from the true
// sequence and from each frame given itself as its reference (frame 0's
// blind entry is not read).
BlindControl score_blind_control(const std::vector<SequenceSample>& sequences,
                                 const std::vector<SequencePrediction>& truth,
                                 const std::vector<SequencePrediction>& blind);

// mean over valid pixels of || p / z_p - g / z_g ||, p the predicted and g the
// true pointmap of one frame ([H, W, 3], same coordinates), each divided by
// the mean distance of its own valid points to the origin, so that only where
// the frame is placed and shaped counts, not its scale. NaN when either has
// no extent or the prediction is not finite.
double frame_placement_error(const at::Tensor& pred, const at::Tensor& gt, const at::Tensor& valid);

}  // namespace long3r

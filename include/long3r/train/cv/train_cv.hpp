// The trainer's OpenCV side (library long3r_train_cv: the pipeline's PnP,
// the evaluation metrics, the dataset reader, plots): held-out scoring with
// the paper's metrics, TUM folders as training data, the loss-curve picture,
// and the extensions that hand these to the trainer's core (trainer.hpp).
#pragma once

#include <opencv2/core.hpp>

#include <memory>
#include <string>
#include <vector>

#include "long3r/pipeline/pose.hpp"
#include "long3r/train/prediction.hpp"
#include "long3r/train/train_config.hpp"
#include "long3r/train/train_data.hpp"
#include "long3r/train/trainer.hpp"

namespace long3r {

// All of the below for a Trainer: full_validation_scorer, TUM folders,
// loss_curve.png.
TrainerExtensions opencv_trainer_extensions();

// A TUM-layout folder as training data: frames with depth and pose, and
// calibration.txt. Throws std::runtime_error naming what is missing.
std::unique_ptr<RecordedSource> open_tum_training_source(const std::string& dir);

struct PredictionMetricsOptions {
  int pixel_step = 2;   // subsampling of the clouds
  bool normals = true;  // NC
  // When set: a PNG of the aligned prediction next to the GT, top views
  // coloured by Acc / Comp error (plot_error_top_view, saturating at
  // picture_max_error_m).
  std::string picture_path;
  double picture_max_error_m = 0.3;
  // Intrinsics of the PnP poses: the generator's (false) or, as the pipeline
  // does without a calibration, estimated from frame 0's pointmap (true; if
  // that fails, no frame is posed).
  bool estimate_intrinsics = false;
  PnpRansac pnp_ransac = PnpConfig{}.ransac;  // the pipeline's default
};
// Scores a prediction against the sequence's ground truth: one Sim(3)
// (Umeyama on corresponding valid pixels) aligns the predicted points to the
// GT (pointmap_error as pointmap_metrics), then Acc / Comp / NC on the
// aligned clouds; camera poses by PnP on the predicted pointmaps (all
// pixels, as validation) give ATE / RPE after their own Sim(3) alignment. An
// estimate without any motion (the baseline) has no unique Sim(3); its
// least-squares optimum maps every pose onto the GT centroid, so ATE is then
// the spread of the GT positions and RPE the GT's own frame-to-frame motion.
PredictionMetrics evaluate_prediction(const SequencePrediction& prediction,
                                      const SequenceSample& sample,
                                      const PredictionMetricsOptions& options);
// evaluate_prediction with the validation config's pixel step and normals.
PredictionMetrics full_validation_scorer(const SequencePrediction& prediction,
                                         const SequenceSample& sample,
                                         const ValidationConfig& config);

// Oracle of the loss probe (docs/model_card.md, "Why the model does not
// register"), from the ground truth, confidence 1: every frame's exact
// pointmap in its own camera, all cameras at camera 0 (a perfect depth
// predictor that never registers). first_frame_prediction is the other.
SequencePrediction true_depth_no_motion_prediction(const SequenceSample& sample);

// loss_curve.png: training loss (raw and smoothed), validation loss and the
// learning rate over the steps (plot_line_chart).
cv::Mat plot_training_curves(const std::vector<LogRow>& rows, int width = 900, int height = 560);

}  // namespace long3r

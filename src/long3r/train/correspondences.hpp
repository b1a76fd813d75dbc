// Corresponding valid pixels of a predicted and a ground-truth pointmap, and
// the sequence's Sim(3) fit on them: shared by pointmap_metrics, probe_loss
// and evaluate_prediction. Private to the train libraries.
#pragma once

#include <ATen/core/Tensor.h>

#include <Eigen/Core>

#include <cstdint>
#include <vector>

#include "long3r/train/prediction.hpp"
#include "long3r/train/train_data.hpp"

namespace long3r {

// Appends the (prediction, GT) points of the valid pixels of one frame
// ([H, W, 3] pointmaps, [H, W] mask), every `step`-th row and column.
// Pixels whose prediction is not finite are left out; returns their count.
int64_t append_correspondences(const at::Tensor& pred, const at::Tensor& gt,
                               const at::Tensor& valid, int step,
                               std::vector<Eigen::Vector3f>* pred_pts,
                               std::vector<Eigen::Vector3f>* gt_pts);

// One Sim(3) (Umeyama) for the whole sequence, aligning the predicted points
// to the GT on the valid pixels every `step`-th row and column; returns the
// mean distance after it and, when asked, the aligned points and their GT
// partners. Throws std::invalid_argument for mismatched pointmap sizes and
// std::runtime_error for fewer than 3 usable points.
double aligned_pointmap_error(const SequencePrediction& prediction, const SequenceSample& sample,
                              int step, std::vector<Eigen::Vector3f>* aligned,
                              std::vector<Eigen::Vector3f>* gt_pts);

}  // namespace long3r

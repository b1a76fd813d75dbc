// The blind control: how much of a model's placement of a frame comes from
// its reference view (docs/model_card.md, "The blind control").
#include <ATen/ATen.h>
#include <c10/core/InferenceMode.h>

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "long3r/geometry/umeyama.hpp"
#include "long3r/train/blind_control.hpp"
#include "long3r/train/correspondences.hpp"
#include "long3r/train/prediction.hpp"
#include "long3r/train/train_data.hpp"

namespace long3r {

namespace {

constexpr int64_t kChunk = 16;  // sequences per batched forward pass

double rad_to_deg(double r) { return r * 180.0 / M_PI; }

double rotation_angle_deg(const Eigen::Matrix3d& R) {
  return rad_to_deg(std::acos(std::clamp((R.trace() - 1.0) / 2.0, -1.0, 1.0)));
}

// Pointmaps [B, H, W, 3] (CPU float32) of frame `index` of forward passes
// over `frames` (each [B, 3, H, W]).
at::Tensor run_frames(Long3rModel& model, const std::vector<at::Tensor>& frames,
                      std::size_t index) {
  const std::vector<StreamOutput> out = model.forward_sequence(frames);
  return out[index].pts3d.to(at::kCPU, at::kFloat).contiguous();
}

// [H, W, 3] points moved by T.
at::Tensor transform_points(const at::Tensor& pts, const Eigen::Isometry3d& T) {
  const Eigen::Matrix<float, 3, 3, Eigen::RowMajor> Rt = T.linear().transpose().cast<float>();
  const Eigen::Vector3f t = T.translation().cast<float>();
  const at::Tensor R_T = at::from_blob(const_cast<float*>(Rt.data()), {3, 3}, at::kFloat).clone();
  const at::Tensor tt = at::from_blob(const_cast<float*>(t.data()), {3}, at::kFloat).clone();
  return at::matmul(pts, R_T) + tt;
}

// Mean distance of the valid points of [H, W, 3] to the origin.
double mean_distance(const at::Tensor& pts, const at::Tensor& valid) {
  const at::Tensor d = pts.norm(2, -1).masked_select(valid);
  return d.numel() > 0 ? d.mean().item<double>() : 0.0;
}

// Image motion of frame k's valid pixels in the reference camera, pixels
// (their median).
double motion_px(const SequenceSample& s, int64_t k) {
  const PinholeIntrinsics& K0 = s.intrinsics[0];
  const at::Tensor g = s.pts[k];
  const int64_t H = g.size(0), W = g.size(1);
  const at::Tensor u = at::arange(W, at::kFloat).view({1, W}).expand({H, W});
  const at::Tensor v = at::arange(H, at::kFloat).view({H, 1}).expand({H, W});
  const at::Tensor z = g.select(-1, 2);
  const at::Tensor in_front = s.valid[k] & (z > 1e-6);
  const at::Tensor zs = at::where(in_front, z, at::ones_like(z));
  const at::Tensor du =
      g.select(-1, 0) / zs * static_cast<float>(K0.fx) + static_cast<float>(K0.cx) - u;
  const at::Tensor dv =
      g.select(-1, 1) / zs * static_cast<float>(K0.fy) + static_cast<float>(K0.cy) - v;
  // The median: points that come close to camera 0's image plane project
  // arbitrarily far and would rule a mean.
  const at::Tensor d = (du * du + dv * dv).sqrt().masked_select(in_front);
  return d.numel() > 0 ? d.median().item<double>() : std::numeric_limits<double>::quiet_NaN();
}

}  // namespace

double frame_placement_error(const at::Tensor& pred, const at::Tensor& gt,
                             const at::Tensor& valid) {
  const double zp = mean_distance(pred, valid), zg = mean_distance(gt, valid);
  if (!(zp > 0.0) || !(zg > 0.0) || !std::isfinite(zp)) {
    return std::numeric_limits<double>::quiet_NaN();
  }
  const at::Tensor e = (pred / zp - gt / zg).norm(2, -1).masked_select(valid);
  return e.mean().item<double>();
}

double frame_shape_error(const at::Tensor& pred, const at::Tensor& gt, const at::Tensor& valid) {
  std::vector<Eigen::Vector3f> src, dst;
  append_correspondences(pred, gt, valid, 1, &src, &dst);
  const double zg = mean_distance(gt, valid);
  if (src.size() < 3 || !(zg > 0.0)) return std::numeric_limits<double>::quiet_NaN();
  Sim3 T;
  try {
    T = align_correspondences(src, dst, true);
  } catch (const std::invalid_argument&) {
    return std::numeric_limits<double>::quiet_NaN();  // a collapsed prediction
  }
  double sum = 0.0;
  for (std::size_t i = 0; i < src.size(); ++i) {
    sum += (T * src[i].cast<double>() - dst[i].cast<double>()).norm();
  }
  const double e = sum / static_cast<double>(src.size()) / zg;
  return std::isfinite(e) ? e : std::numeric_limits<double>::quiet_NaN();
}

BlindControl score_blind_control(const std::vector<SequenceSample>& sequences,
                                 const std::vector<SequencePrediction>& truth,
                                 const std::vector<SequencePrediction>& blind) {
  if (sequences.empty()) throw std::invalid_argument("blind_control: no sequences");
  if (truth.size() != sequences.size() || blind.size() != sequences.size()) {
    throw std::invalid_argument("blind_control: one true and one blind prediction per sequence");
  }
  BlindControl r;
  double sum_true = 0, sum_blind = 0, sum_rot_err = 0, sum_rot = 0, sum_motion = 0, sum_shape = 0;
  int64_t motion_n = 0, shape_n = 0;
  for (std::size_t s = 0; s < sequences.size(); ++s) {
    const SequenceSample& seq = sequences[s];
    const std::size_t n = seq.images.size();
    if (n < 2 || truth[s].pts.size() != n || blind[s].pts.size() != n) {
      throw std::invalid_argument("blind_control: predictions need the sequence's N >= 2 frames");
    }
    for (std::size_t k = 1; k < n; ++k) {
      const int64_t f = static_cast<int64_t>(k);
      const at::Tensor& valid = seq.valid[f];
      const at::Tensor& pred = truth[s].pts[k];
      const double e_true = frame_placement_error(pred, seq.pts[f], valid);
      const double e_blind = frame_placement_error(blind[s].pts[k], seq.pts[f], valid);
      if (!std::isfinite(e_true) || !std::isfinite(e_blind)) {
        ++r.unplaced;
        continue;
      }
      sum_true += e_true;
      sum_blind += e_blind;
      const double shape = frame_shape_error(pred, seq.pts[f], valid);
      if (std::isfinite(shape)) {
        sum_shape += shape;
        ++shape_n;
      }
      // The rotation the prediction applies to the frame: its points in
      // their own camera (ground truth) onto the predicted ones.
      const at::Tensor own_gt = transform_points(seq.pts[f], seq.T_C0_C[k].inverse());
      std::vector<Eigen::Vector3f> src, dst;
      append_correspondences(own_gt, pred, valid, 1, &src, &dst);
      const Eigen::Matrix3d R_true = seq.T_C0_C[k].linear();
      double rot_err = rotation_angle_deg(R_true);  // as a prediction that never turns
      try {
        if (src.size() >= 3) {
          const Sim3 T = align_correspondences(src, dst, true);  // own camera -> prediction
          rot_err = rotation_angle_deg(T.rotation.transpose() * R_true);
        }
      } catch (const std::invalid_argument&) {
        // A collapsed prediction applies no rotation: scored as none.
      }
      sum_rot_err += rot_err;
      sum_rot += rotation_angle_deg(R_true);
      const double m = motion_px(seq, f);
      if (std::isfinite(m)) {
        sum_motion += m;
        ++motion_n;
      }
      ++r.frames;
    }
  }
  if (r.frames > 0) {
    const double nf = static_cast<double>(r.frames);
    r.reg_true = sum_true / nf;
    r.reg_blind = sum_blind / nf;
    if (r.reg_blind > 0.0) r.blind_ratio = r.reg_true / r.reg_blind;
    r.rot_err_deg = sum_rot_err / nf;
    r.rot_true_deg = sum_rot / nf;
  }
  if (motion_n > 0) r.motion_px = sum_motion / static_cast<double>(motion_n);
  if (shape_n > 0) r.shape_err = sum_shape / static_cast<double>(shape_n);
  return r;
}

BlindControl blind_control(Long3rModel& model, const std::vector<SequenceSample>& sequences) {
  if (sequences.empty()) throw std::invalid_argument("blind_control: no sequences");
  const std::size_t n = sequences[0].images.size();
  if (n < 2) throw std::invalid_argument("blind_control: sequences need >= 2 frames");
  for (const SequenceSample& s : sequences) {
    if (s.images.size() != n) {
      throw std::invalid_argument("blind_control: sequences of unequal length");
    }
  }
  std::vector<SequencePrediction> truth(sequences.size()), blind(sequences.size());
  {
    const TrainingModeGuard inference(model, false);
    c10::InferenceMode guard;
    for (std::size_t c0 = 0; c0 < sequences.size(); c0 += kChunk) {
      const std::size_t c1 = std::min(sequences.size(), c0 + kChunk);
      // The true run: each sequence as it is, a batch of sequences at once.
      std::vector<at::Tensor> frames;
      for (std::size_t i = 0; i < n; ++i) {
        std::vector<at::Tensor> batch;
        for (std::size_t s = c0; s < c1; ++s) batch.push_back(sequences[s].images[i]);
        frames.push_back(at::stack(batch).to(model.device()));
      }
      const std::vector<StreamOutput> out = model.forward_sequence(frames);
      for (std::size_t k = 0; k < n; ++k) {
        const at::Tensor pts = out[k].pts3d.to(at::kCPU, at::kFloat);
        // Blind: frame k given itself as its reference, placed by the head
        // that places a pair's second view (frame 0 has no blind twin).
        const at::Tensor own = k == 0 ? at::Tensor() : run_frames(model, {frames[k], frames[k]}, 1);
        for (std::size_t s = c0; s < c1; ++s) {
          const int64_t b = static_cast<int64_t>(s - c0);
          truth[s].pts.push_back(pts[b].contiguous());
          blind[s].pts.push_back(k == 0 ? pts[b].contiguous() : own[b].contiguous());
        }
      }
    }
  }
  return score_blind_control(sequences, truth, blind);
}

}  // namespace long3r

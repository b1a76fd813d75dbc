// Trainer pieces: loss, ground truth, schedule, optimisation, curriculum
// freezing, checkpoint/resume, initialisation and configuration.
#include <ATen/ATen.h>
#include <gtest/gtest.h>
#include <torch/nn/module.h>
#include <torch/nn/modules/linear.h>
#include <torch/nn/modules/normalization.h>
#include <torch/optim/adamw.h>

#include <opencv2/core.hpp>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <map>
#include <optional>
#include <random>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include "long3r/model/loading/safetensors.hpp"
#include "long3r/model/network/long3r_model.hpp"
#include "long3r/model/runtime/inference.hpp"
#include "long3r/pipeline/pose.hpp"
#include "long3r/synth/cv/dataset_layouts.hpp"
#include "long3r/train/blind_control.hpp"
#include "long3r/train/cross_view_completion.hpp"
#include "long3r/train/cv/train_cv.hpp"
#include "long3r/train/data_parallel.hpp"
#include "long3r/train/frame_cache.hpp"
#include "long3r/train/prediction.hpp"
#include "long3r/train/train_config.hpp"
#include "long3r/train/train_data.hpp"
#include "long3r/train/train_loss.hpp"
#include "long3r/train/trainer.hpp"
#include "long3r/train/weight_init.hpp"
#include "support/test_support.hpp"

namespace fs = std::filesystem;
using long3r::LossConfig;
using long3r::StreamOutput;

namespace {

// N outputs (and N-1 coarse) equal to `pts` [B, N, H, W, 3] times `scale`.
void make_outputs(const at::Tensor& pts, double scale, const at::Tensor& conf,
                  std::vector<StreamOutput>* out, std::vector<StreamOutput>* coarse) {
  const int64_t N = pts.size(1);
  out->clear();
  coarse->clear();
  for (int64_t i = 0; i < N; ++i) {
    StreamOutput o;
    o.pts3d = pts.select(1, i) * scale;
    o.conf = conf.select(1, i);
    out->push_back(o);
    if (i > 0) coarse->push_back(o);
  }
}

at::Tensor random_gt(int64_t B, int64_t N, int64_t H, int64_t W) {
  at::Tensor p = at::randn({B, N, H, W, 3});
  p.select(-1, 2).abs_().add_(1.0);  // in front of the camera
  return p;
}

std::string scratch(const std::string& name) { return long3r::test::scratch_dir("train/" + name); }

// `steps` AdamW steps (lr 2e-3) of the sequence loss on one fixed batch:
// the regression term of the first and of the last step.
std::pair<double, double> overfit(long3r::Long3rModel& model, const long3r::Batch& batch,
                                  int steps) {
  torch::optim::AdamW opt(model.module().parameters(), torch::optim::AdamWOptions(2e-3));
  double first = 0, last = 0;
  for (int i = 0; i < steps; ++i) {
    opt.zero_grad();
    std::vector<StreamOutput> coarse;
    const auto out = model.forward_sequence(batch.frames, &coarse);
    const long3r::LossTerms t =
        long3r::sequence_loss(out, coarse, batch.pts, batch.valid, LossConfig{});
    t.total.backward();
    opt.step();
    if (i == 0) first = t.regression;
    last = t.regression;
  }
  return {first, last};
}

// A configuration small enough for a unit test: long3r_tiny at 64 x 64.
long3r::TrainConfig tiny_config() {
  long3r::TrainConfig c;
  c.model = "long3r_tiny";
  c.image_size = 64;
  long3r::TrainStage s1;
  s1.name = "s1";
  s1.steps = 3;
  s1.frames = 3;
  s1.batch_size = 1;
  s1.lr = 1e-3;
  s1.warmup_steps = 1;
  long3r::TrainStage s2 = s1;
  s2.name = "s2";
  s2.frames = 4;
  s2.lr = 1e-4;
  s2.freeze_encoder = true;
  c.stages = {s1, s2};
  c.data.synth.train_scenes = 4;
  c.data.synth.val_scenes = 0;
  c.data.synth.trajectory_frames = 30;
  c.validation.sequences = 0;
  c.checkpoint_every = 0;
  return c;
}

// tiny_config() validated once, at the end of a run: one 3-frame sequence.
long3r::TrainConfig tiny_config_validated_at_end() {
  long3r::TrainConfig c = tiny_config();
  c.validation.sequences = 1;
  c.validation.frames = 3;
  c.validation.every = 0;
  c.data.synth.val_scenes = 1;
  return c;
}

}  // namespace

TEST(TrainLoss, PerfectPredictionHasZeroRegressionAndUnitConfidenceZeroLoss) {
  at::manual_seed(1);
  const at::Tensor gt = random_gt(2, 3, 4, 5);
  const at::Tensor valid = at::ones({2, 3, 4, 5}, at::kBool);
  std::vector<StreamOutput> out, coarse;
  LossConfig cfg;
  // A prediction at a smaller scale is a perfect one after normalisation; with
  // conf = 1 the -alpha log conf term vanishes and the scale loss is off.
  make_outputs(gt, 0.5, at::ones({2, 3, 4, 5}), &out, &coarse);
  long3r::LossTerms t = long3r::sequence_loss(out, coarse, gt, valid, cfg);
  EXPECT_NEAR(t.total.item<double>(), 0.0, 1e-5);
  EXPECT_NEAR(t.regression, 0.0, 1e-5);
  EXPECT_DOUBLE_EQ(t.scale_loss.item<double>(), 0.0);
  // Higher confidence on a perfect prediction lowers the loss (-alpha log c).
  make_outputs(gt, 0.5, at::full({2, 3, 4, 5}, 3.0), &out, &coarse);
  t = long3r::sequence_loss(out, coarse, gt, valid, cfg);
  EXPECT_NEAR(t.total.item<double>(), -cfg.alpha * std::log(3.0), 1e-5);
  // A wrong prediction costs.
  std::vector<StreamOutput> bad, bad_coarse;
  make_outputs(gt + at::randn_like(gt) * 0.3, 1.0, at::ones({2, 3, 4, 5}), &bad, &bad_coarse);
  t = long3r::sequence_loss(bad, bad_coarse, gt, valid, cfg);
  EXPECT_GT(t.total.item<double>(), 0.05);
  EXPECT_GT(t.regression, 0.05);
}

TEST(TrainLoss, InvalidPixelsAreIgnored) {
  at::manual_seed(2);
  const at::Tensor gt = random_gt(1, 2, 4, 4);
  at::Tensor valid = at::ones({1, 2, 4, 4}, at::kBool);
  std::vector<StreamOutput> out, coarse;
  make_outputs(gt, 1.0, at::ones({1, 2, 4, 4}), &out, &coarse);
  // Garbage where the GT is invalid changes nothing.
  valid[0][1][2][3] = false;
  out[1].pts3d = out[1].pts3d.clone();
  out[1].pts3d[0][2][3] = at::tensor({1e3f, -1e3f, 1e3f});
  coarse[0] = out[1];
  // The normalisation of the prediction only uses valid pixels too.
  const long3r::LossTerms t = long3r::sequence_loss(out, coarse, gt, valid, LossConfig());
  EXPECT_NEAR(t.total.item<double>(), 0.0, 1e-5);
}

TEST(TrainLoss, RegressionIsInvariantToThePredictionsScale) {
  at::manual_seed(3);
  const at::Tensor gt = random_gt(2, 4, 3, 3);
  const at::Tensor valid = at::rand({2, 4, 3, 3}) > 0.2;
  const at::Tensor pred = gt + at::randn_like(gt) * 0.5;
  const at::Tensor conf = 1.0 + at::rand({2, 4, 3, 3}) * 4.0;
  std::vector<StreamOutput> out, coarse;
  LossConfig cfg;
  cfg.scale_weight = 0.0;
  make_outputs(pred, 1.0, conf, &out, &coarse);
  const double a = long3r::sequence_loss(out, coarse, gt, valid, cfg).total.item<double>();
  make_outputs(pred, 7.5, conf, &out, &coarse);
  const double b = long3r::sequence_loss(out, coarse, gt, valid, cfg).total.item<double>();
  EXPECT_NEAR(a, b, 1e-5 * std::abs(a));
  // The GT's own scale does not matter either.
  make_outputs(pred, 1.0, conf, &out, &coarse);
  const double c = long3r::sequence_loss(out, coarse, gt * 0.1, valid, cfg).total.item<double>();
  EXPECT_NEAR(a, c, 1e-5 * std::abs(a));
}

TEST(TrainLoss, ScaleLossPenalisesOnlyLargerPredictions) {
  at::manual_seed(4);
  const at::Tensor gt = random_gt(1, 3, 4, 4);
  const at::Tensor valid = at::ones({1, 3, 4, 4}, at::kBool);
  const double z = long3r::average_distance(gt, valid).item<double>();
  std::vector<StreamOutput> out, coarse;
  make_outputs(gt, 2.0, at::ones({1, 3, 4, 4}), &out, &coarse);
  long3r::LossTerms t = long3r::sequence_loss(out, coarse, gt, valid, LossConfig());
  EXPECT_NEAR(t.scale_loss.item<double>(), z, 1e-4 * z);  // 2z - z
  EXPECT_NEAR(t.total.item<double>(), t.conf_loss.item<double>() + z, 1e-4 * z);
  make_outputs(gt, 0.9, at::ones({1, 3, 4, 4}), &out, &coarse);
  t = long3r::sequence_loss(out, coarse, gt, valid, LossConfig());
  EXPECT_DOUBLE_EQ(t.scale_loss.item<double>(), 0.0);
  // Batch: only the item with the larger prediction counts, averaged over
  // such items (Spann3R).
  const at::Tensor gt2 = at::cat({gt, gt});
  std::vector<StreamOutput> o2, c2;
  const at::Tensor pred2 = at::cat({gt * 3.0, gt * 0.5});
  make_outputs(pred2, 1.0, at::ones({2, 3, 4, 4}), &o2, &c2);
  t = long3r::sequence_loss(o2, c2, gt2, at::cat({valid, valid}), LossConfig());
  EXPECT_NEAR(t.scale_loss.item<double>(), 2.0 * z, 1e-4 * z);
  // And its gradient shrinks the prediction.
  at::Tensor p = (gt * 2.0).requires_grad_(true);
  make_outputs(p, 1.0, at::ones({1, 3, 4, 4}), &out, &coarse);
  LossConfig only_scale;
  only_scale.alpha = 1e-9;
  long3r::sequence_loss(out, coarse, gt, valid, only_scale).scale_loss.backward();
  EXPECT_GT((p.grad() * p.detach()).sum().item<double>(), 0.0);
}

TEST(TrainData, PrepareSequenceShrinksImagesByAreaAndDepthByNearest) {
  // A 4 x 4 frame to 2 x 2 (validation: full centred crop, no jitter).
  long3r::RawFrame f;
  f.bgr = at::arange(48, at::kFloat).mul(5.0).reshape({4, 4, 3}).to(at::kByte);
  f.depth = at::arange(16, at::kFloat).add(1.0).reshape({4, 4});
  f.intrinsics = long3r::PinholeIntrinsics::from_hfov(4, 4, 90.0);
  const long3r::SequenceSample s =
      long3r::prepare_sequence({f, f}, 2, long3r::AugmentConfig{}, nullptr, "t");
  ASSERT_EQ(s.images[0].sizes(), (at::IntArrayRef{3, 2, 2}));
  for (int v = 0; v < 2; ++v) {
    for (int u = 0; u < 2; ++u) {
      for (int c = 0; c < 3; ++c) {
        // Model channel c is RGB: BGR channel 2 - c, mean of the 2 x 2 block.
        double sum = 0.0;
        for (int dy = 0; dy < 2; ++dy) {
          for (int dx = 0; dx < 2; ++dx) {
            sum += f.bgr[2 * v + dy][2 * u + dx][2 - c].item<double>();
          }
        }
        EXPECT_NEAR(s.images[0][c][v][u].item<double>(), (sum / 4.0 / 255.0 - 0.5) / 0.5, 1e-5)
            << "pixel " << u << "," << v << " channel " << c;
      }
      // Nearest: source pixel (2u, 2v), never a mix across pixels.
      EXPECT_FLOAT_EQ(s.pts[0][v][u][2].item<float>(), f.depth[2 * v][2 * u].item<float>());
    }
  }
  EXPECT_TRUE(s.valid.all().item<bool>());
  // Growing is bilinear with pixel centres aligned: a constant stays constant.
  long3r::RawFrame flat = f;
  flat.bgr = at::full({4, 4, 3}, 51, at::kByte);
  const long3r::SequenceSample big =
      long3r::prepare_sequence({flat, flat}, 8, long3r::AugmentConfig{}, nullptr, "t");
  EXPECT_NEAR((big.images[1] - (51.0 / 255.0 - 0.5) / 0.5).abs().max().item<double>(), 0.0, 1e-6);
  // Frames that are not [H, W, 3] uint8 with an [H, W] float32 depth are refused.
  long3r::RawFrame bad = f;
  bad.depth = at::zeros({4, 3}, at::kFloat);
  EXPECT_THROW(long3r::prepare_sequence({f, bad}, 2, long3r::AugmentConfig{}, nullptr, "t"),
               std::invalid_argument);
  bad = f;
  bad.bgr = f.bgr.to(at::kFloat);
  EXPECT_THROW(long3r::prepare_sequence({bad, f}, 2, long3r::AugmentConfig{}, nullptr, "t"),
               std::invalid_argument);
}

TEST(TrainData, PointmapMatchesHandComputation) {
  at::Tensor depth = at::zeros({2, 3}, at::kFloat);
  depth[0][0] = 2.0f;
  depth[1][2] = 4.0f;
  depth[0][1] = std::nanf("");
  long3r::PinholeIntrinsics k;
  k.fx = 2.0;
  k.fy = 4.0;
  k.cx = 1.0;
  k.cy = 0.5;
  // Camera C sits 1 m along x of camera 0 and is turned 90 degrees about z.
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  T.translation() = Eigen::Vector3d(1.0, 0.0, 0.0);
  at::Tensor valid;
  const at::Tensor pts = long3r::depth_to_pointmap(depth, k, T, &valid);
  ASSERT_EQ(pts.sizes(), (at::IntArrayRef{2, 3, 3}));
  EXPECT_TRUE(valid[0][0].item<bool>());
  EXPECT_TRUE(valid[1][2].item<bool>());
  EXPECT_FALSE(valid[0][1].item<bool>());  // NaN depth
  EXPECT_FALSE(valid[1][0].item<bool>());  // zero depth
  EXPECT_EQ(valid.sum().item<int64_t>(), 2);
  // Pixel (u=0, v=0), z=2: camera point ((0-1)/2*2, (0-0.5)/4*2, 2) = (-1, -0.25, 2);
  // Rz(90) (x, y, z) -> (-y, x, z) = (0.25, -1, 2); + (1, 0, 0).
  EXPECT_NEAR(pts[0][0][0].item<float>(), 1.25f, 1e-6);
  EXPECT_NEAR(pts[0][0][1].item<float>(), -1.0f, 1e-6);
  EXPECT_NEAR(pts[0][0][2].item<float>(), 2.0f, 1e-6);
  // Pixel (u=2, v=1), z=4: ((2-1)/2*4, (1-0.5)/4*4, 4) = (2, 0.5, 4) -> (-0.5, 2, 4) + t.
  EXPECT_NEAR(pts[1][2][0].item<float>(), 0.5f, 1e-6);
  EXPECT_NEAR(pts[1][2][1].item<float>(), 2.0f, 1e-6);
  EXPECT_NEAR(pts[1][2][2].item<float>(), 4.0f, 1e-6);
  EXPECT_EQ(pts[1][0].abs().sum().item<float>(), 0.0f);
}

TEST(TrainData, CropResizeIntrinsicsFollowPixelCentres) {
  long3r::PinholeIntrinsics k;
  k.fx = k.fy = 100.0;
  k.cx = 63.5;
  k.cy = 47.5;
  // Cropping 64 x 64 at (32, 16) and halving: the pixel centre at source
  // (32, 16) lands at (0.25 - 0.5 + ...): check the mapping of two points.
  const long3r::PinholeIntrinsics r = long3r::crop_resize_intrinsics(k, 32, 16, 64, 64, 32, 32);
  EXPECT_DOUBLE_EQ(r.fx, 50.0);
  EXPECT_DOUBLE_EQ(r.cx, (63.5 - 32 + 0.5) * 0.5 - 0.5);
  EXPECT_DOUBLE_EQ(r.cy, (47.5 - 16 + 0.5) * 0.5 - 0.5);
  EXPECT_EQ(r.width, 32);
  // A 3D point projects to consistent pixels before and after.
  const Eigen::Vector3d X(0.3, -0.2, 2.0);
  const Eigen::Vector2d a = k.project(X), b = r.project(X);
  EXPECT_NEAR(b.x(), (a.x() - 32 + 0.5) * 0.5 - 0.5, 1e-9);
  EXPECT_NEAR(b.y(), (a.y() - 16 + 0.5) * 0.5 - 0.5, 1e-9);
}

TEST(TrainData, SequenceGroundTruthIsInCameraZerosFrame) {
  long3r::DataConfig dc;
  dc.synth.train_scenes = 2;
  dc.synth.trajectory_frames = 20;
  long3r::SequenceSampler sampler(dc, 64, 5);
  const long3r::SequenceSample s = sampler.validation_sequence(0, 3, 3);
  ASSERT_EQ(s.images.size(), 3u);
  EXPECT_EQ(s.images[0].sizes(), (at::IntArrayRef{3, 64, 64}));
  EXPECT_TRUE(s.T_C0_C[0].isApprox(Eigen::Isometry3d::Identity()));
  EXPECT_GT(s.valid.to(at::kFloat).mean().item<double>(), 0.9);  // closed rooms
  // Frame 0's points have the depth as z.
  const at::Tensor z0 = s.pts[0].select(-1, 2);
  EXPECT_GT(z0.masked_select(s.valid[0]).min().item<float>(), 0.0f);
  // Augmented samples are deterministic given the seed.
  long3r::SequenceSampler a(dc, 64, 9), b(dc, 64, 9);
  const long3r::SequenceSample sa = a.sample(3), sb = b.sample(3);
  EXPECT_EQ(sa.source, sb.source);
  EXPECT_TRUE(at::equal(sa.images[2], sb.images[2]));
  EXPECT_TRUE(at::equal(sa.pts, sb.pts));
  // Frame i's GT maps back into its own camera with depth = z.
  const Eigen::Isometry3d Ti = sa.T_C0_C[2].inverse();
  const at::Tensor p = sa.pts[2][32][32];
  const Eigen::Vector3d Xc =
      Ti * Eigen::Vector3d(p[0].item<float>(), p[1].item<float>(), p[2].item<float>());
  const Eigen::Vector2d px = sa.intrinsics[2].project(Xc);
  EXPECT_NEAR(px.x(), 32.0, 1e-3);
  EXPECT_NEAR(px.y(), 32.0, 1e-3);
}

TEST(TrainSchedule, WarmupThenCosine) {
  long3r::TrainConfig c = tiny_config();
  c.stages[0].steps = 10;
  c.stages[0].lr = 1.0;
  c.stages[0].warmup_steps = 4;
  c.stages[0].min_lr_ratio = 0.1;
  c.stages[1].steps = 5;
  c.stages[1].lr = 0.5;
  c.stages[1].warmup_steps = 0;
  c.stages[1].min_lr_ratio = 0.0;
  EXPECT_DOUBLE_EQ(long3r::learning_rate_at(c, 0), 0.25);
  EXPECT_DOUBLE_EQ(long3r::learning_rate_at(c, 3), 1.0);
  EXPECT_DOUBLE_EQ(long3r::learning_rate_at(c, 4), 1.0);  // cosine starts at the peak
  // Steps 4..9 decay over 6 steps: progress (s - 4) / 5.
  EXPECT_NEAR(long3r::learning_rate_at(c, 6), 0.1 + 0.45 * (1 + std::cos(M_PI * 0.4)), 1e-12);
  EXPECT_NEAR(long3r::learning_rate_at(c, 9), 0.1, 1e-12);
  EXPECT_DOUBLE_EQ(long3r::learning_rate_at(c, 10), 0.5);  // stage 2 restarts
  EXPECT_NEAR(long3r::learning_rate_at(c, 14), 0.0, 1e-12);
  EXPECT_EQ(long3r::stage_at(c, 12).index, 1);
  EXPECT_EQ(long3r::stage_at(c, 12).local_step, 2);
  EXPECT_EQ(long3r::stage_at(c, 15).index, 2);
}

TEST(TrainOptim, FewStepsOverfitAFixedBatch) {
  at::manual_seed(6);
  long3r::Long3rModel model(long3r::test::tiny_long3r_config());
  model.set_training(true);
  long3r::DataConfig dc;
  dc.synth.train_scenes = 1;
  dc.synth.trajectory_frames = 20;
  long3r::SequenceSampler sampler(dc, 64, 3);
  const auto [first, last] = overfit(model, long3r::collate({sampler.sample(3)}), 25);
  EXPECT_LT(last, 0.6 * first) << "first " << first << " last " << last;
}

// CroCo's layout and loss: patches row-major, pixels row by row, channels
// last; per-patch normalised targets; only hidden patches count.
TEST(TrainLoss, CrossViewCompletionPatchesAndLoss) {
  const int64_t p = 2;
  const at::Tensor yy = at::arange(4, at::kFloat).view({1, 1, 4, 1}).expand({1, 3, 4, 6});
  const at::Tensor xx = at::arange(6, at::kFloat).view({1, 1, 1, 6}).expand({1, 3, 4, 6});
  const at::Tensor cc = at::arange(3, at::kFloat).view({1, 3, 1, 1}).expand({1, 3, 4, 6});
  const at::Tensor img = (cc * 1000 + yy * 10 + xx).contiguous();
  const at::Tensor patches = long3r::patchify(img, p);
  ASSERT_EQ(patches.sizes(), (std::vector<int64_t>{1, 6, p * p * 3}));
  for (int64_t k = 0; k < 6; ++k) {
    for (int64_t py = 0; py < p; ++py) {
      for (int64_t px = 0; px < p; ++px) {
        for (int64_t c = 0; c < 3; ++c) {
          const double y = static_cast<double>((k / 3) * p + py),
                       x = static_cast<double>((k % 3) * p + px);
          EXPECT_EQ(patches[0][k][(py * p + px) * 3 + c].item<float>(), c * 1000 + y * 10 + x)
              << k << " " << py << " " << px << " " << c;
        }
      }
    }
  }

  at::manual_seed(3);
  const at::Tensor target = at::randn({2, 6, 12});
  const at::Tensor mean = target.mean(-1, true);
  const at::Tensor normalised = (target - mean) / (target.var(-1, true, true) + 1e-6).sqrt();
  const at::Tensor visible = at::tensor({1, 4}, at::kLong);
  at::Tensor pred = normalised.clone();
  pred.index_fill_(1, visible, 50.0);  // visible patches are not scored
  EXPECT_NEAR(long3r::completion_loss(pred, target, visible).item<double>(), 0.0, 1e-10);
  EXPECT_NEAR(long3r::completion_loss(pred + 1.0, target, visible).item<double>() -
                  long3r::completion_loss(pred.index_fill(1, visible, 1.0) + 0.0, target, visible)
                      .item<double>(),
              1.0, 1e-5);
  // The target's scale and offset per patch do not matter.
  EXPECT_NEAR(long3r::completion_loss(pred, target * 3.0 + 2.0, visible).item<double>(), 0.0, 1e-8);

  const at::Tensor v = long3r::draw_visible_patches(16, 0.75);
  ASSERT_EQ(v.numel(), 4);
  EXPECT_TRUE(at::equal(std::get<0>(v.sort()), v));
  EXPECT_EQ(std::get<0>(at::_unique(v)).numel(), 4);
  EXPECT_GE(v.min().item<int64_t>(), 0);
  EXPECT_LT(v.max().item<int64_t>(), 16);
  EXPECT_EQ(long3r::draw_visible_patches(16, 0.99).numel(), 1);
  EXPECT_THROW(long3r::draw_visible_patches(16, 1.0), std::invalid_argument);
}

// The model with a pixel head learns to complete a fixed pair: the pretext
// task is wired end to end.
TEST(TrainOptim, CrossViewCompletionFitsAFixedPair) {
  at::manual_seed(7);
  long3r::Long3rModel model(long3r::test::tiny_long3r_config());
  model.set_training(true);
  const int64_t p = model.config().dust3r.patch_size;
  torch::nn::Linear head(model.config().dust3r.dec_embed_dim, p * p * 3);
  long3r::DataConfig dc;
  dc.synth.train_scenes = 1;
  dc.synth.trajectory_frames = 20;
  long3r::SequenceSampler sampler(dc, 64, 3);
  const long3r::Batch batch = long3r::collate({sampler.sample(2)});
  std::vector<at::Tensor> params = model.module().parameters();
  for (const at::Tensor& t : head->parameters()) params.push_back(t);
  torch::optim::AdamW opt(params, torch::optim::AdamWOptions(2e-3));
  const at::Tensor visible = long3r::draw_visible_patches((64 / p) * (64 / p), 0.75);
  const at::Tensor target = long3r::patchify(batch.frames[1], p);
  // Predicting the patches' mean (0 after normalisation) scores about 1:
  // the bar for having learned anything of the hidden pixels.
  const double blind =
      long3r::completion_loss(at::zeros_like(target), target, visible).item<double>();
  double last = 0;
  for (int i = 0; i < 100; ++i) {
    opt.zero_grad();
    const at::Tensor loss = long3r::completion_loss(
        head(model.complete_view(batch.frames[1], batch.frames[0], visible)), target, visible);
    loss.backward();
    opt.step();
    last = loss.item<double>();
  }
  EXPECT_LT(last, 0.5 * blind) << "blind " << blind << " last " << last;
}

TEST(TrainTrainer, StageTwoFreezesTheEncoder) {
  long3r::TrainConfig c = tiny_config();
  c.stages[0].steps = 1;
  long3r::TrainOptions o;
  o.out_dir = scratch("freeze");
  o.quiet = true;
  long3r::Trainer tr(c, o);
  auto snapshot = [&]() {
    std::map<std::string, at::Tensor> m;
    for (const auto& kv : tr.model().module().named_parameters())
      m[kv.key()] = kv.value().detach().clone();
    return m;
  };
  const auto s0 = snapshot();
  tr.step();  // stage 1: everything trains
  const auto s1 = snapshot();
  EXPECT_FALSE(
      at::equal(s0.at("dust3r.patch_embed.proj.weight"), s1.at("dust3r.patch_embed.proj.weight")));
  tr.step();  // stage 2
  const auto s2 = snapshot();
  int frozen = 0, moved = 0;
  for (const auto& kv : tr.model().module().named_parameters()) {
    if (long3r::is_encoder_parameter(kv.key())) {
      EXPECT_FALSE(kv.value().requires_grad()) << kv.key();
      EXPECT_TRUE(at::equal(s1.at(kv.key()), s2.at(kv.key()))) << kv.key();
      ++frozen;
    } else if (!at::equal(s1.at(kv.key()), s2.at(kv.key()))) {
      ++moved;
    }
  }
  EXPECT_GT(frozen, 4);
  EXPECT_GT(moved, 20);
  EXPECT_TRUE(tr.model()
                  .module()
                  .named_parameters()
                  .find("dust3r.dec_blocks.0.attn.qkv.weight")
                  ->requires_grad());
}

TEST(TrainTrainer, ResumeReproducesTheNextStep) {
  long3r::TrainConfig c = tiny_config();
  c.stages[0].batch_size = 2;
  long3r::TrainOptions o;
  o.out_dir = scratch("resume");
  o.quiet = true;
  o.seed = 4;
  double expected = 0, expected_lr = 0;
  {
    long3r::Trainer a(c, o);
    a.step();
    a.step();
    a.save_checkpoint();
    const long3r::LogRow r = a.step();
    expected = r.loss;
    expected_lr = r.lr;
  }
  o.resume = true;
  long3r::Trainer b(c, o);
  EXPECT_EQ(b.global_step(), 2);
  ASSERT_EQ(b.log().size(), 2u);
  const long3r::LogRow r = b.step();
  EXPECT_EQ(r.step, 3);
  EXPECT_DOUBLE_EQ(r.lr, expected_lr);
  EXPECT_NEAR(r.loss, expected, 1e-6 * std::abs(expected));
  // A different seed gives different data: the check above can fail.
  long3r::TrainOptions other = o;
  other.resume = false;
  other.out_dir = scratch("resume_other");
  other.seed = 5;
  long3r::Trainer d(c, other);
  d.step();
  d.step();
  EXPECT_NE(d.step().loss, expected);
}

// The frame cache holds the renderer's bytes: every frame of every scene
// equals its render, a sampler reading it draws the same batches as one that
// renders, and a trainer given it trains the same steps.
TEST(TrainFrameCache, HoldsTheRenderersFramesAndTrainsTheSameSteps) {
  long3r::TrainConfig c = tiny_config();
  c.data.synth.train_scenes = 3;
  c.data.synth.trajectory_frames = 12;
  c.data.min_stride = 1;
  c.data.max_stride = 3;
  c.data.reverse_fraction = 0.5;
  const int size = c.data.synth.render_side(c.image_size);
  const std::string path = scratch("frame_cache") + "/frames.cache";
  std::vector<std::pair<int64_t, int64_t>> progress;
  long3r::FrameCache::write(path, c.data.synth, size, 2, [&](int64_t done, int64_t total) {
    progress.emplace_back(done, total);
  });
  EXPECT_EQ(progress.back(), std::make_pair(int64_t{3}, int64_t{3}));
  const auto cache = std::make_shared<const long3r::FrameCache>(path, c.data.synth, size, 3);
  EXPECT_EQ(cache->scenes(), 3);
  EXPECT_EQ(cache->frames_per_scene(), 12);
  EXPECT_FALSE(cache->covers(c.data.synth.train_seed_begin + 3));
  EXPECT_FALSE(cache->covers(c.data.synth.val_seed_begin));
  EXPECT_THROW(cache->frame(c.data.synth.train_seed_begin, 12), std::out_of_range);
  long3r::SequenceSampler rendering(c.data, static_cast<int>(c.image_size), 1, 1);
  for (int64_t s = 0; s < 3; ++s) {
    const uint64_t seed = c.data.synth.train_seed_begin + static_cast<uint64_t>(s);
    const std::vector<long3r::RawFrame> rendered = rendering.synth_frames(seed, 0, 1, 12);
    for (int64_t f = 0; f < 12; ++f) {
      const long3r::RawFrame a = cache->frame(seed, f);
      const long3r::RawFrame& b = rendered[static_cast<std::size_t>(f)];
      ASSERT_TRUE(at::equal(a.bgr, b.bgr)) << "scene " << seed << " frame " << f;
      ASSERT_TRUE(at::equal(a.depth, b.depth)) << "scene " << seed << " frame " << f;
      ASSERT_EQ(a.T_W_C.matrix(), b.T_W_C.matrix()) << "scene " << seed << " frame " << f;
      ASSERT_EQ(a.intrinsics.fx, b.intrinsics.fx);
      ASSERT_EQ(a.intrinsics.fy, b.intrinsics.fy);
      ASSERT_EQ(a.intrinsics.cx, b.intrinsics.cx);
      ASSERT_EQ(a.intrinsics.cy, b.intrinsics.cy);
      ASSERT_EQ(a.intrinsics.width, b.intrinsics.width);
    }
  }
  long3r::SequenceSampler cached(c.data, static_cast<int>(c.image_size), 9, 1);
  long3r::SequenceSampler plain(c.data, static_cast<int>(c.image_size), 9, 1);
  cached.set_frame_cache(cache);
  for (int i = 0; i < 3; ++i) {
    const long3r::Batch a = cached.sample_batch(2, 3), b = plain.sample_batch(2, 3);
    EXPECT_EQ(a.sources, b.sources);
    EXPECT_TRUE(at::equal(a.pts, b.pts));
    EXPECT_TRUE(at::equal(a.valid, b.valid));
    for (std::size_t k = 0; k < a.frames.size(); ++k)
      EXPECT_TRUE(at::equal(a.frames[k], b.frames[k]));
  }
  // Validation's held-out scenes are not in the cache and are rendered.
  EXPECT_TRUE(
      at::equal(cached.validation_sequence(0, 2, 3).pts, plain.validation_sequence(0, 2, 3).pts));

  long3r::TrainOptions o;
  o.quiet = true;
  o.seed = 4;
  o.out_dir = scratch("frame_cache_rendered");
  long3r::Trainer rendered_run(c, o);
  o.out_dir = scratch("frame_cache_cached");
  o.frame_cache = path;
  long3r::Trainer cached_run(c, o);
  for (int i = 0; i < 3; ++i) {
    const double want = rendered_run.step().loss;
    EXPECT_DOUBLE_EQ(cached_run.step().loss, want) << "step " << i + 1;
  }
}

// A cache that does not fit is refused, naming the file and what is wrong:
// made for other scenes, cut short, not a cache, or frames other than the
// generator's.
TEST(TrainFrameCache, RefusesACacheThatDoesNotFit) {
  long3r::TrainConfig c = tiny_config();
  c.data.synth.train_scenes = 2;
  c.data.synth.trajectory_frames = 5;
  const int size = c.data.synth.render_side(c.image_size);
  const std::string dir = scratch("frame_cache_refused");
  const std::string path = dir + "/frames.cache";
  long3r::FrameCache::write(path, c.data.synth, size, 1);
  const auto refused = [&](const std::string& file, const long3r::SynthDataConfig& synth,
                           const std::string& why) {
    try {
      long3r::FrameCache cache(file, synth, size, 2);
      ADD_FAILURE() << "accepted: " << why;
    } catch (const long3r::FrameCacheError& e) {
      const std::string m = e.what();
      EXPECT_NE(m.find(file), std::string::npos) << m;
      EXPECT_NE(m.find(why), std::string::npos) << m;
    }
  };
  long3r::SynthDataConfig other = c.data.synth;
  other.speed = 0.03;
  refused(path, other, "made for speed 0.02, the configuration has 0.03");
  // Its name says which scenes it holds: the same for the same frames (a
  // validation setting is no part of them), another for other frames.
  const std::string name = long3r::FrameCache::file_name(c.data.synth, size);
  EXPECT_EQ(name.rfind("synth_64px_1000-1001x5_", 0), 0u) << name;
  long3r::SynthDataConfig same = c.data.synth;
  same.val_scenes = 7;
  EXPECT_EQ(long3r::FrameCache::file_name(same, size), name);
  EXPECT_NE(long3r::FrameCache::file_name(other, size), name);
  EXPECT_NE(long3r::FrameCache::file_name(c.data.synth, size + 8), name);
  other = c.data.synth;
  other.train_scenes = 3;
  refused(path, other, "made for train_scenes 2");
  try {
    long3r::FrameCache cache(path, c.data.synth, size + 8, 0);
    ADD_FAILURE() << "accepted another render size";
  } catch (const long3r::FrameCacheError& e) {
    EXPECT_NE(std::string(e.what()).find("render_size"), std::string::npos) << e.what();
  }
  std::string bytes;
  {
    std::ifstream in(path, std::ios::binary);
    bytes.assign(std::istreambuf_iterator<char>(in), {});
  }
  const auto write = [&](const std::string& file, const std::string& content) {
    std::ofstream(file, std::ios::binary) << content;
    return file;
  };
  refused(write(dir + "/short.cache", bytes.substr(0, bytes.size() - 64)), c.data.synth,
          "cut short or grown");
  refused(write(dir + "/text.cache", "not a cache\n" + std::string(5000, 'x')), c.data.synth,
          "not a frame cache");
  refused(dir + "/missing.cache", c.data.synth, "cannot open");
  // One pixel of the last scene's last frame changed: the check renders
  // the first and the last frame of the cache.
  std::string tampered = bytes;
  tampered[tampered.size() - 100] ^= 0x01;
  refused(write(dir + "/tampered.cache", tampered), c.data.synth,
          "frame 4 of scene " + std::to_string(c.data.synth.train_seed_begin + 1) + " differs");
  EXPECT_NO_THROW(long3r::FrameCache(path, c.data.synth, size, 2));
}

// train_log.csv is appended to at each checkpoint; a resume takes the log
// up to its checkpoint from the file and cuts off the rows logged after it.
TEST(TrainTrainer, LogIsAppendedAndCutBackToTheCheckpointOnResume) {
  long3r::TrainConfig c = tiny_config();
  long3r::TrainOptions o;
  o.out_dir = scratch("log_append");
  o.quiet = true;
  o.seed = 4;
  const std::string csv = o.out_dir + "/train_log.csv";
  const auto steps_in_file = [&csv] {
    std::ifstream in(csv);
    std::stringstream ss;
    ss << in.rdbuf();
    std::vector<int64_t> steps;
    for (const long3r::LogRow& r : long3r::log_rows_from_csv(ss.str())) steps.push_back(r.step);
    return steps;
  };
  {
    long3r::Trainer a(c, o);
    a.step();
    a.step();
    a.save_checkpoint();
    EXPECT_EQ(steps_in_file(), (std::vector<int64_t>{1, 2}));
    a.step();
    a.save_checkpoint();
    a.step();
    a.write_outputs();
    EXPECT_EQ(steps_in_file(), (std::vector<int64_t>{1, 2, 3, 4}));
  }
  // Back to the checkpoint of step 2 (as if the later ones were lost).
  const std::string ckpt = o.out_dir + "/checkpoint";
  fs::remove(ckpt + "/step_00000003.pt");
  std::ofstream(ckpt + "/latest") << "step_00000002.pt\n";
  o.resume = true;
  {
    long3r::Trainer b(c, o);
    ASSERT_EQ(b.log().size(), 2u);
    b.step();
    b.save_checkpoint();
    EXPECT_EQ(steps_in_file(), (std::vector<int64_t>{1, 2, 3}));
  }
  // A log that lacks the checkpoint's rows is refused, not silently restarted.
  fs::remove(csv);
  try {
    long3r::Trainer d(c, o);
    ADD_FAILURE() << "resumed without its log";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("train_log.csv"), std::string::npos) << e.what();
  }
}

// The data thread draws the same batches in the same order (across the stage
// change, whose sequences are longer), and a checkpoint taken while batches
// wait ahead resumes exactly, with or without a data thread.
TEST(TrainTrainer, PrefetchTrainsOnTheSameBatchesAndResumesExactly) {
  long3r::TrainConfig c = tiny_config();
  long3r::TrainOptions o;
  o.quiet = true;
  o.seed = 4;
  o.out_dir = scratch("prefetch_reference");
  std::vector<double> expected;
  {
    long3r::Trainer a(c, o);
    for (int i = 0; i < 5; ++i) expected.push_back(a.step().loss);
  }
  o.out_dir = scratch("prefetch");
  o.prefetch_batches = 2;
  {
    long3r::Trainer b(c, o);
    for (int i = 0; i < 3; ++i) {
      EXPECT_NEAR(b.step().loss, expected[i], 1e-6 * std::abs(expected[i])) << "step " << i + 1;
    }
    b.save_checkpoint();  // two batches are waiting ahead now
  }                       // the data thread stops with its trainer
  for (int prefetch : {0, 3}) {
    long3r::TrainOptions r = o;
    r.resume = true;
    r.prefetch_batches = prefetch;
    long3r::Trainer t(c, r);
    ASSERT_EQ(t.global_step(), 3);
    const long3r::LogRow row = t.step();
    EXPECT_EQ(row.stage, 2);
    EXPECT_NEAR(row.loss, expected[3], 1e-6 * std::abs(expected[3])) << "prefetch " << prefetch;
    EXPECT_NEAR(t.step().loss, expected[4], 1e-6 * std::abs(expected[4]))
        << "prefetch " << prefetch;
  }
}

// A cross_view_completion stage before the sequence stage: its rows log the
// completion loss (no pointmap terms), a resume reproduces both kinds of
// step (the pixel head is in the checkpoint), and the exported model is the
// LONG3R model alone (loaded strictly, no pixel head).
TEST(TrainTrainer, CrossViewCompletionStageResumesAndIsNotExported) {
  long3r::TrainConfig c = tiny_config();
  c.stages[0].task = long3r::kTaskCrossViewCompletion;
  c.stages[0].frames = 2;
  c.stages[0].batch_size = 2;
  c.stages[1].steps = 2;
  long3r::TrainOptions o;
  o.out_dir = scratch("completion");
  o.quiet = true;
  o.seed = 4;
  std::vector<double> expected;
  {
    long3r::Trainer a(c, o);
    for (int i = 0; i < 2; ++i) {
      const long3r::LogRow r = a.step();
      EXPECT_EQ(r.stage, 1);
      EXPECT_TRUE(std::isfinite(r.loss) && r.loss > 0.0) << r.loss;
      EXPECT_TRUE(std::isnan(r.regression));
      EXPECT_GT(r.grad_norm, 0.0);
    }
    a.save_checkpoint();
    for (int i = 0; i < 2; ++i) expected.push_back(a.step().loss);
    EXPECT_EQ(a.log().back().stage, 2);
    EXPECT_TRUE(std::isfinite(a.log().back().regression));
    a.write_outputs();
  }
  EXPECT_NO_THROW(long3r::Long3rModel::from_file(o.out_dir + "/model.safetensors"));
  long3r::Long3rModel fresh(long3r::test::tiny_long3r_config());
  fresh.save(o.out_dir + "/fresh.safetensors");
  const long3r::TensorFile file = long3r::load_safetensors(o.out_dir + "/model.safetensors");
  const long3r::TensorFile reference = long3r::load_safetensors(o.out_dir + "/fresh.safetensors");
  std::vector<std::string> names, reference_names;
  for (const auto& kv : file.tensors) names.push_back(kv.first);
  for (const auto& kv : reference.tensors) reference_names.push_back(kv.first);
  EXPECT_EQ(names, reference_names);

  o.resume = true;
  long3r::Trainer b(c, o);
  ASSERT_EQ(b.global_step(), 2);
  EXPECT_NEAR(b.step().loss, expected[0], 1e-6 * std::abs(expected[0]));
  EXPECT_NEAR(b.step().loss, expected[1], 1e-6 * std::abs(expected[1]));

  // A configuration with the stage cannot resume a checkpoint without its
  // head: it says so.
  long3r::TrainOptions plain = o;
  plain.resume = false;
  plain.out_dir = scratch("completion_plain");
  {
    long3r::Trainer p(tiny_config(), plain);
    p.step();
    p.save_checkpoint();
  }
  plain.resume = true;
  try {
    long3r::Trainer t(c, plain);
    ADD_FAILURE() << "resumed without the completion head";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("cross-view completion head"), std::string::npos)
        << e.what();
  }
}

// A time budget ends the run early, as its end would: validated, with the
// outputs written and the reason recorded; without the OpenCV side the
// validation has the loss and pointmap figures and no picture is drawn.
TEST(TrainTrainer, TimeBudgetEndsTheRunWithItsOutputs) {
  const long3r::TrainConfig c = tiny_config_validated_at_end();
  long3r::TrainOptions o;
  o.quiet = true;
  o.out_dir = scratch("budget");
  o.time_budget_s = 1e-3;  // spent by the first step
  o.prefetch_batches = 1;
  long3r::Trainer t(c, o);
  t.run();
  EXPECT_EQ(t.stop_reason(), "time_budget");
  EXPECT_EQ(t.global_step(), 1);
  const std::filesystem::path out(o.out_dir);
  EXPECT_TRUE(std::filesystem::exists(out / "model.safetensors"));
  EXPECT_TRUE(std::filesystem::exists(out / "checkpoint" / "step_00000001.pt"));
  EXPECT_FALSE(std::filesystem::exists(out / "loss_curve.png"));
  std::ifstream in(out / "validation.json");
  std::stringstream text;
  text << in.rdbuf();
  const std::string j = text.str();
  // A field of the file: its value's text (the file is indented JSON, one field a line).
  auto field = [&j](const std::string& key) {
    const std::size_t at = j.find("\"" + key + "\": ");
    if (at == std::string::npos) return std::string("absent");
    const std::size_t begin = at + key.size() + 4;
    return j.substr(begin, j.find_first_of(",\n", begin) - begin);
  };
  EXPECT_EQ(field("step"), "1");
  EXPECT_EQ(field("steps_planned"), "6");
  EXPECT_EQ(field("stop_reason"), "\"time_budget\"");
  const double pointmap_err = std::stod(field("pointmap_err_m"));
  EXPECT_GT(pointmap_err, 0.0);
  EXPECT_GT(std::stod(field("regression")), std::stod(field("registered")));
  EXPECT_EQ(field("acc_mean_m"), "null");  // not computed without the OpenCV side
  EXPECT_EQ(field("ate_rmse_m"), "null");

  // With it: the paper's figures and the picture.
  o.out_dir = scratch("budget_cv");
  o.extensions = long3r::opencv_trainer_extensions();
  long3r::Trainer full(c, o);
  full.run();
  EXPECT_TRUE(std::filesystem::exists(std::filesystem::path(o.out_dir) / "loss_curve.png"));
  ASSERT_TRUE(full.log().back().val.has_value());
  EXPECT_TRUE(std::isfinite(full.log().back().val->prediction.acc_mean));
  EXPECT_NEAR(full.log().back().val->prediction.pointmap_error, pointmap_err, 0.5 * pointmap_err);
}

// A stop request (long3r_train: SIGINT, SIGTERM) ends the run before the
// next step with the last step's checkpoint and outputs, without the
// end-of-run validation; the run resumes there.
TEST(TrainTrainer, AStopRequestEndsTheRunAtTheLastStepsCheckpoint) {
  const long3r::TrainConfig c = tiny_config_validated_at_end();
  long3r::TrainOptions o;
  o.quiet = true;
  o.out_dir = scratch("stop_request");
  int asked = 0;
  o.stop_requested = [&asked] { return ++asked > 2; };  // after two steps
  {
    long3r::Trainer t(c, o);
    t.run();
    EXPECT_EQ(t.stop_reason(), "stop_request");
    EXPECT_EQ(t.global_step(), 2);
    ASSERT_EQ(t.log().size(), 2u);
    EXPECT_FALSE(t.log().back().val.has_value());  // not validated: stopping is quick
  }
  EXPECT_EQ(asked, 3);
  const std::filesystem::path out(o.out_dir);
  EXPECT_TRUE(std::filesystem::exists(out / "model.safetensors"));
  std::ifstream latest(out / "checkpoint" / "latest");
  std::string name;
  latest >> name;
  EXPECT_EQ(name, "step_00000002.pt");
  o.resume = true;
  o.stop_requested = nullptr;
  long3r::Trainer resumed(c, o);
  EXPECT_EQ(resumed.global_step(), 2);
  resumed.run();
  EXPECT_EQ(resumed.stop_reason(), "schedule");
  EXPECT_EQ(resumed.global_step(), c.total_steps());
}

// Without the OpenCV side there is no TUM reader: such a config is refused by name.
TEST(TrainTrainer, TumFoldersNeedTheOpenCvSide) {
  long3r::TrainConfig c = tiny_config();
  c.data.tum_dirs = {"/nonexistent"};
  long3r::TrainOptions o;
  o.quiet = true;
  o.out_dir = scratch("tum_refused");
  try {
    long3r::Trainer t(c, o);
    FAIL() << "accepted data.tum_dirs without a reader";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("data.tum_dirs"), std::string::npos) << e.what();
  }
  o.extensions = long3r::opencv_trainer_extensions();
  try {
    long3r::Trainer t(c, o);
    FAIL() << "opened a folder that does not exist";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent"), std::string::npos) << e.what();
  }
}

// Mixed precision (amp "bf16": the forward pass under bfloat16 autocast)
// against float32, same seed, one fixed sequence (one scene, no augmentation)
// so that the loss can fall over a few steps: every loss finite, the same fall
// within a margin, and the master weights float32 throughout. On a CPU
// without native bfloat16 it runs emulated, so it must be asked for.
TEST(TrainTrainer, Bfloat16MixedPrecisionTrainsLikeFloat32) {
  long3r::TrainConfig c = tiny_config();
  c.stages.resize(1);
  c.stages[0].steps = 6;
  c.stages[0].warmup_steps = 0;
  c.stages[0].min_lr_ratio = 1.0;
  c.data.synth.train_scenes = 1;
  c.data.synth.trajectory_frames = c.stages[0].frames;
  c.data.synth.hfov_max_deg = c.data.synth.hfov_min_deg;
  c.data.augment.color_jitter = 0.0;
  c.data.augment.max_crop = 0.0;
  long3r::TrainOptions o;
  o.quiet = true;
  o.seed = 2;
  auto run = [&](const std::string& amp, const std::string& dir) {
    long3r::TrainConfig cc = c;
    cc.amp = amp;
    cc.allow_emulated_precision = true;
    long3r::TrainOptions oo = o;
    oo.out_dir = scratch(dir);
    long3r::Trainer t(cc, oo);
    std::vector<double> losses;
    for (int i = 0; i < 6; ++i) losses.push_back(t.step().loss);
    for (const auto& p : t.model().module().named_parameters()) {
      EXPECT_EQ(p.value().scalar_type(), at::kFloat) << amp << " " << p.key();
    }
    return losses;
  };
  const std::vector<double> f32 = run("off", "amp_off"), bf16 = run("bf16", "amp_bf16");
  for (std::size_t i = 0; i < f32.size(); ++i) {
    std::printf("step %zu: loss float32 %.5f, bfloat16 autocast %.5f\n", i + 1, f32[i], bf16[i]);
    EXPECT_TRUE(std::isfinite(bf16[i])) << "step " << i + 1;
  }
  const double fall_f32 = 1.0 - f32.back() / f32.front();
  const double fall_bf16 = 1.0 - bf16.back() / bf16.front();
  EXPECT_GT(fall_f32, 0.05);  // the check below means something
  EXPECT_GT(fall_bf16, 0.5 * fall_f32) << "float32 fell " << fall_f32 << ", bf16 " << fall_bf16;
  EXPECT_LT(fall_bf16, 1.5 * fall_f32) << "float32 fell " << fall_f32 << ", bf16 " << fall_bf16;
  EXPECT_NEAR(bf16.front(), f32.front(), 0.05 * f32.front());  // same weights, same data

  // Without the permission, a CPU that only emulates bfloat16 refuses it.
  if (!long3r::cpu_has_native_bfloat16()) {
    long3r::TrainConfig cc = c;
    cc.amp = "bf16";
    long3r::TrainOptions oo = o;
    oo.out_dir = scratch("amp_refused");
    try {
      long3r::Trainer t(cc, oo);
      ADD_FAILURE() << "amp bf16 on an emulating CPU was accepted";
    } catch (const long3r::ConfigError& e) {
      EXPECT_NE(std::string(e.what()).find("allow_emulated_precision"), std::string::npos)
          << e.what();
    }
  }
}

TEST(TrainLog, CsvColumnsAreReadBackByName) {
  std::vector<long3r::LogRow> rows(2);
  rows[0].step = 1;
  rows[0].stage = 1;
  rows[0].loss = 0.5;
  rows[0].grad_norm = 2.25;
  rows[1].step = 2;
  rows[1].stage = 2;
  rows[1].lr = 1e-4;
  rows[1].wall_s = 3.5;
  long3r::ValidationMetrics v;
  v.loss = 0.25;
  v.prediction.acc_mean = 0.125;
  v.prediction.ate_rmse = std::numeric_limits<double>::quiet_NaN();
  rows[1].val = v;
  const std::string csv = long3r::log_rows_to_csv(rows);
  // The header train_log.csv has always had, then the columns added since.
  EXPECT_EQ(csv.substr(0, csv.find('\n')),
            "step,stage,loss,conf_loss,scale_loss,regression,lr,grad_norm,step_s,data_s,wall_s,"
            "val_loss,val_regression,val_pointmap_err_m,val_acc_mean_m,val_acc_median_m,"
            "val_comp_mean_m,val_comp_median_m,val_nc_mean,val_nc_median,val_ate_rmse_m,"
            "val_registered,val_blind_ratio,val_reg_true,val_reg_blind,val_rot_err_deg,"
            "val_rot_true_deg,val_completion_true,val_completion_shuffled,val_shape_err,"
            "val_depth_slope");
  auto expect_rows = [&](const std::vector<long3r::LogRow>& got) {
    ASSERT_EQ(got.size(), 2u);
    EXPECT_EQ(got[0].step, 1);
    EXPECT_EQ(got[0].loss, 0.5);
    EXPECT_EQ(got[0].grad_norm, 2.25);
    EXPECT_FALSE(got[0].val.has_value());
    EXPECT_EQ(got[1].stage, 2);
    EXPECT_EQ(got[1].lr, 1e-4);
    EXPECT_EQ(got[1].wall_s, 3.5);
    ASSERT_TRUE(got[1].val.has_value());
    EXPECT_EQ(got[1].val->loss, 0.25);
    EXPECT_EQ(got[1].val->prediction.acc_mean, 0.125);
    EXPECT_TRUE(std::isnan(got[1].val->prediction.ate_rmse));
  };
  expect_rows(long3r::log_rows_from_csv(csv));

  // The same table with its columns in reverse order, and a last line cut short.
  std::istringstream in(csv);
  std::string line, reversed;
  while (std::getline(in, line)) {
    std::vector<std::string> cells;
    std::stringstream ss(line);
    std::string cell;
    while (std::getline(ss, cell, ',')) cells.insert(cells.begin(), cell);
    for (std::size_t i = 0; i < cells.size(); ++i) reversed += (i ? "," : "") + cells[i];
    reversed += "\n";
  }
  expect_rows(long3r::log_rows_from_csv(reversed + "nan,nan,3\n"));

  std::string renamed = csv;
  renamed.replace(renamed.find("grad_norm"), 9, "gradnorm");
  EXPECT_THROW(long3r::log_rows_from_csv(renamed), std::runtime_error);

  // A log written before val_registered and the blind control's columns
  // existed (a resumed older checkpoint): its first 21 columns.
  rows[1].val->registered = 0.75;
  rows[1].val->blind.blind_ratio = 0.5;
  rows[1].val->completion.loss_shuffled = 1.25;
  rows[1].val->blind.shape_err = 0.375;
  std::string older;
  std::istringstream lines(long3r::log_rows_to_csv(rows));
  while (std::getline(lines, line)) {
    std::size_t cut = 0;
    for (int k = 0; k < 21; ++k) cut = line.find(',', cut) + 1;
    older += line.substr(0, cut - 1) + "\n";
  }
  const std::vector<long3r::LogRow> read = long3r::log_rows_from_csv(older);
  expect_rows(read);
  EXPECT_TRUE(std::isnan(read[1].val->registered));
  EXPECT_TRUE(std::isnan(read[1].val->blind.blind_ratio));
  EXPECT_TRUE(std::isnan(read[1].val->completion.loss_shuffled));
  EXPECT_TRUE(std::isnan(read[1].val->blind.shape_err));
  const std::vector<long3r::LogRow> now = long3r::log_rows_from_csv(long3r::log_rows_to_csv(rows));
  EXPECT_EQ(now[1].val->registered, 0.75);
  EXPECT_EQ(now[1].val->blind.blind_ratio, 0.5);
  EXPECT_EQ(now[1].val->completion.loss_shuffled, 1.25);
  EXPECT_EQ(now[1].val->blind.shape_err, 0.375);
}

TEST(TrainInit, CopiesMatchingTensorsByNameAndShape) {
  at::manual_seed(7);
  long3r::Long3rModel src(long3r::test::tiny_long3r_config());
  // A DUSt3R-style file: encoder / decoder names without the "dust3r." prefix,
  // one tensor with a wrong shape and one the model does not have.
  long3r::TensorMap t;
  for (const auto& kv : src.module().named_parameters()) {
    if (kv.key().rfind("dust3r.", 0) == 0) t[kv.key().substr(7)] = kv.value().detach().clone();
  }
  t["patch_embed.proj.weight"] = at::ones({5});
  t["not_a_module.weight"] = at::ones({2});
  const std::string path = scratch("init") + "/dust3r.safetensors";
  long3r::save_safetensors(path, t);
  at::manual_seed(8);
  long3r::Long3rModel dst(long3r::test::tiny_long3r_config());
  const long3r::InitReport r = long3r::init_from_checkpoint(dst, path);
  EXPECT_EQ(r.shape_mismatch, 1);
  EXPECT_EQ(r.unused, 1);
  EXPECT_EQ(r.loaded, static_cast<int64_t>(t.size()) - 2);
  EXPECT_GT(r.fresh, 1);  // value encoder, attention heads, patch_embed.proj.weight
  const auto sp = src.module().named_parameters();
  const auto dp = dst.module().named_parameters();
  EXPECT_TRUE(at::equal(*sp.find("dust3r.enc_blocks.0.attn.qkv.weight"),
                        *dp.find("dust3r.enc_blocks.0.attn.qkv.weight")));
  // The mis-shaped tensor keeps dst's own (randomly initialised) values.
  EXPECT_FALSE(at::equal(*sp.find("dust3r.patch_embed.proj.weight"),
                         *dp.find("dust3r.patch_embed.proj.weight")));
  EXPECT_FALSE(at::equal(*sp.find("attn_head_1.0.weight"), *dp.find("attn_head_1.0.weight")));
}

TEST(TrainConfig, ParsesAndRejectsBadFields) {
  const std::string ok = R"({"model": "long3r_tiny", "image_size": 64,
    "stages": [{"name": "a", "steps": 2, "frames": 5, "lr": 1e-4}],
    "data": {"synth": {"train_scenes": 10, "val_scenes": 2}}})";
  const long3r::TrainConfig c = long3r::parse_train_config(ok);
  EXPECT_EQ(c.stages.size(), 1u);
  EXPECT_EQ(c.stages[0].frames, 5);
  EXPECT_DOUBLE_EQ(c.loss.alpha, 0.2);
  // Round trip.
  const long3r::TrainConfig c2 = long3r::parse_train_config(long3r::train_config_to_json(c));
  EXPECT_EQ(long3r::train_config_to_json(c2), long3r::train_config_to_json(c));
  EXPECT_THROW(long3r::parse_train_config(R"({"stages": [{"steps": 1, "lr": 1e-4, "frams": 3}]})"),
               std::invalid_argument);
  // Validation scenes inside the training range.
  EXPECT_THROW(long3r::parse_train_config(R"({"stages": [{"steps": 1}],
    "data": {"synth": {"train_seed_begin": 0, "train_scenes": 100, "val_seed_begin": 50}}})"),
               std::invalid_argument);
  EXPECT_THROW(long3r::parse_train_config(R"({"image_size": 70, "stages": [{"steps": 1}]})"),
               std::invalid_argument);
  // Stage tasks: a known name; completion takes pairs and hides some but
  // not all patches.
  EXPECT_EQ(c.stages[0].task, "sequence");
  const long3r::TrainConfig cc = long3r::parse_train_config(
      R"({"stages": [{"steps": 1, "frames": 2, "task": "cross_view_completion"}]})");
  EXPECT_DOUBLE_EQ(cc.stages[0].mask_ratio, 0.9);
  EXPECT_THROW(long3r::parse_train_config(R"({"stages": [{"steps": 1, "task": "croco"}]})"),
               std::invalid_argument);
  EXPECT_THROW(long3r::parse_train_config(
                   R"({"stages": [{"steps": 1, "frames": 3, "task": "cross_view_completion"}]})"),
               std::invalid_argument);
  EXPECT_THROW(long3r::parse_train_config(R"({"stages": [{"steps": 1, "frames": 2,
    "task": "cross_view_completion", "mask_ratio": 1.0}]})"),
               std::invalid_argument);
}

TEST(TrainConfig, ShippedDefaultParses) {
  const fs::path p = fs::path(LONG3R_SOURCE_DIR) / "config" / "train_default.json";
  std::ifstream in(p);
  std::stringstream ss;
  ss << in.rdbuf();
  const long3r::TrainConfig c = long3r::parse_train_config(ss.str());
  ASSERT_EQ(c.stages.size(), 3u);
  EXPECT_EQ(c.stages[0].frames, 5);
  EXPECT_FALSE(c.stages[0].freeze_encoder);
  EXPECT_EQ(c.stages[1].frames, 10);
  EXPECT_TRUE(c.stages[1].freeze_encoder);
  EXPECT_EQ(c.stages[2].frames, 32);
  EXPECT_TRUE(c.stages[2].freeze_encoder);
  EXPECT_NO_THROW(long3r::resolve_model_config(c.model));
}

TEST(TrainConfig, EveryCheckedInTrainingConfigParses) {
  // The shipped recipe's stages and the documented experiments: a field
  // misspelt in any of them would only show when someone runs it.
  int seen = 0;
  for (const auto& e : fs::directory_iterator(fs::path(LONG3R_SOURCE_DIR) / "config")) {
    const std::string name = e.path().filename().string();
    if (name.rfind("train_", 0) != 0 || e.path().extension() != ".json") continue;
    SCOPED_TRACE(name);
    std::ifstream in(e.path());
    std::stringstream ss;
    ss << in.rdbuf();
    long3r::TrainConfig c;
    ASSERT_NO_THROW(c = long3r::parse_train_config(ss.str()));
    EXPECT_FALSE(c.stages.empty());
    EXPECT_NO_THROW(long3r::resolve_model_config(
        long3r::locate_model_config(c.model, e.path().parent_path().string())));
    ++seen;
  }
  EXPECT_GE(seen, 4);  // default, ship stage 1 and 2, the long-travel experiment
}

// ----------------------------------------------------- held-out evaluation

namespace {

long3r::SequenceSample held_out_sequence(int64_t frames) {
  long3r::DataConfig dc;
  dc.synth.val_seed_begin = 2000000;
  dc.synth.trajectory_frames = 3 * frames;
  long3r::SequenceSampler sampler(dc, 96, 0, 1);
  return sampler.validation_sequence(0, frames, 3);
}

}  // namespace

TEST(ModelEval, GroundTruthPredictionScoresZero) {
  const long3r::SequenceSample s = held_out_sequence(6);
  long3r::SequencePrediction p;
  for (int64_t i = 0; i < 6; ++i) {
    // Any Sim(3) of the GT is a perfect prediction after alignment.
    p.pts.push_back((s.pts[i] * 2.5f + 1.0f).contiguous());
    p.conf.push_back(at::full({96, 96}, 5.0f));
  }
  long3r::PredictionMetricsOptions o;
  o.pixel_step = 3;
  const long3r::PredictionMetrics m = long3r::evaluate_prediction(p, s, o);
  EXPECT_EQ(m.frames, 6);
  EXPECT_EQ(m.posed, 6);
  EXPECT_LT(m.pointmap_error, 1e-4);
  EXPECT_LT(m.acc_mean, 1e-4);
  EXPECT_LT(m.comp_mean, 1e-4);
  EXPECT_GT(m.nc_mean, 0.99);
  EXPECT_LT(m.ate_rmse, 1e-3);
  EXPECT_LT(m.rpe_trans_rmse, 1e-3);
  EXPECT_NEAR(m.depth_slope, 1.0, 1e-4);
  EXPECT_NEAR(m.depth_correlation, 1.0, 1e-4);
}

// Each frame's points in its own true camera, changed there by `change`
// (x, y, z -> new point), then back in camera 0's frame.
long3r::SequencePrediction changed_in_camera(
    const long3r::SequenceSample& s, const std::function<cv::Vec3f(const cv::Vec3f&)>& change) {
  long3r::SequencePrediction p;
  for (int64_t i = 0; i < s.pts.size(0); ++i) {
    const Eigen::Isometry3d& T_C0_C = s.T_C0_C[static_cast<std::size_t>(i)];
    const at::Tensor gt = s.pts[i].contiguous();
    cv::Mat points_C =
        long3r::points_in_camera(cv::Mat(96, 96, CV_32FC3, gt.data_ptr<float>()), T_C0_C);
    for (auto it = points_C.begin<cv::Vec3f>(); it != points_C.end<cv::Vec3f>(); ++it) {
      *it = change(*it);  // in order: `change` may draw random numbers
    }
    const cv::Mat points_W = long3r::transform_points(points_C, T_C0_C);
    p.pts.push_back(
        at::from_blob(const_cast<float*>(points_W.ptr<float>()), {96, 96, 3}, at::kFloat).clone());
    p.conf.push_back(at::full({96, 96}, 5.0f));
  }
  return p;
}

TEST(ModelEval, DepthResponseTellsCompressedDepthFromNoisyDepth) {
  const long3r::SequenceSample s = held_out_sequence(6);
  long3r::PredictionMetricsOptions o;
  o.pixel_step = 3;
  o.normals = false;
  // Depth compressed towards 2 m along each pixel's ray (z' = 2 (z / 2)^0.5),
  // as a model that regresses to its mean depth: a slope near 0.5 that the
  // frame's Sim(3) cannot undo, and depth ordered as the truth is.
  const long3r::SequencePrediction compressed = changed_in_camera(s, [](const cv::Vec3f& X) {
    return X[2] > 0.0f ? X * static_cast<float>(std::sqrt(2.0 / X[2])) : X;
  });
  const long3r::PredictionMetrics c = long3r::evaluate_prediction(compressed, s, o);
  EXPECT_GT(c.depth_slope, 0.35);
  EXPECT_LT(c.depth_slope, 0.65);
  EXPECT_GT(c.depth_correlation, 0.95);
  // Each pixel's depth off by a random factor (log-normal, sigma 0.2): the
  // ratios unbiased (a slope near 1), the correlation lower.
  std::mt19937 rng(5);
  std::normal_distribution<float> noise(0.0f, 0.2f);
  const long3r::SequencePrediction noisy =
      changed_in_camera(s, [&](const cv::Vec3f& X) { return X * std::exp(noise(rng)); });
  const long3r::PredictionMetrics n = long3r::evaluate_prediction(noisy, s, o);
  EXPECT_GT(n.depth_slope, 0.8);
  EXPECT_LT(n.depth_slope, 1.2);
  EXPECT_LT(n.depth_correlation, 0.9);
  // A frame without usable pixels has no response and leaves the median to
  // the others.
  long3r::SequencePrediction blind = compressed;
  blind.pts[0] = at::full({96, 96, 3}, std::nanf(""));
  EXPECT_FALSE(long3r::depth_response(blind.pts[0], s.pts[0], s.valid[0], s.T_C0_C[0], 3));
  const double rest = long3r::evaluate_prediction(blind, s, o).depth_slope;
  EXPECT_GT(rest, 0.35);
  EXPECT_LT(rest, 0.65);
  const std::optional<long3r::DepthResponse> one =
      long3r::depth_response(compressed.pts[2], s.pts[2], s.valid[2], s.T_C0_C[2], 3);
  ASSERT_TRUE(one);
  EXPECT_GT(one->pixels, 500);
}

TEST(ModelEval, EstimatedIntrinsicsFollowThePredictedFieldOfView) {
  // The pipeline without a calibration takes the focal from frame 0's
  // pointmap. A prediction that is exact up to a wider field of view (x and y
  // squeezed by 0.8 in every camera's own frame, the true poses) is then
  // posed exactly; the GT focal misplaces its cameras.
  const long3r::SequenceSample s = held_out_sequence(6);
  long3r::SequencePrediction p;
  for (int64_t i = 0; i < 6; ++i) {
    const Eigen::Isometry3d& T_C0_C = s.T_C0_C[static_cast<std::size_t>(i)];
    const at::Tensor gt = s.pts[i].contiguous();
    const cv::Mat points_C =
        long3r::points_in_camera(cv::Mat(96, 96, CV_32FC3, gt.data_ptr<float>()), T_C0_C);
    cv::Mat squeezed;
    cv::multiply(points_C, cv::Scalar(0.8, 0.8, 1.0), squeezed);
    const cv::Mat points_W = long3r::transform_points(squeezed, T_C0_C);
    p.pts.push_back(
        at::from_blob(const_cast<float*>(points_W.ptr<float>()), {96, 96, 3}, at::kFloat).clone());
    p.conf.push_back(at::full({96, 96}, 5.0f));
  }
  long3r::PredictionMetricsOptions o;
  o.pixel_step = 3;
  o.normals = false;
  o.estimate_intrinsics = true;
  // No usable pixel in frame 0: no focal, so no poses (not the GT focal).
  long3r::SequencePrediction blind = p;
  blind.pts[0] = at::full({96, 96, 3}, std::nanf(""));
  EXPECT_EQ(long3r::evaluate_prediction(blind, s, o).posed, 0);
  const long3r::PredictionMetrics est = long3r::evaluate_prediction(p, s, o);
  EXPECT_EQ(est.posed, 6);
  EXPECT_LT(est.ate_rmse, 2e-3);
  EXPECT_LT(est.rpe_rot_rmse_deg, 0.1);
  o.estimate_intrinsics = false;
  const long3r::PredictionMetrics gt = long3r::evaluate_prediction(p, s, o);
  ASSERT_EQ(gt.posed, 6);
  EXPECT_GT(gt.ate_rmse, 10.0 * std::max(est.ate_rmse, 1e-4));
}

TEST(ModelEval, ConstantDepthBaselineHasNoMotionAndTheGtSpreadAsAte) {
  const long3r::SequenceSample s = held_out_sequence(6);
  const long3r::SequencePrediction p = long3r::constant_depth_prediction(s, 2.0);
  ASSERT_EQ(p.pts.size(), 6u);
  // Pixel centre (cx, cy) at depth 2 lies on the optical axis.
  const long3r::PinholeIntrinsics& k = s.intrinsics[0];
  const at::Tensor c =
      p.pts[0][static_cast<int64_t>(std::lround(k.cy))][static_cast<int64_t>(std::lround(k.cx))];
  EXPECT_NEAR(c[2].item<float>(), 2.0f, 1e-6);
  EXPECT_NEAR(c[0].item<float>(), 0.0f, 0.02f);
  long3r::PredictionMetricsOptions o;
  o.pixel_step = 3;
  o.normals = false;
  const long3r::PredictionMetrics m = long3r::evaluate_prediction(p, s, o);
  EXPECT_EQ(m.posed, 6);
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const auto& T : s.T_C0_C) mean += T.translation();
  mean /= 6.0;
  double sq = 0;
  for (const auto& T : s.T_C0_C) sq += (T.translation() - mean).squaredNorm();
  EXPECT_NEAR(m.ate_rmse, std::sqrt(sq / 6.0), 1e-3);
  EXPECT_GT(m.ate_rmse, 0.01);  // the camera does move
  EXPECT_GT(m.acc_mean, 0.05);
  // Wrong lengths are refused.
  long3r::SequencePrediction short_p = p;
  short_p.pts.pop_back();
  short_p.conf.pop_back();
  EXPECT_THROW(long3r::evaluate_prediction(short_p, s, o), std::invalid_argument);
}

TEST(ModelEval, LossProbeSplitsRegistrationFromShape) {
  const long3r::SequenceSample s = held_out_sequence(6);
  // The GT itself, at any scale: no loss at all (the loss normalises scale).
  long3r::SequencePrediction exact;
  for (int64_t i = 0; i < 6; ++i) {
    exact.pts.push_back((s.pts[i] * 3.0f).contiguous());
    exact.conf.push_back(at::ones({96, 96}));
  }
  const long3r::LossProbe e = long3r::probe_loss(exact, s);
  EXPECT_LT(e.regression, 1e-5);
  EXPECT_LT(e.registered, 1e-5);

  // Perfect depth in each frame's own camera, no motion: frame 0 is exact,
  // the other frames cost what their registration is worth, and a per-frame
  // similarity fit removes all of it.
  const long3r::SequencePrediction still = long3r::true_depth_no_motion_prediction(s);
  ASSERT_EQ(still.pts.size(), 6u);
  EXPECT_LT((still.pts[0] - s.pts[0]).abs().max().item<float>(), 1e-5f);
  // A point of frame 5 is the GT point seen from camera 5.
  const Eigen::Isometry3d T_C5_C0 = s.T_C0_C[5].inverse();
  const at::Tensor g = s.pts[5][40][50];
  const Eigen::Vector3d x_C0(g[0].item<float>(), g[1].item<float>(), g[2].item<float>());
  const Eigen::Vector3d x_C5 = T_C5_C0 * x_C0;
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(still.pts[5][40][50][c].item<float>(), x_C5[c], 1e-4);
  const long3r::LossProbe n = long3r::probe_loss(still, s);
  EXPECT_GT(n.regression, 1e-3);
  EXPECT_LT(n.registered, 1e-4);

  // Frame 0's geometry for every frame is wrong in shape as well as place.
  const long3r::LossProbe f = long3r::probe_loss(long3r::first_frame_prediction(s), s);
  EXPECT_GT(f.regression, n.regression);
  EXPECT_GT(f.registered, 1e-3);
  EXPECT_LE(f.registered, f.regression);

  // A frame collapsed onto a line has no placement: NaN, not an exception.
  long3r::SequencePrediction collapsed = still;
  collapsed.pts[2] = at::zeros({96, 96, 3});
  collapsed.pts[2].select(-1, 2).fill_(1.0f);
  const long3r::LossProbe c = long3r::probe_loss(collapsed, s);
  EXPECT_TRUE(std::isfinite(c.regression));
  EXPECT_TRUE(std::isnan(c.registered));

  long3r::SequencePrediction short_p = still;
  short_p.pts.pop_back();
  EXPECT_THROW(long3r::probe_loss(short_p, s), std::invalid_argument);
}

// ------------------------------------------------------------ blind control

namespace {

// Held-out sequences of `frames` frames at 64 x 64: one scene, two starts,
// the given stride.
std::vector<long3r::SequenceSample> blind_set(int64_t frames, int64_t stride) {
  long3r::DataConfig dc;
  dc.synth.val_seed_begin = 2000000;
  dc.synth.train_scenes = 0;
  dc.synth.trajectory_frames = 120;
  long3r::SequenceSampler sampler(dc, 64, 0, 1);
  long3r::ValidationConfig vc;
  vc.blind_scenes = 1;
  vc.blind_starts = 2;
  vc.blind_strides = {stride};
  vc.blind_frames = frames;
  return sampler.blind_sequences(vc);
}

}  // namespace

// Registration by construction: the ground truth (at any scale) scores 0;
// each frame left in its own camera scores as the blind prediction does,
// ratio 1, and applies no rotation.
TEST(TrainBlind, OraclesScoreZeroAndOne) {
  const std::vector<long3r::SequenceSample> seqs = blind_set(3, 6);
  ASSERT_EQ(seqs.size(), 2u);
  EXPECT_EQ(seqs[1].source, "val:2000000@107+6");  // the last start that fits
  std::vector<long3r::SequencePrediction> exact, still;
  for (const long3r::SequenceSample& s : seqs) {
    long3r::SequencePrediction e;
    for (int64_t i = 0; i < 3; ++i) e.pts.push_back((s.pts[i] * 2.5f).contiguous());
    exact.push_back(e);
    still.push_back(long3r::true_depth_no_motion_prediction(s));
  }
  const long3r::BlindControl perfect = long3r::score_blind_control(seqs, exact, still);
  EXPECT_EQ(perfect.frames, 4);
  EXPECT_EQ(perfect.unplaced, 0);
  EXPECT_LT(perfect.reg_true, 1e-5);
  EXPECT_GT(perfect.reg_blind, 1e-3);
  EXPECT_LT(perfect.blind_ratio, 1e-3);
  EXPECT_LT(perfect.rot_err_deg, 0.05);
  EXPECT_GT(perfect.rot_true_deg, 0.1);
  EXPECT_GT(perfect.motion_px, 0.5);
  EXPECT_LT(perfect.shape_err, 1e-5);

  const long3r::BlindControl none = long3r::score_blind_control(seqs, still, still);
  EXPECT_DOUBLE_EQ(none.blind_ratio, 1.0);
  EXPECT_DOUBLE_EQ(none.reg_true, perfect.reg_blind);
  EXPECT_NEAR(none.rot_err_deg, none.rot_true_deg, 0.05);
  // Each frame in its own camera has the true shape: its error is all
  // placement, and the shape error tells the two apart.
  EXPECT_LT(none.shape_err, 1e-4);
  EXPECT_GT(none.reg_true, 100.0 * none.shape_err);

  // Points bent away from any Sim(3) (depth grows across the image): a shape
  // error, which no placement removes, bounded by the whole error.
  std::vector<long3r::SequencePrediction> bent = exact;
  for (long3r::SequencePrediction& p : bent) {
    for (at::Tensor& f : p.pts) {
      const at::Tensor x = f.select(-1, 0);
      f = (f * (1.0 + 0.3 * (x - x.mean()) / (x.std() + 1e-6)).unsqueeze(-1)).contiguous();
    }
  }
  const long3r::BlindControl shaped = long3r::score_blind_control(seqs, bent, still);
  EXPECT_GT(shaped.shape_err, 0.01);
  EXPECT_LE(shaped.shape_err, 1.05 * shaped.reg_true);
  EXPECT_NEAR(
      long3r::frame_shape_error(bent[0].pts[1], seqs[0].pts[1], seqs[0].valid[1]),
      long3r::frame_shape_error(bent[0].pts[1] * 3.0f + 1.0f, seqs[0].pts[1], seqs[0].valid[1]),
      1e-4);

  // Wider strides move the points further across the image.
  const std::vector<long3r::SequenceSample> wide = blind_set(3, 18);
  std::vector<long3r::SequencePrediction> wide_still;
  for (const long3r::SequenceSample& s : wide) {
    wide_still.push_back(long3r::true_depth_no_motion_prediction(s));
  }
  EXPECT_GT(long3r::score_blind_control(wide, wide_still, wide_still).motion_px,
            1.5 * none.motion_px);

  // A frame that cannot be placed is counted, not scored.
  std::vector<long3r::SequencePrediction> broken = exact;
  broken[0].pts[1] = at::full({64, 64, 3}, std::numeric_limits<float>::quiet_NaN());
  const long3r::BlindControl b = long3r::score_blind_control(seqs, broken, still);
  EXPECT_EQ(b.frames, 3);
  EXPECT_EQ(b.unplaced, 1);
  EXPECT_THROW(long3r::score_blind_control(seqs, exact, {still[0]}), std::invalid_argument);
}

// The model's run: batched, in inference mode, the mode restored after; the
// same figures as predicting each sequence on its own.
TEST(TrainBlind, ModelRunMatchesPerSequencePredictions) {
  at::manual_seed(11);
  long3r::Long3rModel model(long3r::test::tiny_long3r_config());
  model.set_training(true);
  const std::vector<long3r::SequenceSample> seqs = blind_set(3, 6);
  const long3r::BlindControl b = long3r::blind_control(model, seqs);
  EXPECT_TRUE(model.training());
  EXPECT_EQ(b.frames, 4);
  EXPECT_TRUE(std::isfinite(b.blind_ratio));
  std::vector<long3r::SequencePrediction> truth, blind;
  for (const long3r::SequenceSample& s : seqs) {
    truth.push_back(long3r::predict_sequence(model, s));
    long3r::SequencePrediction own;
    own.pts.push_back(truth.back().pts[0]);
    for (int64_t k = 1; k < 3; ++k) {
      long3r::SequenceSample pair;
      pair.images = {s.images[k], s.images[k]};
      own.pts.push_back(long3r::predict_sequence(model, pair).pts[1]);
    }
    blind.push_back(own);
  }
  // Batched streams run the padded attention path: equal to float rounding.
  const long3r::BlindControl one = long3r::score_blind_control(seqs, truth, blind);
  EXPECT_NEAR(b.reg_true, one.reg_true, 1e-4 * one.reg_true);
  EXPECT_NEAR(b.reg_blind, one.reg_blind, 1e-4 * one.reg_blind);
  EXPECT_NEAR(b.shape_err, one.shape_err, 1e-3 * one.shape_err);
  EXPECT_DOUBLE_EQ(b.rot_true_deg, one.rot_true_deg);
  EXPECT_DOUBLE_EQ(b.motion_px, one.motion_px);
}

// The completion stage's control: the same hidden patches for both
// references, torch's default generator untouched, repeatable.
TEST(TrainBlind, CompletionControlComparesTrueAndShuffledReferences) {
  at::manual_seed(12);
  long3r::Long3rModel model(long3r::test::tiny_long3r_config());
  const int64_t p = model.config().dust3r.patch_size;
  torch::nn::Linear head(model.config().dust3r.dec_embed_dim, p * p * 3);
  const std::vector<long3r::SequenceSample> pairs = blind_set(2, 6);
  at::manual_seed(5);
  const double expected_draw = at::rand({1}).item<double>();
  at::manual_seed(5);
  const long3r::CompletionControl c = long3r::completion_control(model, head, pairs, 0.75, 3);
  EXPECT_EQ(at::rand({1}).item<double>(), expected_draw);
  EXPECT_TRUE(std::isfinite(c.loss_true));
  EXPECT_TRUE(std::isfinite(c.loss_shuffled));
  EXPECT_NE(c.loss_true, c.loss_shuffled);
  const long3r::CompletionControl again = long3r::completion_control(model, head, pairs, 0.75, 3);
  EXPECT_EQ(again.loss_true, c.loss_true);
  EXPECT_THROW(long3r::completion_control(model, head, {pairs[0]}, 0.75), std::invalid_argument);
}

// ------------------------------------------- the fast pair configuration

// CroCo's initialisation: linear layers xavier-uniform with zero biases,
// unit LayerNorms, mask_token drawn, the DPT heads untouched.
TEST(TrainInit, CrocoInitialisation) {
  at::manual_seed(13);
  long3r::Long3rModel model(long3r::test::tiny_long3r_config());
  std::map<std::string, at::Tensor> before;
  for (const auto& kv : model.module().named_parameters()) before[kv.key()] = kv.value().clone();
  long3r::init_croco_weights(model);
  int linears = 0, heads = 0;
  for (const auto& item : model.module().named_modules()) {
    const std::string& name = item.key();
    torch::nn::Module& m = *item.value();
    if (name.find("downstream_head") != std::string::npos) {
      for (const auto& kv : m.named_parameters(/*recurse=*/false)) {
        EXPECT_TRUE(at::equal(kv.value(), before.at(name + "." + kv.key()))) << name;
        ++heads;
      }
      continue;
    }
    if (auto* l = m.as<torch::nn::LinearImpl>()) {
      const double bound =
          std::sqrt(6.0 / static_cast<double>(l->weight.size(0) + l->weight.size(1)));
      EXPECT_LE(l->weight.abs().max().item<double>(), bound) << name;
      EXPECT_GT(l->weight.abs().max().item<double>(), 0.5 * bound) << name;
      if (l->bias.defined()) {
        EXPECT_EQ(l->bias.abs().max().item<double>(), 0.0) << name;
      }
      ++linears;
    } else if (auto* n = m.as<torch::nn::LayerNormImpl>()) {
      if (!n->weight.defined()) continue;
      EXPECT_TRUE(at::equal(n->weight, at::ones_like(n->weight))) << name;
      EXPECT_TRUE(at::equal(n->bias, at::zeros_like(n->bias))) << name;
    }
  }
  EXPECT_GT(linears, 10);
  EXPECT_GT(heads, 0);
  const at::Tensor mask = model.module().named_parameters()["dust3r.mask_token"];
  EXPECT_GT(mask.abs().max().item<double>(), 0.0);
  EXPECT_LT(mask.abs().max().item<double>(), 0.2);
}

// Crops centred on the principal point keep it at the model input's centre
// whatever the crop's size; reversed sequences say so in their source.
TEST(TrainData, CropAtThePrincipalPointAndReversedSequences) {
  long3r::DataConfig dc;
  dc.synth.train_scenes = 3;
  dc.synth.trajectory_frames = 30;
  dc.synth.render_size = 96;
  dc.augment.max_crop = 0.4;
  dc.augment.crop_at_principal_point = true;
  dc.reverse_fraction = 1.0;
  long3r::SequenceSampler sampler(dc, 64, 4);
  for (int i = 0; i < 4; ++i) {
    const long3r::SequenceSample s = sampler.sample(2);
    // Integer crop offsets: within half a source pixel, scaled up to 64 / 57.
    EXPECT_NEAR(s.intrinsics[0].cx, 31.5, 0.6) << s.source;
    EXPECT_NEAR(s.intrinsics[0].cy, 31.5, 0.6) << s.source;
    EXPECT_EQ(s.source.back(), 'r');
  }
  dc.reverse_fraction = 0.0;
  long3r::SequenceSampler forward(dc, 64, 4);
  EXPECT_NE(forward.sample(2).source.back(), 'r');
}

// DUSt3R's linear head in the LONG3R trainer path: the fast pair model
// (patch 8) overfits a fixed pair.
TEST(TrainOptim, LinearHeadModelFitsAFixedPair) {
  at::manual_seed(14);
  long3r::ModelConfig mc = long3r::test::tiny_long3r_config();
  mc.dust3r.head_type = long3r::HeadType::kLinear;
  mc.dust3r.patch_size = 8;
  long3r::Long3rModel model(mc);
  const auto params = model.module().named_parameters();
  ASSERT_TRUE(params.contains("dust3r.downstream_head1.proj.weight"));
  EXPECT_EQ(params["dust3r.downstream_head1.proj.weight"].sizes(),
            (at::IntArrayRef{4 * 8 * 8, mc.dust3r.dec_embed_dim}));
  EXPECT_FALSE(params.contains("dust3r.downstream_head1.dpt.head.0.weight"));
  long3r::init_croco_weights(model);
  model.set_training(true);
  long3r::DataConfig dc;
  dc.synth.train_scenes = 1;
  dc.synth.trajectory_frames = 20;
  long3r::SequenceSampler sampler(dc, 64, 3);
  const long3r::Batch batch = long3r::collate({sampler.sample(2)});
  {
    const long3r::TrainingModeGuard inference(model, false);
    EXPECT_EQ(model.forward_sequence(batch.frames)[1].pts3d.sizes(),
              (at::IntArrayRef{1, 64, 64, 3}));
  }
  const auto [first, last] = overfit(model, batch, 25);
  EXPECT_LT(last, 0.6 * first) << "first " << first << " last " << last;
}

TEST(TrainConfig, BlindControlAndPairFieldsAreChecked) {
  const std::string base = R"({"model": "long3r_tiny", "image_size": 64,
    "stages": [{"steps": 1, "frames": 2}], "data": {"synth": {"val_scenes": 4}}, )";
  const long3r::TrainConfig ok = long3r::parse_train_config(
      base +
      R"("weight_init": "croco", "validation": {"blind_scenes": 4, "blind_strides": [4, 8]}})");
  EXPECT_EQ(ok.weight_init, "croco");
  EXPECT_EQ(ok.validation.blind_strides, (std::vector<int64_t>{4, 8}));
  auto error = [&](const std::string& tail) {
    try {
      long3r::parse_train_config(base + tail);
    } catch (const std::invalid_argument& e) {
      return std::string(e.what());
    }
    return std::string("parsed");
  };
  EXPECT_NE(error(R"("weight_init": "xavier"})").find("weight_init"), std::string::npos);
  EXPECT_NE(error(R"("validation": {"blind_scenes": 5}})").find("blind_scenes"), std::string::npos);
  EXPECT_NE(
      error(R"("validation": {"blind_scenes": 2, "blind_strides": [300]}})").find("blind_strides"),
      std::string::npos);
  EXPECT_THROW(long3r::parse_train_config(R"({"stages": [{"steps": 1, "frames": 2}],
    "data": {"reverse_fraction": 1.5}})"),
               std::invalid_argument);
}

// ------------------------------------------------------------ data parallel

TEST(TrainData, ShardsOfABatchAreItsParts) {
  long3r::DataConfig dc;
  dc.synth.train_scenes = 3;
  dc.synth.trajectory_frames = 20;
  long3r::SequenceSampler whole(dc, 32, 11), first(dc, 32, 11), second(dc, 32, 11);
  const long3r::Batch all = whole.sample_batch(4, 3);
  const long3r::Batch a = first.sample_batch(4, 3, 0, 1);
  const long3r::Batch b = second.sample_batch(4, 3, 1, 3);
  ASSERT_EQ(a.pts.size(0), 1);
  ASSERT_EQ(b.pts.size(0), 3);
  EXPECT_TRUE(at::equal(at::cat({a.pts, b.pts}), all.pts));
  EXPECT_TRUE(at::equal(at::cat({a.frames[2], b.frames[2]}), all.frames[2]));
  EXPECT_EQ(b.sources[2], all.sources[3]);
  // Every sampler moved past the whole batch: the next batches agree too.
  EXPECT_EQ(first.rng_state(), whole.rng_state());
  EXPECT_EQ(second.rng_state(), whole.rng_state());
  EXPECT_EQ(first.sample_batch(2, 2).sources, whole.sample_batch(2, 2).sources);
  EXPECT_THROW(second.sample_batch(4, 3, 3, 2), std::invalid_argument);
}

TEST(TrainLoss, ShardedLossesAddUpToTheWholeBatch) {
  // Two "ranks" each hold two of a batch of four; valid pixels fall unevenly
  // and only some items are over scale, so per-shard means would not add up.
  at::manual_seed(7);
  const int64_t B = 4, N = 3, H = 5, W = 6;
  const at::Tensor gt = random_gt(B, N, H, W);
  const at::Tensor valid = at::rand({B, N, H, W}) > 0.3;
  valid[0].fill_(true);
  const at::Tensor pred0 =
      (gt + at::randn_like(gt) * 0.2) * at::tensor({1.5f, 1.4f, 0.9f, 0.7f}).view({B, 1, 1, 1, 1});
  const at::Tensor conf0 = at::rand({B, N, H, W}) + 1.0;
  LossConfig cfg;
  auto loss_of = [&](int64_t first, int64_t count, const long3r::BatchShards* shards,
                     at::Tensor* grad) {
    const at::Tensor pred = pred0.narrow(0, first, count).clone().set_requires_grad(true);
    std::vector<StreamOutput> out, coarse;
    make_outputs(pred, 1.0, conf0.narrow(0, first, count), &out, &coarse);
    const long3r::LossTerms t = long3r::sequence_loss(out, coarse, gt.narrow(0, first, count),
                                                      valid.narrow(0, first, count), cfg, shards);
    t.total.backward();
    *grad = pred.grad();
    return t.total.item<double>();
  };
  at::Tensor g_whole, g0, g1;
  const double whole = loss_of(0, B, nullptr, &g_whole);
  // What each rank's normalisers are, then each rank summing in the other's.
  std::vector<at::Tensor> local(2);
  for (int r = 0; r < 2; ++r) {
    long3r::BatchShards record{2, [&local, r](const at::Tensor& t) { local[r] = t.clone(); }};
    at::Tensor unused;
    loss_of(2 * r, 2, &record, &unused);
  }
  long3r::BatchShards rank0{2, [&](const at::Tensor& t) { t.add_(local[1]); }};
  long3r::BatchShards rank1{2, [&](const at::Tensor& t) { t.add_(local[0]); }};
  const double l0 = loss_of(0, 2, &rank0, &g0), l1 = loss_of(2, 2, &rank1, &g1);
  EXPECT_NEAR((l0 + l1) / 2.0, whole, 1e-5 * std::abs(whole));
  // Averaged over the ranks, the gradients are the whole batch's.
  EXPECT_TRUE(at::allclose(at::cat({g0, g1}) / 2.0, g_whole, 1e-4, 1e-7));
  // Without the shared normalisers the shards' mean loss would differ.
  at::Tensor unused;
  const double plain = (loss_of(0, 2, nullptr, &unused) + loss_of(2, 2, nullptr, &unused)) / 2.0;
  EXPECT_GT(std::abs(plain - whole), 1e-4);
}

TEST(DataParallel, TheJobComesFromTorchrunSrunOrNothing) {
  auto env_of = [](std::map<std::string, std::string> vars) {
    return long3r::distributed_env_from([vars](const char* name) -> const char* {
      const auto it = vars.find(name);
      return it == vars.end() ? nullptr : it->second.c_str();
    });
  };
  const long3r::DistributedEnv none = env_of({});
  EXPECT_FALSE(none.distributed());
  EXPECT_EQ(none.launcher, "none");
  const long3r::DistributedEnv torchrun = env_of({{"RANK", "3"},
                                                  {"WORLD_SIZE", "8"},
                                                  {"LOCAL_RANK", "1"},
                                                  {"MASTER_ADDR", "node0"},
                                                  {"MASTER_PORT", "29500"},
                                                  {"TORCHELASTIC_RUN_ID", "x"},
                                                  {"TORCHELASTIC_USE_AGENT_STORE", "True"},
                                                  {"TORCHELASTIC_RESTART_COUNT", "2"}});
  EXPECT_TRUE(torchrun.distributed());
  EXPECT_EQ(torchrun.launcher, "torchrun");
  EXPECT_EQ(torchrun.rank, 3);
  EXPECT_EQ(torchrun.local_rank, 1);
  EXPECT_EQ(torchrun.master_addr, "node0");
  EXPECT_EQ(torchrun.master_port, 29500);
  EXPECT_TRUE(torchrun.agent_store);
  EXPECT_EQ(torchrun.restart_count, 2);
  EXPECT_EQ(torchrun.describe(), "rank 3 of 8");
  const long3r::DistributedEnv srun = env_of({{"SLURM_PROCID", "5"},
                                              {"SLURM_NTASKS", "16"},
                                              {"SLURM_LOCALID", "1"},
                                              {"MASTER_ADDR", "gpu01"},
                                              {"MASTER_PORT", "12345"}});
  EXPECT_EQ(srun.launcher, "srun");
  EXPECT_EQ(srun.rank, 5);
  EXPECT_EQ(srun.world_size, 16);
  EXPECT_FALSE(srun.agent_store);
  // One SLURM task is one process, whatever else is set.
  EXPECT_FALSE(env_of({{"SLURM_PROCID", "0"}, {"SLURM_NTASKS", "1"}}).distributed());
  // Malformed or inconsistent variables are named.
  auto refused = [&](std::map<std::string, std::string> vars, const std::string& named) {
    try {
      env_of(vars);
      ADD_FAILURE() << "accepted; expected a refusal naming " << named;
    } catch (const long3r::ConfigError& e) {
      EXPECT_NE(std::string(e.what()).find(named), std::string::npos) << e.what();
    }
  };
  refused({{"RANK", "2"}, {"WORLD_SIZE", "2"}, {"MASTER_ADDR", "a"}, {"MASTER_PORT", "1"}},
          "RANK=\"2\"");
  refused({{"RANK", "0"}, {"WORLD_SIZE", "two"}}, "WORLD_SIZE");
  refused({{"RANK", "1"}, {"WORLD_SIZE", "2"}, {"MASTER_PORT", "29500"}}, "MASTER_ADDR");
  refused({{"SLURM_PROCID", "1"}, {"SLURM_NTASKS", "2"}}, "scontrol show hostnames");
  refused({{"RANK", "0"}, {"WORLD_SIZE", "2"}, {"MASTER_ADDR", "a"}, {"MASTER_PORT", "70000"}},
          "MASTER_PORT");
  long3r::DataParallelConfig bad;
  bad.backend = "mpi";
  EXPECT_THROW(bad.validate(), long3r::ConfigError);
}

TEST(DataParallel, AGlobalBatchMustSplitEvenly) {
  long3r::TrainConfig c = tiny_config();
  c.stages[0].batch_size = 3;
  long3r::TrainOptions o;
  o.out_dir = scratch("uneven");
  o.distributed.world_size = 2;
  o.distributed.rank = 0;
  try {
    long3r::Trainer t(c, o);
    ADD_FAILURE() << "a batch of 3 over 2 ranks was accepted";
  } catch (const long3r::ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("batch_size 3"), std::string::npos) << e.what();
  }
}

// ------------------------------------------------------------ dataset mixing

namespace {

// A recorded sequence in memory: flat depth 2 m, identity poses moving along
// x; frame `broken` (if any) cannot be read.
class MemorySequence : public long3r::RecordedSource {
 public:
  MemorySequence(std::string name, int64_t size, int64_t broken = -1)
      : name_(std::move(name)), size_(size), broken_(broken) {}
  int64_t size() const override { return size_; }
  long3r::RawFrame frame(int64_t index) const override {
    if (index == broken_) {
      throw long3r::RecordedFrameError(name_ + "/frame" + std::to_string(index) +
                                       ".png: truncated");
    }
    long3r::RawFrame f;
    f.bgr = at::full({24, 32, 3}, static_cast<int>(index % 200), at::kByte);
    f.depth = at::full({24, 32}, 2.0f);
    f.intrinsics = long3r::PinholeIntrinsics::from_hfov(32, 24, 60.0);
    f.T_W_C.translation().x() = 0.1 * static_cast<double>(index);
    return f;
  }
  std::string name() const override { return name_; }

 private:
  std::string name_;
  int64_t size_, broken_;
};

}  // namespace

TEST(TrainData, DatasetsMixByWeightAndUnreadableFramesAreSkipped) {
  long3r::DataConfig dc;
  dc.synth.enabled = false;
  long3r::DatasetSource a, b;
  a.layout = "scannet";
  a.root = "/nonexistent/a";
  a.weight = 3.0;
  a.min_stride = 2;
  a.max_stride = 5;
  b.layout = "co3d";
  b.root = "/nonexistent/b";
  b.name = "objects";
  dc.datasets = {a, b};
  dc.augment.max_crop = 0.0;
  long3r::DatasetOpener opener = [](const long3r::DatasetSource& s) {
    long3r::OpenedDataset d;
    if (s.layout == "scannet") {
      d.sequences.push_back(std::make_unique<MemorySequence>("scene0", 60));
    } else {
      // Frame 1 of this sequence cannot be read, and every 3-frame sample
      // of its 3 frames needs it: all of them are skipped.
      d.sequences.push_back(std::make_unique<MemorySequence>("seq1", 3, 1));
      d.skipped.push_back(s.root + "/seq2: no index");
    }
    return d;
  };
  long3r::SequenceSampler sampler(dc, 16, 5, 1, {}, opener);
  int from_a = 0, from_b = 0;
  const int n = 200;
  for (int i = 0; i < n; ++i) {
    const long3r::SequenceSample s = sampler.sample(3);
    if (s.source.rfind("scannet:scene0@", 0) == 0) {
      ++from_a;
      // Gaps within [2, 5]: "scannet:scene0@start+g1+g2".
      std::stringstream gaps(s.source.substr(s.source.find('@') + 1));
      int64_t start = 0, g = 0;
      char plus = 0;
      gaps >> start;
      for (int k = 0; k < 2; ++k) {
        gaps >> plus >> g;
        EXPECT_TRUE(plus == '+' && g >= 2 && g <= 5) << s.source;
      }
    } else {
      EXPECT_EQ(s.source.rfind("objects:seq1@", 0), 0u) << s.source;
      ++from_b;
    }
  }
  // 3 : 1 by weight, less the samples of "objects", all skipped: about a
  // third as many skips as samples kept.
  EXPECT_EQ(from_b, 0);
  EXPECT_EQ(from_a, n);
  EXPECT_GT(sampler.skipped_samples(), n / 8);
  EXPECT_LT(sampler.skipped_samples(), n / 2);
  // A dataset with no usable sequence is refused by name; so is a build
  // without readers.
  long3r::DataConfig empty = dc;
  empty.datasets = {b};
  EXPECT_THROW(
      long3r::SequenceSampler(empty, 16, 5, 1, {},
                              [](const long3r::DatasetSource&) { return long3r::OpenedDataset{}; }),
      std::runtime_error);
  EXPECT_THROW(long3r::SequenceSampler(dc, 16, 5, 1), std::runtime_error);
}

TEST(TrainConfig, DatasetsAreCheckedByName) {
  long3r::TrainConfig c = tiny_config();
  c.data.synth.enabled = false;
  long3r::DatasetSource d;
  d.layout = "scannet";
  d.root = "/data/scannet";
  c.data.datasets = {d};
  EXPECT_NO_THROW(long3r::validate_train_config(c));
  // Through the JSON file, field by field.
  const long3r::TrainConfig back = long3r::parse_train_config(long3r::train_config_to_json(c));
  ASSERT_EQ(back.data.datasets.size(), 1u);
  EXPECT_EQ(back.data.datasets[0].root, "/data/scannet");
  auto refused = [&](long3r::TrainConfig bad, const std::string& named) {
    try {
      long3r::validate_train_config(bad);
      ADD_FAILURE() << "accepted; expected a refusal naming " << named;
    } catch (const long3r::ConfigError& e) {
      EXPECT_NE(std::string(e.what()).find(named), std::string::npos) << e.what();
    }
  };
  long3r::TrainConfig bad = c;
  bad.data.datasets[0].layout = "megadepth";
  refused(bad, "data.datasets[0].layout \"megadepth\"");
  bad = c;
  bad.data.datasets[0].weight = 0.0;
  refused(bad, "data.datasets[0].weight");
  bad = c;
  bad.data.datasets[0].max_stride = 0;
  refused(bad, "min_stride <= max_stride");
  bad = c;
  bad.data.synth.enabled = true;
  refused(bad, "data.synth.enabled to false");
}

TEST(TrainTrainer, TrainsOnAPublicDatasetLayout) {
  // Two ScanNet-layout scenes written from generated ones, read through the
  // trainer's OpenCV extensions, trained on for the tiny schedule.
  const std::string root = scratch("layout_scannet");
  long3r::synth::write_scannet_sequence(root, "scene0000_00",
                                        long3r::synth::render_layout_frames(21, 8, 64, 48));
  long3r::synth::write_scannet_sequence(root, "scene0001_00",
                                        long3r::synth::render_layout_frames(22, 8, 64, 48));
  long3r::TrainConfig c = tiny_config();
  c.data.synth.enabled = false;
  long3r::DatasetSource d;
  d.layout = "scannet";
  d.root = root;
  d.max_stride = 2;
  c.data.datasets = {d};
  long3r::TrainOptions o;
  o.out_dir = scratch("layout_scannet_run");
  o.quiet = true;
  o.extensions = long3r::opencv_trainer_extensions();
  long3r::Trainer t(c, o);
  t.run();
  ASSERT_EQ(t.log().size(), 6u);
  for (const long3r::LogRow& r : t.log()) EXPECT_TRUE(std::isfinite(r.loss)) << r.step;
  // Without the readers (a torch-only build) such a config is refused.
  o.extensions.open_dataset = {};
  EXPECT_THROW(long3r::Trainer(c, o), std::runtime_error);
}

// Tests of the network blocks (src/long3r/model/network/modules.hpp): attention
// against a hand computation, shapes through encoder / decoder / DPT head for
// grids of odd size, postprocess, and the portrait transposition of
// landscape_only models.
#include <ATen/ATen.h>
#include <c10/core/InferenceMode.h>
#include <gtest/gtest.h>
#include <torch/utils.h>

#include <cmath>
#include <stdexcept>

#include "long3r/model/loading/checkpoint.hpp"
#include "long3r/model/network/modules.hpp"
#include "support/test_support.hpp"

namespace {

namespace m = long3r::model;

using long3r::test::copy_parameters;
using long3r::test::tiny_dust3r_config;

TEST(ModelBlocks, AttentionMatchesHandComputation) {
  torch::manual_seed(1);
  const int64_t B = 2, N = 5, C = 8, heads = 2, dh = C / heads;
  m::Attention attn(C, heads, true);
  const at::Tensor x = at::randn({B, N, C});
  c10::InferenceMode guard;
  const at::Tensor got = attn(x, m::RopeTable());

  const at::Tensor qkv = at::linear(x, attn->qkv->weight, attn->qkv->bias);  // [B, N, 3C]
  at::Tensor want = at::zeros({B, N, C});
  for (int64_t h = 0; h < heads; ++h) {
    const at::Tensor q = qkv.narrow(2, h * dh, dh);
    const at::Tensor k = qkv.narrow(2, C + h * dh, dh);
    const at::Tensor v = qkv.narrow(2, 2 * C + h * dh, dh);
    const at::Tensor w = at::softmax(at::bmm(q, k.transpose(1, 2)) / std::sqrt(double(dh)), -1);
    want.narrow(2, h * dh, dh).copy_(at::bmm(w, v));
  }
  want = at::linear(want, attn->proj->weight, attn->proj->bias);
  EXPECT_LE((got - want).abs().max().item<double>(), 1e-5);
}

TEST(ModelBlocks, BlockShapesAndResidual) {
  torch::manual_seed(2);
  c10::InferenceMode guard;
  m::Block block(32, 2, 128, true, 1e-6);
  m::DecoderBlock dblock(16, 2, 64, 1e-6, true);
  m::Rope2D rope(100.0);
  const at::Tensor x = at::randn({2, 12, 32});
  const at::Tensor before = x.clone();
  const at::Tensor y = block(x, rope.table(16, 3, 4, at::kCPU, at::kFloat));
  EXPECT_EQ(y.sizes(), x.sizes());
  EXPECT_TRUE(x.equal(before));  // inputs are never modified
  const at::Tensor a = at::randn({2, 12, 16}), b = at::randn({2, 12, 16});
  const m::RopeTable r = rope.table(8, 3, 4, at::kCPU, at::kFloat);
  EXPECT_EQ(dblock(a, b, r, r).sizes(), a.sizes());
  // norm_y exists only with norm_im2_in_dec.
  m::DecoderBlock no_norm_y(16, 2, 64, 1e-6, false);
  EXPECT_FALSE(no_norm_y->norm_y);
  EXPECT_TRUE(dblock->norm_y);
}

TEST(ModelBlocks, Dust3rShapesForOddGrids) {
  torch::manual_seed(4);
  m::Dust3rNet net(tiny_dust3r_config());
  c10::InferenceMode guard;
  // 3x5 and 5x7 patch grids exercise the refinenet4 crop.
  for (const auto& hw : std::vector<std::pair<int64_t, int64_t>>{{48, 80}, {80, 112}, {32, 32}}) {
    const int64_t H = hw.first, W = hw.second, N = (H / 16) * (W / 16);
    const at::Tensor img = at::randn({2, 3, H, W});
    const at::Tensor f = net->encode(img, long3r::Trace());
    EXPECT_EQ(f.sizes(), (std::vector<int64_t>{2, N, 32}));
    const auto g = net->grid(H, W);
    const auto dec = net->decode(f, g, f, g, long3r::Trace());
    ASSERT_EQ(dec.first.size(), 5u);  // encoder output + 4 layers
    EXPECT_EQ(dec.first.back().sizes(), (std::vector<int64_t>{2, N, 16}));
    long3r::TensorMap rec;
    const m::HeadOutput out = net->head(1, dec.first, H, W, long3r::Trace(&rec, "h."));
    EXPECT_EQ(out.pts3d.sizes(), (std::vector<int64_t>{2, H, W, 3}));
    EXPECT_EQ(out.conf.sizes(), (std::vector<int64_t>{2, H, W}));
    EXPECT_TRUE(out.pts3d.is_contiguous());
    EXPECT_GE(out.conf.min().item<double>(), 1.0);
    // refinenet4 before the crop is 2 * ceil(grid / 2).
    EXPECT_EQ(rec.at("h.refinenet4").size(2), 2 * ((H / 16 + 1) / 2));
    EXPECT_EQ(rec.at("h.raw").sizes(), (std::vector<int64_t>{2, 4, H, W}));
  }
  EXPECT_THROW(net->grid(50, 64), std::invalid_argument);
}

TEST(ModelBlocks, PostprocessExpModes) {
  long3r::Dust3rConfig c = tiny_dust3r_config();
  at::Tensor raw = at::zeros({1, 4, 1, 2});
  raw[0][0][0][0] = 3.0;  // xyz = (3, 4, 0), |xyz| = 5
  raw[0][1][0][0] = 4.0;
  raw[0][3][0][0] = 0.5;  // conf logit
  // Second pixel: xyz = 0 must give 0, not NaN.
  const m::HeadOutput o = m::postprocess(raw, c);
  const double s = std::expm1(5.0) / 5.0;
  EXPECT_NEAR(o.pts3d[0][0][0][0].item<double>(), 3.0 * s, 1e-3 * s);
  EXPECT_NEAR(o.pts3d[0][0][0][1].item<double>(), 4.0 * s, 1e-3 * s);
  EXPECT_EQ(o.pts3d[0][0][1].abs().sum().item<double>(), 0.0);
  EXPECT_NEAR(o.conf[0][0][0].item<double>(), 1.0 + std::exp(0.5), 1e-6);
  EXPECT_NEAR(o.conf[0][0][1].item<double>(), 2.0, 1e-6);

  c.conf_mode = long3r::ConfMode::kSigmoid;
  c.conf_vmin = 0.0;
  c.conf_vmax = 2.0;
  c.depth_mode = long3r::DepthMode::kLinear;
  const m::HeadOutput l = m::postprocess(raw, c);
  EXPECT_NEAR(l.pts3d[0][0][0][1].item<double>(), 4.0, 1e-6);
  EXPECT_NEAR(l.conf[0][0][0].item<double>(), 2.0 / (1.0 + std::exp(-0.5)), 1e-6);
}

TEST(ModelBlocks, PortraitOutputsAreTransposedWithLandscapeOnly) {
  torch::manual_seed(5);
  long3r::Dust3rConfig c = tiny_dust3r_config();
  c.landscape_only = true;
  m::Dust3rNet land_only(c);
  c.landscape_only = false;
  m::Dust3rNet free(c);
  copy_parameters(*land_only, *free);
  c10::InferenceMode guard;

  // Portrait: same head run, outputs transposed to [B, W, H, .].
  const int64_t H = 80, W = 48;
  const at::Tensor img = at::randn({1, 3, H, W});
  auto run = [&](m::Dust3rNet& net, const at::Tensor& image) {
    const at::Tensor f = net->encode(image, long3r::Trace());
    const auto g = net->grid(image.size(2), image.size(3));
    const auto dec = net->decode(f, g, f, g, long3r::Trace());
    return net->head(2, dec.second, image.size(2), image.size(3), long3r::Trace());
  };
  const m::HeadOutput p = run(land_only, img);
  const m::HeadOutput q = run(free, img);
  EXPECT_EQ(p.pts3d.sizes(), (std::vector<int64_t>{1, W, H, 3}));
  EXPECT_EQ(p.conf.sizes(), (std::vector<int64_t>{1, W, H}));
  EXPECT_EQ(q.pts3d.sizes(), (std::vector<int64_t>{1, H, W, 3}));
  EXPECT_TRUE(p.pts3d.equal(q.pts3d.transpose(1, 2)));
  EXPECT_TRUE(p.conf.equal(q.conf.transpose(1, 2)));

  // Landscape: no transposition either way.
  const at::Tensor limg = at::randn({1, 3, W, H});
  const m::HeadOutput a = run(land_only, limg);
  const m::HeadOutput b = run(free, limg);
  EXPECT_EQ(a.pts3d.sizes(), (std::vector<int64_t>{1, W, H, 3}));
  EXPECT_TRUE(a.pts3d.equal(b.pts3d));

  // ManyAR_PatchEmbed models take landscape images only.
  c.patch_embed = long3r::PatchEmbedKind::kManyAR;
  m::Dust3rNet many_ar(c);
  EXPECT_THROW(many_ar->encode(img, long3r::Trace()), std::invalid_argument);
  EXPECT_NO_THROW(many_ar->encode(limg, long3r::Trace()));
}

}  // namespace

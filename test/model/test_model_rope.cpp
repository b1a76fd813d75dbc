// Tests of the 2D RoPE (src/long3r/model/network/modules.hpp): table caching, table
// values against the closed form, and the rotation against a direct port of
// the official formula (chunk into y/x halves, rotate_half, embedding lookup).
#include <ATen/ATen.h>
#include <gtest/gtest.h>
#include <torch/utils.h>

#include <cmath>

#include "long3r/model/network/modules.hpp"

namespace {

using long3r::model::grid_positions;
using long3r::model::Rope2D;
using long3r::model::RopeTable;

TEST(ModelRope, TablesAreCachedPerHeadWidthGridDeviceDtype) {
  Rope2D rope(100.0);
  EXPECT_EQ(rope.cache_size(), 0u);
  const RopeTable a = rope.table(16, 7, 5, at::kCPU, at::kFloat);
  const RopeTable b = rope.table(16, 7, 5, at::kCPU, at::kFloat);
  EXPECT_EQ(rope.cache_size(), 1u);
  // The same storage, not a recomputation.
  EXPECT_EQ(a.cos.data_ptr(), b.cos.data_ptr());
  EXPECT_EQ(a.sin.data_ptr(), b.sin.data_ptr());
  EXPECT_EQ(a.cos.sizes(), (std::vector<int64_t>{35, 16}));

  rope.table(16, 5, 7, at::kCPU, at::kFloat);   // transposed grid
  rope.table(8, 7, 5, at::kCPU, at::kFloat);    // other head width
  rope.table(16, 7, 5, at::kCPU, at::kDouble);  // other dtype
  EXPECT_EQ(rope.cache_size(), 4u);
  const RopeTable c = rope.table(16, 7, 5, at::kCPU, at::kFloat);
  EXPECT_EQ(c.cos.data_ptr(), a.cos.data_ptr());
  rope.clear_cache();
  EXPECT_EQ(rope.cache_size(), 0u);
  EXPECT_THROW(rope.table(6, 2, 2, at::kCPU, at::kFloat), c10::Error);  // not a multiple of 4
}

TEST(ModelRope, TableValuesFollowTheClosedForm) {
  const double base = 100.0;
  const int64_t dh = 16, gh = 3, gw = 4, half = dh / 2;
  Rope2D rope(base);
  const RopeTable t = rope.table(dh, gh, gw, at::kCPU, at::kDouble);
  for (int64_t y = 0; y < gh; ++y) {
    for (int64_t x = 0; x < gw; ++x) {
      const int64_t n = y * gw + x;
      for (int64_t c = 0; c < dh; ++c) {
        const int64_t pos = c < half ? y : x;  // first half: row, second: column
        const int64_t j = c % half;
        const int64_t f = j % (half / 2);
        const double angle = static_cast<double>(pos) * std::pow(base, -2.0 * f / half);
        // Sign of rotate_half folded into the first quarter of each half.
        const double sign = j < half / 2 ? -1.0 : 1.0;
        EXPECT_NEAR(t.cos[n][c].item<double>(), std::cos(angle), 1e-6) << n << "," << c;
        EXPECT_NEAR(t.sin[n][c].item<double>(), sign * std::sin(angle), 1e-6) << n << "," << c;
      }
    }
  }
}

// The official RoPE2D.forward for tokens [B, heads, N, Dh] and positions [B, N, 2].
at::Tensor official_rope(const at::Tensor& tokens, const at::Tensor& positions, double base) {
  const int64_t D = tokens.size(3) / 2;
  const at::Tensor inv_freq =
      1.0 / at::pow(base, at::arange(0, D, 2, at::kFloat) / static_cast<double>(D));
  const at::Tensor t = at::arange(positions.max().item<int64_t>() + 1, at::kFloat);
  at::Tensor freqs = at::einsum("i,j->ij", {t, inv_freq});
  freqs = at::cat({freqs, freqs}, -1);
  const at::Tensor cos = freqs.cos(), sin = freqs.sin();
  auto rotate_half = [](const at::Tensor& x) {
    const int64_t h = x.size(-1) / 2;
    return at::cat({-x.narrow(-1, h, h), x.narrow(-1, 0, h)}, -1);
  };
  auto rope1d = [&](const at::Tensor& x, const at::Tensor& pos1d) {
    const at::Tensor c = at::embedding(cos, pos1d).unsqueeze(1);
    const at::Tensor s = at::embedding(sin, pos1d).unsqueeze(1);
    return x * c + rotate_half(x) * s;
  };
  const auto yx = tokens.chunk(2, -1);
  return at::cat({rope1d(yx[0], positions.select(2, 0)), rope1d(yx[1], positions.select(2, 1))},
                 -1);
}

TEST(ModelRope, ApplyEqualsTheOfficialFormula) {
  torch::manual_seed(3);
  const int64_t B = 2, heads = 3, gh = 4, gw = 6, dh = 16;
  const at::Tensor x = at::randn({B, heads, gh * gw, dh});
  Rope2D rope(100.0);
  const RopeTable table = rope.table(dh, gh, gw, at::kCPU, at::kFloat);
  const at::Tensor got = Rope2D::apply(x, table);
  const at::Tensor want = official_rope(x, grid_positions(B, gh, gw, at::kCPU), 100.0);
  EXPECT_LE((got - want).abs().max().item<double>(), 1e-6);

  // Non-contiguous input (as the attention passes it): same values.
  const at::Tensor xt = x.transpose(1, 2).contiguous().transpose(1, 2);
  ASSERT_FALSE(xt.is_contiguous());
  EXPECT_TRUE(Rope2D::apply(xt, table).equal(got));

  // A rotation per channel pair: norms per token and head are unchanged, and
  // the token at position (0, 0) is not rotated at all.
  EXPECT_TRUE(at::allclose(got.norm(2, -1), x.norm(2, -1), 1e-5, 1e-5));
  EXPECT_TRUE(at::allclose(got.select(2, 0), x.select(2, 0)));
  EXPECT_FALSE(at::allclose(got.select(2, 1), x.select(2, 1)));
}

TEST(ModelRope, GridPositionsAreRowMajorYX) {
  const at::Tensor p = grid_positions(2, 2, 3, at::kCPU);
  EXPECT_EQ(p.sizes(), (std::vector<int64_t>{2, 6, 2}));
  EXPECT_EQ(p.scalar_type(), at::kLong);
  const at::Tensor want = at::tensor({0, 0, 0, 1, 0, 2, 1, 0, 1, 1, 1, 2}, at::kLong).view({6, 2});
  EXPECT_TRUE(p[0].equal(want));
  EXPECT_TRUE(p[1].equal(want));
}

}  // namespace

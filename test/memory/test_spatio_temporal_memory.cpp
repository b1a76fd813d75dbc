// Tests of LONG3R's 3D spatio-temporal memory
// (include/long3r/memory/spatio_temporal_memory.hpp): token positions, adaptive voxel
// size, long-term pruning with its tie-breaking, field alignment, the memory
// bound, batch independence and autograd behaviour.
#include <ATen/ATen.h>
#include <c10/core/InferenceMode.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <map>
#include <set>
#include <tuple>
#include <utility>
#include <vector>

#include "long3r/memory/spatio_temporal_memory.hpp"

namespace {

using long3r::SpatioTemporalMemory;
using long3r::SpatioTemporalMemoryConfig;
using long3r::VoxelStatistic;

const double kSqrt2 = std::sqrt(2.0);

// Token (y, x) of an h x w grid at origin + (x * dx, y * dy, 0). [1, h*w, 3]
at::Tensor grid_positions(int64_t h, int64_t w, double dx, double dy,
                          std::array<double, 3> origin = {0, 0, 0}) {
  at::Tensor p = at::zeros({1, h * w, 3}, at::kDouble);
  for (int64_t y = 0; y < h; ++y) {
    for (int64_t x = 0; x < w; ++x) {
      p[0][y * w + x][0] = origin[0] + x * dx;
      p[0][y * w + x][1] = origin[1] + y * dy;
      p[0][y * w + x][2] = origin[2];
    }
  }
  return p.to(at::kFloat);
}

// Brute-force d_i: mean distance to the existing 8-neighbours.
std::vector<double> brute_force_distances(const at::Tensor& pos, int64_t h, int64_t w) {
  std::vector<double> out;
  for (int64_t y = 0; y < h; ++y) {
    for (int64_t x = 0; x < w; ++x) {
      double sum = 0;
      int n = 0;
      for (int64_t ny = y - 1; ny <= y + 1; ++ny) {
        for (int64_t nx = x - 1; nx <= x + 1; ++nx) {
          if ((ny == y && nx == x) || ny < 0 || nx < 0 || ny >= h || nx >= w) continue;
          sum += (pos[y * w + x] - pos[ny * w + nx]).to(at::kDouble).norm().item<double>();
          ++n;
        }
      }
      out.push_back(sum / n);
    }
  }
  return out;
}

}  // namespace

// ---------------------------------------------------------------------------
// Token positions.
// ---------------------------------------------------------------------------

// A planar pointmap X = u*s, Y = v*s, Z = 2 over an 8 x 12 image with patch 4:
// tokens at the patch centres; then a confidence spike and a zero-confidence patch.
TEST(SpatioTemporalMemory, TokenPositionsAreConfidenceWeightedPatchMeans) {
  const double s = 0.5;
  at::Tensor pts = at::zeros({1, 8, 12, 3});
  for (int64_t v = 0; v < 8; ++v) {
    for (int64_t u = 0; u < 12; ++u) {
      pts[0][v][u][0] = u * s;
      pts[0][v][u][1] = v * s;
      pts[0][v][u][2] = 2.0;
    }
  }
  at::Tensor conf = at::ones({1, 8, 12});
  at::Tensor tok = long3r::token_positions(pts, conf, 4);
  ASSERT_EQ(tok.sizes(), (std::vector<int64_t>{1, 6, 3}));
  for (int64_t i = 0; i < 2; ++i) {
    for (int64_t j = 0; j < 3; ++j) {
      EXPECT_NEAR(tok[0][i * 3 + j][0].item<double>(), (4 * j + 1.5) * s, 1e-6);
      EXPECT_NEAR(tok[0][i * 3 + j][1].item<double>(), (4 * i + 1.5) * s, 1e-6);
      EXPECT_NEAR(tok[0][i * 3 + j][2].item<double>(), 2.0, 1e-6);
    }
  }
  // Pixel (v=0, u=3) of token 0 with confidence 3: x = (24 + 2*3) / 18 * s, since
  // sum_u over the patch is 24; y = 24 / 18 * s (that pixel has v = 0).
  conf[0][0][3] = 3.0;
  // Token 5 (rows 4..7, columns 8..11) has zero total confidence: plain mean.
  conf[0].narrow(0, 4, 4).narrow(1, 8, 4).zero_();
  tok = long3r::token_positions(pts, conf, 4);
  EXPECT_NEAR(tok[0][0][0].item<double>(), 30.0 / 18.0 * s, 1e-6);
  EXPECT_NEAR(tok[0][0][1].item<double>(), 24.0 / 18.0 * s, 1e-6);
  EXPECT_NEAR(tok[0][5][0].item<double>(), 9.5 * s, 1e-6);
  EXPECT_NEAR(tok[0][5][1].item<double>(), 5.5 * s, 1e-6);
}

// ---------------------------------------------------------------------------
// Adaptive voxel size.
// ---------------------------------------------------------------------------

// Square grid of spacing a: corners have 3 neighbours (2 axial, 1 diagonal),
// edges 5 (3 axial, 2 diagonal), interior 8 (4 + 4). The min is a corner.
TEST(SpatioTemporalMemory, NeighbourDistancesOnSquareGrid) {
  const double a = 0.5;
  const double corner = (2 + kSqrt2) / 3 * a;
  const double edge = (3 + 2 * kSqrt2) / 5 * a;
  const double interior = (4 + 4 * kSqrt2) / 8 * a;
  const at::Tensor pos = grid_positions(3, 4, a, a, {1.0, -2.0, 3.0});
  const at::Tensor d = long3r::neighbour_distances(pos, {3, 4});
  ASSERT_EQ(d.sizes(), (std::vector<int64_t>{1, 12}));
  const std::vector<double> expected = {corner,   edge, edge,   corner, edge, interior,
                                        interior, edge, corner, edge,   edge, corner};
  for (int64_t i = 0; i < 12; ++i) EXPECT_NEAR(d[0][i].item<double>(), expected[i], 1e-6) << i;
  const std::vector<double> v = long3r::image_voxel_size(pos, {3, 4}, VoxelStatistic::kMin, 0.0);
  ASSERT_EQ(v.size(), 1u);
  EXPECT_NEAR(v[0], corner, 1e-6);
}

// Non-uniform grids where the minimum sits on the border.
TEST(SpatioTemporalMemory, NeighbourDistancesNonUniformGrids) {
  // dx = 1, dy = 2: a top/bottom edge token (neighbours: 2 x dx, 1 x dy, 2 diagonals)
  // has d = (4 + 2 sqrt5) / 5 ~ 1.694, below the corners ((3 + sqrt5) / 3 ~ 1.745),
  // left/right edges ((5 + 2 sqrt5) / 5) and the interior ((6 + 4 sqrt5) / 8).
  {
    const double s5 = std::sqrt(5.0);
    const at::Tensor pos = grid_positions(3, 4, 1.0, 2.0);
    const at::Tensor d = long3r::neighbour_distances(pos, {3, 4});
    EXPECT_NEAR(d[0][1].item<double>(), (4 + 2 * s5) / 5, 1e-6);  // top edge
    EXPECT_NEAR(d[0][0].item<double>(), (3 + s5) / 3, 1e-6);      // corner
    EXPECT_NEAR(d[0][4].item<double>(), (5 + 2 * s5) / 5, 1e-6);  // left edge
    EXPECT_NEAR(d[0][5].item<double>(), (6 + 4 * s5) / 8, 1e-6);  // interior
    EXPECT_NEAR(long3r::image_voxel_size(pos, {3, 4}, VoxelStatistic::kMin, 0)[0], (4 + 2 * s5) / 5,
                1e-6);
  }
  // 4 x 4 unit grid whose last column sits at x = 2.2 (0.2 from column 2): the
  // right corners have d = (1 + 0.2 + sqrt(1.04)) / 3 ~ 0.740, the minimum.
  {
    at::Tensor pos = grid_positions(4, 4, 1.0, 1.0);
    for (int64_t y = 0; y < 4; ++y) pos[0][y * 4 + 3][0] = 2.2;
    const at::Tensor d = long3r::neighbour_distances(pos, {4, 4});
    const std::vector<double> brute = brute_force_distances(pos[0], 4, 4);
    for (int64_t i = 0; i < 16; ++i) EXPECT_NEAR(d[0][i].item<double>(), brute[i], 1e-6) << i;
    const double right_corner = (1.2 + std::sqrt(1.04)) / 3;
    const double right_edge = (2.2 + 2 * std::sqrt(1.04)) / 5;
    EXPECT_NEAR(d[0][3].item<double>(), right_corner, 1e-6);
    EXPECT_NEAR(d[0][7].item<double>(), right_edge, 1e-6);
    EXPECT_NEAR(long3r::image_voxel_size(pos, {4, 4}, VoxelStatistic::kMin, 0)[0], right_corner,
                1e-6);
  }
}

// Percentile statistic (linear interpolation) on a 3 x 3 unit grid: sorted d =
// 4 corners, 4 edges, 1 interior.
TEST(SpatioTemporalMemory, VoxelSizePercentile) {
  const double corner = (2 + kSqrt2) / 3, edge = (3 + 2 * kSqrt2) / 5,
               interior = (4 + 4 * kSqrt2) / 8;
  const at::Tensor pos = grid_positions(3, 3, 1.0, 1.0);
  auto pct = [&](double p) {
    return long3r::image_voxel_size(pos, {3, 3}, VoxelStatistic::kPercentile, p)[0];
  };
  EXPECT_NEAR(pct(0), corner, 1e-6);
  EXPECT_NEAR(pct(25), corner, 1e-6);
  EXPECT_NEAR(pct(50), edge, 1e-6);
  EXPECT_NEAR(pct(93.75), (edge + interior) / 2, 1e-6);  // position 7.5 of 0..8
  EXPECT_NEAR(pct(100), interior, 1e-6);

  SpatioTemporalMemoryConfig cfg;
  cfg.voxel_statistic = VoxelStatistic::kPercentile;
  cfg.voxel_percentile = 50;
  SpatioTemporalMemory mem(cfg);
  mem.add_frame(at::zeros({1, 9, 4}), at::zeros({1, 9, 4}), pos, 0, {3, 3});
  EXPECT_NEAR(mem.last_v_img()[0], edge, 1e-6);
}

// v_img per frame and v_scene as the running mean, per stream.
TEST(SpatioTemporalMemory, SceneVoxelSizeIsRunningMean) {
  const double c = (2 + kSqrt2) / 3;  // v_img of a square grid of unit spacing
  const std::vector<std::array<double, 2>> spacing = {{1.0, 0.25}, {2.0, 1.0}, {0.5, 4.0}};
  SpatioTemporalMemory mem;
  std::array<double, 2> sum = {0, 0};
  for (size_t f = 0; f < spacing.size(); ++f) {
    const at::Tensor pos = at::cat({grid_positions(3, 4, spacing[f][0], spacing[f][0]),
                                    grid_positions(3, 4, spacing[f][1], spacing[f][1])});
    mem.add_frame(at::zeros({2, 12, 4}), at::zeros({2, 12, 4}), pos, static_cast<int64_t>(f),
                  {3, 4});
    for (int b = 0; b < 2; ++b) {
      sum[b] += c * spacing[f][b];
      EXPECT_NEAR(mem.last_v_img()[b], c * spacing[f][b], 1e-6) << f << "," << b;
      EXPECT_NEAR(mem.v_scene()[b], sum[b] / (f + 1), 1e-6) << f << "," << b;
    }
  }
  EXPECT_NEAR(mem.v_scene()[0], c * 3.5 / 3, 1e-6);
  EXPECT_NEAR(mem.v_scene()[1], c * 5.25 / 3, 1e-6);
  mem.reset();
  EXPECT_EQ(mem.batch_size(), 0);
  EXPECT_TRUE(mem.v_scene().empty());
}

// ---------------------------------------------------------------------------
// Pruning rule.
// ---------------------------------------------------------------------------

// Voxel size 1. Voxel (0,0,0): tokens 0 (a .2, frame 3) and 1 (a .9, frame 0) ->
// attention wins (1). Voxel (1,0,0): 2 and 3 tie on attention -> newer frame (3).
// Voxel (2,0,0): 4 and 5 tie on attention and frame -> later order (5). Voxel
// (-1,0,0): 6 (a .6) and 7 (a .1) -> 6; token 7 sits at x = -0.2 so truncation
// instead of floor would merge it into voxel (0,0,0). Token 8 has a NaN position
// and is never merged.
TEST(SpatioTemporalMemory, PruningRuleKeepsBestTokenPerVoxel) {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const at::Tensor pos = at::tensor({0.1f,  0.1f, 0.1f, 0.9f,  0.2f, 0.3f, 1.1f, 0.5f, 0.5f,
                                     1.9f,  0.9f, 0.9f, 2.5f,  0.5f, 0.5f, 2.6f, 0.4f, 0.4f,
                                     -0.5f, 0.2f, 0.3f, -0.2f, 0.2f, 0.3f, nan,  0.f,  0.f})
                             .reshape({9, 3});
  const at::Tensor att = at::tensor({0.2f, 0.9f, 0.4f, 0.4f, 0.3f, 0.3f, 0.6f, 0.1f, 0.05f});
  const at::Tensor frame = at::tensor({3, 0, 1, 2, 5, 5, 4, 4, 6}).to(at::kLong);
  const at::Tensor order = at::arange(9);
  auto kept = [&](double voxel, int64_t capacity) {
    const at::Tensor k = long3r::select_long_term_tokens(pos, att, frame, order, voxel, capacity);
    return std::vector<int64_t>(k.data_ptr<int64_t>(), k.data_ptr<int64_t>() + k.numel());
  };
  EXPECT_EQ(kept(1.0, 100), (std::vector<int64_t>{1, 3, 5, 6, 8}));
  // Capacity keeps the highest cumulative attention: .9, .6, .4.
  EXPECT_EQ(kept(1.0, 3), (std::vector<int64_t>{1, 3, 6}));
  EXPECT_EQ(kept(1.0, 0), (std::vector<int64_t>{}));
  // Voxel size 10: all finite tokens share voxel (0,0,0) except 6, 7 (voxel -1).
  EXPECT_EQ(kept(10.0, 100), (std::vector<int64_t>{1, 6, 8}));
  // No usable voxel size: capacity only.
  EXPECT_EQ(kept(0.0, 100).size(), 9u);
  EXPECT_EQ(kept(std::nan(""), 4), (std::vector<int64_t>{1, 2, 3, 6}));
}

// Capacity ties: equal attention -> higher frame index, then later order.
TEST(SpatioTemporalMemory, PruningCapacityTiesKeepNewer) {
  const at::Tensor pos = at::rand({5, 3});
  const at::Tensor att = at::tensor({0.5f, 0.5f, 0.5f, 0.1f, 0.5f});
  const at::Tensor frame = at::tensor({0, 2, 1, 3, 2}).to(at::kLong);
  const at::Tensor order = at::tensor({0, 1, 2, 3, 4}).to(at::kLong);
  auto kept = [&](int64_t capacity, const at::Tensor& ord) {
    const at::Tensor k = long3r::select_long_term_tokens(pos, att, frame, ord, 0.0, capacity);
    return std::vector<int64_t>(k.data_ptr<int64_t>(), k.data_ptr<int64_t>() + k.numel());
  };
  EXPECT_EQ(kept(1, order), (std::vector<int64_t>{4}));
  EXPECT_EQ(kept(2, order), (std::vector<int64_t>{1, 4}));
  EXPECT_EQ(kept(3, order), (std::vector<int64_t>{1, 2, 4}));
  EXPECT_EQ(kept(1, at::tensor({0, 9, 2, 3, 4}).to(at::kLong)), (std::vector<int64_t>{1}));
}

// The pruning rule against a brute-force reference on random clouds: one small
// enough for the packed voxel key, one spread so far (voxel indices up to the
// int64 clamp) that the rows must be compared whole, and non-finite tokens.
TEST(SpatioTemporalMemory, PruningMatchesBruteForceAtAnyScale) {
  at::manual_seed(13);
  const int64_t n = 400;
  for (const double spread : {3.0, 1e30}) {
    at::Tensor pos = (at::rand({n, 3}, at::kDouble) - 0.5) * spread;
    pos[7][1] = std::numeric_limits<double>::quiet_NaN();
    pos[9][2] = std::numeric_limits<double>::infinity();
    // Duplicated positions so that many voxels hold several tokens.
    pos.narrow(0, 200, 100).copy_(pos.narrow(0, 0, 100));
    const at::Tensor pos_f = pos.to(at::kFloat);
    const at::Tensor att = at::randint(0, 5, {n}).to(at::kFloat);
    const at::Tensor frame = at::randint(0, 20, {n}, at::kLong);
    const at::Tensor order = at::randperm(n, at::kLong);
    const double voxel = 0.25;
    // Reference: the greatest token per voxel by (attention, frame, order).
    auto greater = [&](int64_t a, int64_t b) {
      const auto key = [&](int64_t i) {
        return std::make_tuple(att[i].item<float>(), frame[i].item<int64_t>(),
                               order[i].item<int64_t>());
      };
      return key(a) > key(b);
    };
    std::map<std::array<int64_t, 3>, int64_t> best;
    std::vector<int64_t> winners;
    for (int64_t i = 0; i < n; ++i) {
      const at::Tensor p = pos_f[i].to(at::kDouble);
      if (!p.isfinite().all().item<bool>()) {
        winners.push_back(i);
        continue;
      }
      std::array<int64_t, 3> v{};
      for (int d = 0; d < 3; ++d) {
        v[d] = static_cast<int64_t>(
            std::clamp(std::floor(p[d].item<double>() / voxel), -4.0e18, 4.0e18));
      }
      const auto it = best.find(v);
      if (it == best.end() || greater(i, it->second)) best[v] = i;
    }
    for (const auto& kv : best) winners.push_back(kv.second);
    for (const int64_t capacity : {int64_t{1000}, int64_t{50}}) {
      std::vector<int64_t> want = winners;
      if (static_cast<int64_t>(want.size()) > capacity) {
        std::sort(want.begin(), want.end(), greater);
        want.resize(static_cast<std::size_t>(capacity));
      }
      std::sort(want.begin(), want.end());
      const at::Tensor k =
          long3r::select_long_term_tokens(pos_f, att, frame, order, voxel, capacity);
      const std::vector<int64_t> got(k.data_ptr<int64_t>(), k.data_ptr<int64_t>() + k.numel());
      EXPECT_EQ(got, want) << "spread " << spread << ", capacity " << capacity;
    }
    // The duplicates did merge.
    EXPECT_LT(best.size(), static_cast<std::size_t>(n - 2 - 100 + 1));
  }
}

// ---------------------------------------------------------------------------
// The memory class.
// ---------------------------------------------------------------------------

namespace {

// Every frame is a 2 x 2 unit grid, so v_img = v_scene = (2 + sqrt2) / 3 ~ 1.138.
// A frame placed at voxel m lies inside voxel (m, 0, 0): its tokens span
// [m v + 0.05, m v + 1.05] in x and y.
const double kUnitVoxel = (2 + kSqrt2) / 3;

std::array<double, 3> frame_origin(int64_t voxel_x) {
  return {voxel_x * kUnitVoxel + 0.05, 0.05, 0.5 * kUnitVoxel};
}

// Token (f, t) stored in B = 1 stream: key = [f, t, 7, 100 f + t], value = 0.5 - key.
struct Tracker {
  SpatioTemporalMemory mem;
  std::map<int64_t, int64_t> voxel_of_frame;
  std::map<std::pair<int64_t, int64_t>, double> attention;

  explicit Tracker(SpatioTemporalMemoryConfig cfg) : mem(cfg) {}

  void add(int64_t f, int64_t voxel_x) {
    voxel_of_frame[f] = voxel_x;
    at::Tensor keys = at::zeros({1, 4, 4});
    for (int64_t t = 0; t < 4; ++t) {
      keys[0][t][0] = f;
      keys[0][t][1] = t;
      keys[0][t][2] = 7;
      keys[0][t][3] = 100 * f + t;
    }
    mem.add_frame(keys, 0.5 - keys, grid_positions(2, 2, 1.0, 1.0, frame_origin(voxel_x)), f,
                  {2, 2});
  }
  std::pair<int64_t, int64_t> token_at(int64_t s) const {
    const at::Tensor k = mem.keys()[0][s];
    return {std::lround(k[0].item<double>()), std::lround(k[1].item<double>())};
  }
  // Adds attention to the listed tokens (in the current layout).
  void give(const std::map<std::pair<int64_t, int64_t>, double>& inc) {
    at::Tensor v = at::zeros({1, mem.padded_size()});
    for (int64_t s = 0; s < mem.padded_size(); ++s) {
      const auto it = inc.find(token_at(s));
      if (it != inc.end()) {
        v[0][s] = it->second;
        attention[it->first] += it->second;
      }
    }
    mem.add_attention(v);
  }
  // Checks every field of every token and returns the long-term tokens in order.
  std::vector<std::pair<int64_t, int64_t>> check() const {
    const int64_t n = mem.padded_size();
    EXPECT_EQ(mem.keys().sizes(), (std::vector<int64_t>{1, n, 4}));
    EXPECT_TRUE(mem.valid_mask().all().item<bool>());
    const at::Tensor attn = mem.attention();
    std::vector<std::pair<int64_t, int64_t>> long_tokens;
    for (int64_t s = 0; s < n; ++s) {
      const auto [f, t] = token_at(s);
      const at::Tensor key = mem.keys()[0][s];
      EXPECT_EQ(key[2].item<double>(), 7.0);
      EXPECT_EQ(key[3].item<double>(), 100.0 * f + t);
      EXPECT_TRUE(mem.values()[0][s].equal(0.5 - key)) << f << "," << t;
      EXPECT_EQ(mem.frame_indices()[0][s].item<int64_t>(), f);
      const std::array<double, 3> o = frame_origin(voxel_of_frame.at(f));
      const at::Tensor p = mem.positions()[0][s];
      EXPECT_NEAR(p[0].item<double>(), o[0] + (t % 2), 1e-6) << f << "," << t;
      EXPECT_NEAR(p[1].item<double>(), o[1] + (t / 2), 1e-6) << f << "," << t;
      EXPECT_NEAR(p[2].item<double>(), o[2], 1e-6);
      const auto it = attention.find({f, t});
      EXPECT_NEAR(attn[0][s].item<double>(), it == attention.end() ? 0.0 : it->second, 1e-6)
          << f << "," << t;
      if (s >= mem.short_size()) long_tokens.push_back({f, t});
    }
    return long_tokens;
  }
};

using TokenList = std::vector<std::pair<int64_t, int64_t>>;

}  // namespace

// K = 1: each frame moves to long-term when the next arrives. Frames 0, 1, 3 lie
// in voxel 0, frame 2 in voxel 5, frame 4 in voxel 10.
TEST(SpatioTemporalMemory, PruningKeepsFieldsAligned) {
  SpatioTemporalMemoryConfig cfg;
  cfg.short_term_frames = 1;
  cfg.long_term_capacity = 100;
  Tracker tr(cfg);

  tr.add(0, 0);
  EXPECT_NEAR(tr.mem.v_scene()[0], kUnitVoxel, 1e-6);
  EXPECT_EQ(tr.check(), TokenList{});
  tr.give({{{0, 0}, 0.125}, {{0, 1}, 0.5}, {{0, 2}, 0.25}, {{0, 3}, 0.5}});

  // Frame 0 moves: one voxel, tokens 1 and 3 tie at .5 within the frame -> the
  // later token (3).
  tr.add(1, 0);
  EXPECT_EQ(tr.check(), (TokenList{{0, 3}}));
  EXPECT_EQ(tr.mem.short_size(), 4);
  tr.give({{{1, 0}, 0.5}, {{1, 1}, 0.25}, {{1, 2}, 0.25}});

  // Frame 1 moves into voxel 0: (1,0) ties (0,3) at .5 -> the newer frame.
  tr.add(2, 5);
  EXPECT_EQ(tr.check(), (TokenList{{1, 0}}));
  tr.give({{{2, 2}, 0.75}});

  // Frame 2 moves into its own voxel: winner (2,2); long-term in insertion order.
  tr.add(3, 0);
  EXPECT_EQ(tr.check(), (TokenList{{1, 0}, {2, 2}}));
  tr.give({{{1, 0}, 1.0}, {{3, 1}, 1.25}});

  // Frame 3 moves into voxel 0: the older (1,0) with 1.5 beats (3,1) with 1.25.
  tr.add(4, 10);
  EXPECT_EQ(tr.check(), (TokenList{{1, 0}, {2, 2}}));
  EXPECT_EQ(tr.mem.long_sizes(), (std::vector<int64_t>{2}));
  EXPECT_EQ(tr.mem.total_sizes(), (std::vector<int64_t>{6}));
  EXPECT_EQ(tr.mem.frames_added(), 5);
}

// K = 1, L = 1, every frame in its own voxel: the capacity keeps the highest
// attention, and the newer token on a tie.
TEST(SpatioTemporalMemory, CapacityKeepsHighestAttentionTiesNewer) {
  SpatioTemporalMemoryConfig cfg;
  cfg.short_term_frames = 1;
  cfg.long_term_capacity = 1;
  Tracker tr(cfg);
  tr.add(0, 0);
  tr.give({{{0, 3}, 0.5}});
  tr.add(1, 3);
  EXPECT_EQ(tr.check(), (TokenList{{0, 3}}));
  tr.give({{{1, 2}, 0.5}});
  tr.add(2, 6);  // (0,3) and (1,2) tie at .5 -> (1,2)
  EXPECT_EQ(tr.check(), (TokenList{{1, 2}}));
  tr.give({{{2, 0}, 0.875}});
  tr.add(3, 9);  // (2,0) .875 beats (1,2) .5
  EXPECT_EQ(tr.check(), (TokenList{{2, 0}}));
}

// 300 frames of random tokens: the memory never exceeds K*P + L per stream and
// reaches it; right after every frame the long-term tokens occupy distinct voxels
// of the current v_scene and are older than the short-term window.
TEST(SpatioTemporalMemory, BoundedOverLongStream) {
  SpatioTemporalMemoryConfig cfg;
  cfg.short_term_frames = 3;
  cfg.long_term_capacity = 20;
  const int64_t p = 16, bound = 3 * p + 20;
  SpatioTemporalMemory mem(cfg);
  at::manual_seed(42);
  std::vector<int64_t> reached(2, 0);
  for (int64_t f = 0; f < 300; ++f) {
    // Stream 1 at a scale 100x smaller, to exercise per-stream voxel sizes.
    const at::Tensor pos = at::rand({2, p, 3}) * 10 * at::tensor({1.0f, 0.01f}).view({2, 1, 1});
    mem.add_frame(at::randn({2, p, 4}), at::randn({2, p, 4}), pos, f, {4, 4});
    const std::vector<int64_t> total = mem.total_sizes();
    const std::vector<int64_t> lng = mem.long_sizes();
    ASSERT_EQ(mem.keys().size(1), mem.padded_size());
    ASSERT_EQ(mem.short_size(), std::min<int64_t>(f + 1, 3) * p);
    const at::Tensor positions = mem.positions();
    const at::Tensor frames = mem.frame_indices();
    for (int b = 0; b < 2; ++b) {
      ASSERT_LE(total[b], bound) << f;
      ASSERT_LE(lng[b], 20) << f;
      reached[b] = std::max(reached[b], total[b]);
      const at::Tensor lp = positions[b].narrow(0, mem.short_size(), lng[b]).to(at::kDouble);
      const at::Tensor voxels = (lp / mem.v_scene()[b]).floor();
      std::set<std::array<int64_t, 3>> distinct;
      for (int64_t i = 0; i < lng[b]; ++i) {
        distinct.insert({voxels[i][0].item<int64_t>(), voxels[i][1].item<int64_t>(),
                         voxels[i][2].item<int64_t>()});
        ASSERT_LT(frames[b][mem.short_size() + i].item<int64_t>(), f - 2);
      }
      ASSERT_EQ(static_cast<int64_t>(distinct.size()), lng[b]) << f;
    }
    mem.add_attention(at::rand({2, mem.padded_size()}) * mem.valid_mask());
  }
  EXPECT_EQ(reached, (std::vector<int64_t>{bound, bound}));
  EXPECT_EQ(mem.total_sizes(), (std::vector<int64_t>{bound, bound}));
}

// A B = 2 memory behaves as two B = 1 memories; its padding is marked invalid.
TEST(SpatioTemporalMemory, BatchStreamsAreIndependent) {
  SpatioTemporalMemoryConfig cfg;
  cfg.short_term_frames = 2;
  cfg.long_term_capacity = 10;
  SpatioTemporalMemory both(cfg), first(cfg), second(cfg);
  at::manual_seed(5);
  bool saw_padding = false;
  for (int64_t f = 0; f < 40; ++f) {
    const at::Tensor pos = at::cat({at::rand({1, 9, 3}) * 5, at::rand({1, 9, 3}) * 3});
    const at::Tensor keys = at::randn({2, 9, 4}), values = at::randn({2, 9, 4});
    both.add_frame(keys, values, pos, f, {3, 3});
    first.add_frame(keys.narrow(0, 0, 1), values.narrow(0, 0, 1), pos.narrow(0, 0, 1), f, {3, 3});
    second.add_frame(keys.narrow(0, 1, 1), values.narrow(0, 1, 1), pos.narrow(0, 1, 1), f, {3, 3});
    SpatioTemporalMemory* single[2] = {&first, &second};
    at::Tensor inc = at::zeros({2, both.padded_size()});
    for (int b = 0; b < 2; ++b) {
      const int64_t n = single[b]->padded_size();
      ASSERT_EQ(both.total_sizes()[b], n);
      EXPECT_EQ(both.v_scene()[b], single[b]->v_scene()[0]);
      EXPECT_TRUE(both.keys()[b].narrow(0, 0, n).equal(single[b]->keys()[0]));
      EXPECT_TRUE(both.values()[b].narrow(0, 0, n).equal(single[b]->values()[0]));
      EXPECT_TRUE(both.positions()[b].narrow(0, 0, n).equal(single[b]->positions()[0]));
      EXPECT_TRUE(both.frame_indices()[b].narrow(0, 0, n).equal(single[b]->frame_indices()[0]));
      EXPECT_TRUE(both.attention()[b].narrow(0, 0, n).equal(single[b]->attention()[0]));
      const int64_t pad = both.padded_size() - n;
      saw_padding = saw_padding || pad > 0;
      EXPECT_FALSE(both.valid_mask()[b].narrow(0, n, pad).any().item<bool>());
      EXPECT_TRUE(both.valid_mask()[b].narrow(0, 0, n).all().item<bool>());
      EXPECT_TRUE((both.frame_indices()[b].narrow(0, n, pad) == -1).all().item<bool>());
      EXPECT_EQ(both.keys()[b].narrow(0, n, pad).abs().sum().item<double>(), 0.0);
      const at::Tensor inc_b = at::rand({1, n});
      single[b]->add_attention(inc_b);
      inc[b].narrow(0, 0, n).copy_(inc_b[0]);
    }
    both.add_attention(inc);
  }
  EXPECT_TRUE(saw_padding);
}

// A payload travels with its token through the short-term window, the move to
// long-term, voxel pruning and the capacity: with payload = [key, value] every
// gathered row equals the token's key and value, per stream, padding included.
TEST(SpatioTemporalMemory, PayloadTravelsWithItsToken) {
  SpatioTemporalMemoryConfig cfg;
  cfg.short_term_frames = 2;
  cfg.long_term_capacity = 12;
  SpatioTemporalMemory mem(cfg);
  at::manual_seed(6);
  bool saw_both_parts = false;
  for (int64_t f = 0; f < 60; ++f) {
    const at::Tensor pos = at::cat({at::rand({1, 9, 3}) * 5, at::rand({1, 9, 3}) * 2});
    const at::Tensor keys = at::randn({2, 9, 4}), values = at::randn({2, 9, 4});
    mem.add_frame(keys, values, pos, f, {3, 3}, at::cat({keys, values}, 2));
    ASSERT_TRUE(mem.has_payload());
    const int64_t S = mem.padded_size();
    // Every token once, in reverse, and a padded row pointing at token 0.
    at::Tensor index = at::arange(S - 1, -1, -1, at::kLong).repeat({2, 1});
    const std::vector<int64_t> total = mem.total_sizes();
    for (int64_t b = 0; b < 2; ++b) {
      index[b].narrow(0, 0, S - total[b]).fill_(0);
    }
    const at::Tensor got = mem.gather_payload(index);
    ASSERT_EQ(got.sizes(), (at::IntArrayRef{2, S, 8}));
    const at::Tensor want = at::cat(
        {long3r::gather_tokens(mem.keys(), index), long3r::gather_tokens(mem.values(), index)}, 2);
    ASSERT_TRUE(got.equal(want)) << "frame " << f;
    saw_both_parts = saw_both_parts || (mem.long_sizes()[0] > 0 && mem.long_sizes()[1] > 0);
    mem.add_attention(at::rand({2, S}) * mem.valid_mask());
  }
  EXPECT_TRUE(saw_both_parts);
  EXPECT_EQ(mem.long_sizes()[0], 12);  // pruning and capacity did act

  // The payload is all or nothing until reset(); an index must be in range.
  const at::Tensor k = at::randn({2, 9, 4}), pos = at::rand({2, 9, 3});
  EXPECT_THROW(mem.add_frame(k, k, pos, 60, {3, 3}), c10::Error);
  EXPECT_THROW(mem.add_frame(k, k, pos, 60, {3, 3}, at::randn({2, 9, 5})), c10::Error);
  EXPECT_THROW(mem.gather_payload(at::full({2, 1}, mem.padded_size(), at::kLong)), c10::Error);
  mem.reset();
  EXPECT_FALSE(mem.has_payload());
  mem.add_frame(k, k, pos, 0, {3, 3});
  EXPECT_THROW(mem.gather_payload(at::zeros({2, 1}, at::kLong)), c10::Error);
}

// read() is memory_gating over the whole memory plus add_attention.
TEST(SpatioTemporalMemory, ReadGatesAndAccumulatesAttention) {
  SpatioTemporalMemoryConfig cfg;
  cfg.short_term_frames = 2;
  cfg.tau = 1e-2;
  SpatioTemporalMemory mem(cfg);
  at::manual_seed(8);
  const int64_t c = 8;
  long3r::GatingNorms norms;
  for (long3r::LayerNormParams* n : {&norms.q, &norms.k, &norms.v}) {
    *n = {at::rand({c}) * 2 + 0.5, at::randn({c}) * 0.1, 1e-5};
  }
  const at::Tensor q = at::randn({1, 4, c}), feat = at::randn({1, 4, c});
  const long3r::GatingResult empty = mem.read(q, feat, norms);
  EXPECT_TRUE(empty.fused.equal(feat));
  for (int64_t f = 0; f < 5; ++f) {
    mem.add_frame(at::randn({1, 4, c}), at::randn({1, 4, c}), at::rand({1, 4, 3}), f, {2, 2});
  }
  const at::Tensor before = mem.attention();
  const long3r::GatingResult r = mem.read(q, feat, norms);
  const long3r::GatingResult expected =
      long3r::memory_gating(q, mem.keys(), mem.values(), feat, norms, 1e-2, false);
  EXPECT_TRUE(r.fused.equal(expected.fused));
  EXPECT_TRUE(r.relevant_mask.equal(expected.relevant_mask));
  EXPECT_TRUE(mem.attention().allclose(before + expected.attention_increment));
  EXPECT_GT(expected.attention_increment.sum().item<double>(), 0.0);
}

// Training keeps the graph through moves and pruning; inference stores detached
// tokens; the memory works under c10::InferenceMode.
TEST(SpatioTemporalMemory, TrainingKeepsGraphInferenceDetaches) {
  SpatioTemporalMemoryConfig cfg;
  cfg.short_term_frames = 1;
  std::vector<at::Tensor> leaves;
  SpatioTemporalMemory train(cfg), infer(cfg);
  train.set_training(true);
  for (int64_t f = 0; f < 3; ++f) {
    leaves.push_back(at::randn({1, 4, 4}).requires_grad_(true));
    const at::Tensor pos = grid_positions(2, 2, 1.0, 1.0, frame_origin(f == 2 ? 4 : 0));
    train.add_frame(leaves.back(), leaves.back() * 2, pos, f, {2, 2});
    infer.add_frame(leaves.back(), leaves.back() * 2, pos, f, {2, 2});
  }
  // Frames 0 and 1 share a voxel: one token of them is left in long-term.
  ASSERT_EQ(train.long_sizes(), (std::vector<int64_t>{1}));
  EXPECT_FALSE(infer.keys().requires_grad());
  EXPECT_FALSE(infer.values().requires_grad());
  ASSERT_TRUE(train.keys().requires_grad());
  (train.keys().sum() + train.values().sum()).backward();
  // Short-term frame 2: d/dkey of (key + 2 key) = 3 for all 16 entries. Long-term:
  // frame 1's last token wins the shared voxel (all attention 0, newest token).
  EXPECT_EQ(leaves[2].grad().sum().item<double>(), 3.0 * 16);
  ASSERT_TRUE(leaves[1].grad().defined());
  EXPECT_TRUE(leaves[1].grad()[0][3].equal(at::full({4}, 3.0f)));
  EXPECT_EQ(leaves[1].grad().sum().item<double>(), 3.0 * 4);
  EXPECT_FALSE(leaves[0].grad().defined() && leaves[0].grad().abs().sum().item<double>() > 0);

  c10::InferenceMode guard;
  SpatioTemporalMemory mem(cfg);
  for (int64_t f = 0; f < 4; ++f) {
    mem.add_frame(at::randn({1, 4, 4}), at::randn({1, 4, 4}),
                  grid_positions(2, 2, 1.0, 1.0, frame_origin(3 * f)), f, {2, 2});
    mem.add_attention(at::rand({1, mem.padded_size()}));
  }
  EXPECT_EQ(mem.long_sizes(), (std::vector<int64_t>{3}));
  EXPECT_EQ(mem.short_size(), 4);
}

// Ablation policy: Spann3R's rules instead of voxels: the long-term tokens
// with the highest attention per frame of age are kept.
TEST(SpatioTemporalMemory, Spann3rPolicyKeepsAttentionPerAgeWithoutVoxels) {
  SpatioTemporalMemoryConfig cfg;
  cfg.short_term_frames = 1;
  cfg.long_term_capacity = 4;  // two frames of P = 2 tokens
  cfg.long_term_policy = long3r::LongTermPolicy::kSpann3r;
  cfg.sim_thresh = 1.0;  // no skip: keys are random here anyway
  SpatioTemporalMemory mem(cfg);
  const at::Tensor pos = at::zeros({1, 2, 3});
  at::manual_seed(3);
  // Frame 0 gets attention 3 per token, frame 1 gets 1, frame 2 gets 1.5.
  const double given[] = {3.0, 1.0, 1.5};
  for (int64_t f = 0; f < 3; ++f) {
    mem.add_frame(at::randn({1, 2, 8}), at::randn({1, 2, 8}), pos, f, {2, 1});
    // The newest frame is the short-term window, first in the layout.
    at::Tensor inc = at::zeros({1, mem.padded_size()});
    inc[0][0] = given[f];
    inc[0][1] = given[f];
    mem.add_attention(inc);
  }
  // Frame 3 pushes frame 2 out: long-term holds frames 0, 1, 2 before the prune.
  // At frame 3 the scores are 3/3 = 1, 1/2 = .5, 1.5/1 = 1.5: frames 2 and 0 stay.
  mem.add_frame(at::randn({1, 2, 8}), at::randn({1, 2, 8}), pos, 3, {2, 1});
  ASSERT_EQ(mem.long_sizes(), (std::vector<int64_t>{4}));
  const at::Tensor frames = mem.frame_indices()[0].narrow(0, mem.short_size(), 4);
  std::set<int64_t> kept;
  for (int64_t i = 0; i < 4; ++i) kept.insert(frames[i].item<int64_t>());
  EXPECT_EQ(kept, (std::set<int64_t>{0, 2}));
}

TEST(SpatioTemporalMemory, Spann3rPolicySkipsFramesSimilarToShortTerm) {
  SpatioTemporalMemoryConfig cfg;
  cfg.short_term_frames = 2;
  cfg.long_term_policy = long3r::LongTermPolicy::kSpann3r;
  cfg.sim_thresh = 0.95;
  SpatioTemporalMemory mem(cfg);
  at::manual_seed(5);
  const at::Tensor k = at::randn({1, 4, 8});
  const at::Tensor pos = at::rand({1, 4, 3});
  mem.add_frame(k, at::randn({1, 4, 8}), pos, 0, {2, 2});
  EXPECT_FALSE(mem.last_frame_skipped());
  // Same keys up to scale: cosine similarity 1 -> skipped, nothing added.
  mem.add_frame(k * 2.0, at::randn({1, 4, 8}), pos, 1, {2, 2});
  EXPECT_TRUE(mem.last_frame_skipped());
  EXPECT_EQ(mem.frames_added(), 1);
  EXPECT_EQ(mem.short_size(), 4);
  // Unrelated keys are added.
  mem.add_frame(at::randn({1, 4, 8}), at::randn({1, 4, 8}), pos, 2, {2, 2});
  EXPECT_FALSE(mem.last_frame_skipped());
  EXPECT_EQ(mem.short_size(), 8);
  // The paper's policy never skips.
  SpatioTemporalMemoryConfig paper;
  paper.short_term_frames = 2;
  SpatioTemporalMemory pm(paper);
  pm.add_frame(k, at::randn({1, 4, 8}), pos, 0, {2, 2});
  pm.add_frame(k, at::randn({1, 4, 8}), pos, 1, {2, 2});
  EXPECT_FALSE(pm.last_frame_skipped());
  EXPECT_EQ(pm.short_size(), 8);
}

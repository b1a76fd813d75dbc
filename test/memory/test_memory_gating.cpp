// Tests of LONG3R's memory gating (include/long3r/memory/memory_gating.hpp) against
// hand-built cases and a plain-loop reference.
#include <ATen/ATen.h>
#include <c10/core/InferenceMode.h>
#include <gtest/gtest.h>

#include <cmath>
#include <set>
#include <vector>

#include "long3r/memory/memory_gating.hpp"

namespace {

using long3r::GatingNorms;
using long3r::GatingResult;
using long3r::LayerNormParams;

// Row i of the 8x8 Sylvester Hadamard matrix; rows 1..7 have zero mean.
std::vector<float> hadamard_row(int i) {
  std::vector<float> r(8);
  for (int j = 0; j < 8; ++j) r[j] = (__builtin_popcount(i & j) % 2 == 0) ? 1.f : -1.f;
  return r;
}

at::Tensor stack_rows(const std::vector<std::vector<float>>& rows) {
  std::vector<at::Tensor> t;
  for (const auto& r : rows) t.push_back(at::tensor(r));
  return at::stack(t, 0);
}

LayerNormParams constant_norm(int64_t c, float gain, float bias = 0.f) {
  return {at::full({c}, gain), at::full({c}, bias), 1e-5};
}

// Plain-loop reference of the gating rules for stream b (double precision).
struct Reference {
  std::vector<std::vector<double>> w, gated;  // [P][S]
  std::vector<bool> relevant;                 // [S]
  std::vector<std::vector<double>> fused;     // [P][C]
  std::vector<double> increment;              // [S]
};

std::vector<double> layer_norm_row(const at::Tensor& x, const LayerNormParams& n) {
  const int64_t c = x.size(0);
  double mean = 0, var = 0;
  for (int64_t i = 0; i < c; ++i) mean += x[i].item<double>();
  mean /= c;
  for (int64_t i = 0; i < c; ++i) var += std::pow(x[i].item<double>() - mean, 2);
  var /= c;
  std::vector<double> out(c);
  for (int64_t i = 0; i < c; ++i) {
    out[i] = (x[i].item<double>() - mean) / std::sqrt(var + n.eps) * n.weight[i].item<double>() +
             n.bias[i].item<double>();
  }
  return out;
}

Reference reference(const at::Tensor& q, const at::Tensor& k, const at::Tensor& v,
                    const at::Tensor& f, const GatingNorms& norms, double tau, bool threshold,
                    int64_t b) {
  const int64_t p_count = q.size(1), s_count = k.size(1), c = q.size(2);
  std::vector<std::vector<double>> qn, kn, vn;
  for (int64_t p = 0; p < p_count; ++p) qn.push_back(layer_norm_row(q[b][p], norms.q));
  for (int64_t s = 0; s < s_count; ++s) kn.push_back(layer_norm_row(k[b][s], norms.k));
  for (int64_t s = 0; s < s_count; ++s) vn.push_back(layer_norm_row(v[b][s], norms.v));
  Reference r;
  r.relevant.assign(s_count, false);
  r.increment.assign(s_count, 0.0);
  for (int64_t p = 0; p < p_count; ++p) {
    std::vector<double> logit(s_count);
    double mx = -1e300;
    for (int64_t s = 0; s < s_count; ++s) {
      double dot = 0;
      for (int64_t i = 0; i < c; ++i) dot += qn[p][i] * kn[s][i];
      logit[s] = dot / std::sqrt(static_cast<double>(c));
      mx = std::max(mx, logit[s]);
    }
    double z = 0;
    for (double l : logit) z += std::exp(l - mx);
    std::vector<double> w(s_count), g(s_count);
    double kept = 0;
    for (int64_t s = 0; s < s_count; ++s) {
      w[s] = std::exp(logit[s] - mx) / z;
      g[s] = (threshold && w[s] < tau) ? 0.0 : w[s];
      kept += g[s];
      if (w[s] > tau) r.relevant[s] = true;
    }
    if (threshold && kept > 0) {
      for (double& x : g) x /= kept;
    }
    std::vector<double> out(c);
    for (int64_t i = 0; i < c; ++i) {
      out[i] = f[b][p][i].item<double>();
      for (int64_t s = 0; s < s_count; ++s) out[i] += g[s] * vn[s][i];
    }
    for (int64_t s = 0; s < s_count; ++s) r.increment[s] += g[s];
    r.w.push_back(w);
    r.gated.push_back(g);
    r.fused.push_back(out);
  }
  return r;
}

void expect_matches(const GatingResult& got, const Reference& ref, int64_t b, double tol) {
  const int64_t p_count = got.weights.size(1), s_count = got.weights.size(2);
  for (int64_t p = 0; p < p_count; ++p) {
    for (int64_t s = 0; s < s_count; ++s) {
      EXPECT_NEAR(got.weights[b][p][s].item<double>(), ref.w[p][s], tol) << p << "," << s;
      EXPECT_NEAR(got.gated_weights[b][p][s].item<double>(), ref.gated[p][s], tol) << p << "," << s;
    }
    for (int64_t i = 0; i < got.fused.size(2); ++i) {
      EXPECT_NEAR(got.fused[b][p][i].item<double>(), ref.fused[p][i], tol) << p << "," << i;
    }
  }
  for (int64_t s = 0; s < s_count; ++s) {
    EXPECT_NEAR(got.attention_increment[b][s].item<double>(), ref.increment[s], tol) << s;
  }
}

// Relevant set of stream b as read from the mask and from the index form.
std::set<int64_t> relevant_from_mask(const GatingResult& r, int64_t b) {
  std::set<int64_t> out;
  for (int64_t s = 0; s < r.relevant_mask.size(1); ++s) {
    if (r.relevant_mask[b][s].item<bool>()) out.insert(s);
  }
  return out;
}
std::set<int64_t> relevant_from_index(const GatingResult& r, int64_t b) {
  std::set<int64_t> out;
  for (int64_t i = 0; i < r.relevant_index.size(1); ++i) {
    if (r.relevant_valid[b][i].item<bool>()) out.insert(r.relevant_index[b][i].item<int64_t>());
  }
  return out;
}
// {s : max_p W[b,p,s] > tau} straight from the returned W.
std::set<int64_t> relevant_from_weights(const GatingResult& r, int64_t b, double tau) {
  std::set<int64_t> out;
  for (int64_t s = 0; s < r.weights.size(2); ++s) {
    for (int64_t p = 0; p < r.weights.size(1); ++p) {
      if (r.weights[b][p][s].item<double>() > tau) {
        out.insert(s);
        break;
      }
    }
  }
  return out;
}

struct RandomCase {
  at::Tensor q, k, v, f;
  GatingNorms norms;
};

RandomCase random_case(int64_t b, int64_t p, int64_t s, int64_t c, double logit_gain,
                       uint64_t seed) {
  at::manual_seed(seed);
  RandomCase rc;
  rc.q = at::randn({b, p, c});
  rc.k = at::randn({b, s, c});
  rc.v = at::randn({b, s, c});
  rc.f = at::randn({b, p, c});
  rc.norms.q = {at::rand({c}) * logit_gain + 0.5, at::randn({c}) * 0.1, 1e-5};
  rc.norms.k = {at::rand({c}) * logit_gain + 0.5, at::randn({c}) * 0.1, 1e-6};
  rc.norms.v = {at::rand({c}) + 0.5, at::randn({c}), 1e-5};
  return rc;
}

}  // namespace

// Queries and keys are Hadamard rows, so the logits are known exactly: a query
// matching a key gets logit A, orthogonal keys 0, and key 5 = h1 + h2 gets
// A / sqrt(2) from query h1. With A = 20: W[q0, k0] ~ 0.997, W[q0, k5] ~ 2.8e-3,
// W[q0, k1..4] ~ 2e-9, so R = {0, 2, 5} for stream 0; stream 1 (both queries h4)
// has R = {3}.
TEST(MemoryGating, RelevantSetKnownByConstruction) {
  const int64_t c = 8;
  const double a = 20.0;
  const float gain = static_cast<float>(std::sqrt(a / std::sqrt(8.0)));
  std::vector<float> k5(8);
  for (int j = 0; j < 8; ++j) k5[j] = hadamard_row(1)[j] + hadamard_row(2)[j];
  const at::Tensor keys1 = stack_rows(
      {hadamard_row(1), hadamard_row(2), hadamard_row(3), hadamard_row(4), hadamard_row(5), k5});
  const at::Tensor keys = at::stack({keys1, keys1});
  const at::Tensor queries = at::stack({stack_rows({hadamard_row(1), hadamard_row(3)}),
                                        stack_rows({hadamard_row(4), hadamard_row(4)})});
  at::manual_seed(1);
  const at::Tensor values = at::randn({2, 6, c});
  const at::Tensor features = at::randn({2, 2, c});
  GatingNorms norms{constant_norm(c, gain), constant_norm(c, gain), constant_norm(c, 1.f)};
  const double tau = 5e-4;

  const GatingResult r =
      long3r::memory_gating(queries, keys, values, features, norms, tau, /*training=*/false);

  ASSERT_EQ(r.weights.sizes(), (std::vector<int64_t>{2, 2, 6}));
  EXPECT_EQ(relevant_from_mask(r, 0), (std::set<int64_t>{0, 2, 5}));
  EXPECT_EQ(relevant_from_mask(r, 1), (std::set<int64_t>{3}));
  for (int64_t b = 0; b < 2; ++b) {
    EXPECT_EQ(relevant_from_mask(r, b), relevant_from_weights(r, b, tau));
    EXPECT_EQ(relevant_from_index(r, b), relevant_from_mask(r, b));
    expect_matches(r, reference(queries, keys, values, features, norms, tau, true, b), b, 1e-5);
  }
  // Padded index form: ascending, left-aligned, padding index 0.
  ASSERT_EQ(r.relevant_index.sizes(), (std::vector<int64_t>{2, 3}));
  const at::Tensor flat = r.relevant_index.contiguous();
  const std::vector<int64_t> index(flat.data_ptr<int64_t>(), flat.data_ptr<int64_t>() + 6);
  EXPECT_EQ(index, (std::vector<int64_t>{0, 2, 5, 3, 0, 0}));
  EXPECT_TRUE(r.relevant_valid.equal(at::tensor({1, 1, 1, 1, 0, 0}).to(at::kBool).reshape({2, 3})));
  EXPECT_EQ(r.relevant_count[0].item<int64_t>(), 3);
  EXPECT_EQ(r.relevant_count[1].item<int64_t>(), 1);
  // The expected magnitudes of the construction.
  EXPECT_NEAR(r.weights[0][0][5].item<double>(), std::exp(-a + a / std::sqrt(2.0)), 1e-4);
  EXPECT_LT(r.weights[0][0][1].item<double>(), 1e-8);
  EXPECT_EQ(r.gated_weights[0][0][1].item<double>(), 0.0);

  // K_R via gather_tokens.
  const at::Tensor k_r = long3r::gather_tokens(keys, r.relevant_index);
  ASSERT_EQ(k_r.sizes(), (std::vector<int64_t>{2, 3, c}));
  EXPECT_TRUE(k_r[0][1].equal(keys[0][2]));
  EXPECT_TRUE(k_r[0][2].equal(keys[0][5]));
  EXPECT_TRUE(k_r[1][0].equal(keys[1][3]));
}

// Random memories with sharp attention so that the threshold cuts: R, W', F^fuse
// and the increment follow the plain-loop reference, and every row of W' with a
// surviving entry sums to 1.
TEST(MemoryGating, ThresholdAndRenormalisationMatchReference) {
  const RandomCase rc = random_case(2, 5, 40, 16, 3.0, 7);
  const double tau = 5e-3;
  const GatingResult r = long3r::memory_gating(rc.q, rc.k, rc.v, rc.f, rc.norms, tau, false);
  int64_t cut = 0, kept = 0;
  for (int64_t b = 0; b < 2; ++b) {
    EXPECT_EQ(relevant_from_mask(r, b), relevant_from_weights(r, b, tau));
    EXPECT_EQ(relevant_from_index(r, b), relevant_from_mask(r, b));
    const Reference ref = reference(rc.q, rc.k, rc.v, rc.f, rc.norms, tau, true, b);
    expect_matches(r, ref, b, 1e-5);
    for (int64_t s = 0; s < 40; ++s) {
      EXPECT_EQ(r.relevant_mask[b][s].item<bool>(), static_cast<bool>(ref.relevant[s]));
    }
    for (int64_t p = 0; p < 5; ++p) {
      EXPECT_NEAR(r.gated_weights[b][p].sum().item<double>(), 1.0, 1e-5);
      for (int64_t s = 0; s < 40; ++s) {
        (r.weights[b][p][s].item<double>() < tau ? cut : kept) += 1;
      }
    }
  }
  // The case must exercise both sides of the threshold.
  EXPECT_GT(cut, 0);
  EXPECT_GT(kept, 0);
  EXPECT_LT(r.relevant_count.sum().item<int64_t>(), 80);
}

// tau = 0 (and training mode whatever tau) is plain attention over the whole memory.
TEST(MemoryGating, ZeroThresholdIsPlainAttention) {
  const RandomCase rc = random_case(2, 4, 30, 8, 1.0, 11);
  const GatingResult inference =
      long3r::memory_gating(rc.q, rc.k, rc.v, rc.f, rc.norms, 0.0, false);
  const GatingResult training =
      long3r::memory_gating(rc.q, rc.k, rc.v, rc.f, rc.norms, 5e-4, /*training=*/true);
  for (int64_t b = 0; b < 2; ++b) {
    const Reference plain = reference(rc.q, rc.k, rc.v, rc.f, rc.norms, 0.0, false, b);
    expect_matches(inference, plain, b, 1e-5);
    expect_matches(training, plain, b, 1e-5);
  }
  EXPECT_TRUE(inference.relevant_mask.all().item<bool>());
  EXPECT_TRUE(training.relevant_mask.all().item<bool>());
  EXPECT_EQ(training.relevant_index.sizes(), (std::vector<int64_t>{2, 30}));
  EXPECT_TRUE(training.relevant_index[1].equal(at::arange(30)));
}

// A row whose weights all fall below tau reads nothing (no NaN): 4000 identical
// keys give W = 1/4000 < 5e-4 everywhere.
TEST(MemoryGating, RowBelowThresholdReadsNothing) {
  const int64_t c = 8, s = 4000;
  at::manual_seed(3);
  const at::Tensor q = at::randn({1, 2, c});
  const at::Tensor k = at::randn({1, 1, c}).expand({1, s, c}).contiguous();
  const at::Tensor v = at::randn({1, s, c});
  const at::Tensor f = at::randn({1, 2, c});
  const GatingNorms norms{constant_norm(c, 1.f), constant_norm(c, 1.f), constant_norm(c, 1.f)};
  const GatingResult r = long3r::memory_gating(q, k, v, f, norms, 5e-4, false);
  EXPECT_NEAR(r.weights[0][0][17].item<double>(), 1.0 / s, 1e-9);
  EXPECT_FALSE(r.relevant_mask.any().item<bool>());
  EXPECT_EQ(r.relevant_index.sizes(), (std::vector<int64_t>{1, 0}));
  EXPECT_TRUE(r.fused.equal(f));
  EXPECT_EQ(r.attention_increment.abs().sum().item<double>(), 0.0);
}

// Padded memory tokens are ignored: a stream's result equals gating over its
// unpadded memory alone, padding gets W = 0, is never relevant, and gets no
// increment, in inference and in training.
TEST(MemoryGating, PaddingIsIgnored) {
  const RandomCase rc = random_case(2, 3, 12, 8, 3.0, 5);
  at::Tensor valid = at::ones({2, 12}, at::kBool);
  valid[1].narrow(0, 9, 3).fill_(false);
  const int64_t short_len = 9;
  for (const bool training : {false, true}) {
    const GatingResult r =
        long3r::memory_gating(rc.q, rc.k, rc.v, rc.f, rc.norms, 1e-2, training, valid);
    const GatingResult alone =
        long3r::memory_gating(rc.q.narrow(0, 1, 1), rc.k.narrow(0, 1, 1).narrow(1, 0, short_len),
                              rc.v.narrow(0, 1, 1).narrow(1, 0, short_len), rc.f.narrow(0, 1, 1),
                              rc.norms, 1e-2, training);
    EXPECT_TRUE(r.fused[1].allclose(alone.fused[0], 1e-5, 1e-6)) << training;
    EXPECT_TRUE(r.weights[1].narrow(1, 0, short_len).allclose(alone.weights[0], 1e-5, 1e-7));
    EXPECT_EQ(r.weights[1].narrow(1, short_len, 3).abs().sum().item<double>(), 0.0);
    EXPECT_FALSE(r.relevant_mask[1].narrow(0, short_len, 3).any().item<bool>());
    EXPECT_EQ(r.attention_increment[1].narrow(0, short_len, 3).abs().sum().item<double>(), 0.0);
    EXPECT_TRUE(r.relevant_mask[1].narrow(0, 0, short_len).equal(alone.relevant_mask[0]));
    if (training) {
      EXPECT_TRUE(r.relevant_mask.equal(valid));
    }
  }
}

// An empty memory reads nothing.
TEST(MemoryGating, EmptyMemory) {
  const RandomCase rc = random_case(2, 3, 0, 8, 1.0, 2);
  const GatingResult r = long3r::memory_gating(rc.q, rc.k, rc.v, rc.f, rc.norms, 5e-4, false);
  EXPECT_TRUE(r.fused.equal(rc.f));
  EXPECT_EQ(r.weights.sizes(), (std::vector<int64_t>{2, 3, 0}));
  EXPECT_EQ(r.relevant_index.sizes(), (std::vector<int64_t>{2, 0}));
  EXPECT_EQ(r.attention_increment.sizes(), (std::vector<int64_t>{2, 0}));
}

// Training mode keeps everything differentiable.
TEST(MemoryGating, GradientFlowsInTraining) {
  RandomCase rc = random_case(2, 4, 10, 8, 1.0, 9);
  std::vector<at::Tensor> leaves = {
      rc.q,           rc.k, rc.v, rc.f, rc.norms.q.weight, rc.norms.k.weight, rc.norms.v.weight,
      rc.norms.v.bias};
  for (at::Tensor& t : leaves) t.requires_grad_(true);
  const GatingResult r = long3r::memory_gating(rc.q, rc.k, rc.v, rc.f, rc.norms, 5e-4, true);
  ASSERT_TRUE(r.fused.requires_grad());
  ASSERT_TRUE(r.attention_increment.requires_grad());
  const at::Tensor probe = at::randn(r.fused.sizes());
  (r.fused * probe).sum().backward();
  for (const at::Tensor& t : leaves) {
    ASSERT_TRUE(t.grad().defined());
    EXPECT_TRUE(t.grad().isfinite().all().item<bool>());
    EXPECT_GT(t.grad().abs().sum().item<double>(), 0.0);
  }
}

// The same results under c10::InferenceMode as with autograd.
TEST(MemoryGating, InferenceModeMatchesAutograd) {
  const RandomCase rc = random_case(1, 4, 20, 8, 2.0, 4);
  const GatingResult ref = long3r::memory_gating(rc.q, rc.k, rc.v, rc.f, rc.norms, 1e-2, false);
  c10::InferenceMode guard;
  const GatingResult r = long3r::memory_gating(rc.q, rc.k, rc.v, rc.f, rc.norms, 1e-2, false);
  EXPECT_TRUE(r.fused.equal(ref.fused));
  EXPECT_TRUE(r.relevant_index.equal(ref.relevant_index));
  EXPECT_TRUE(r.attention_increment.equal(ref.attention_increment));
}

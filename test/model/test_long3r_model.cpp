// Tests of the LONG3R model (include/long3r/model/network/long3r_model.hpp and
// src/long3r/model/network/long3r_modules.hpp): the memory block against a hand
// computation, the stream protocol (latency, flush from head 2, reset,
// determinism, batching), the memory bound on a long stream, gradients in
// training mode, the strict checkpoint round trip, and the LONG3R config.
#include <ATen/ATen.h>
#include <ATen/Context.h>
#include <c10/core/InferenceMode.h>
#include <gtest/gtest.h>
#include <torch/nn/module.h>

#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "long3r/memory/memory_gating.hpp"
#include "long3r/model/loading/safetensors.hpp"
#include "long3r/model/network/long3r_model.hpp"
#include "long3r/model/network/long3r_modules.hpp"
#include "long3r/model/network/model_config.hpp"
#include "support/test_support.hpp"

namespace {

namespace m = long3r::model;

// The input frames: test::pixel_wave_frame (its default wave), 64 x 64 unless
// told; `phase` distinguishes streams.
at::Tensor frame(int64_t t, int64_t H = 64, int64_t W = 64, double phase = 0.0) {
  long3r::test::PixelWave wave;
  wave.phase = phase;
  return long3r::test::pixel_wave_frame(t, H, W, wave);
}

constexpr auto tiny = long3r::test::tiny_long3r_config;

void copy_weights(long3r::Long3rModel& from, long3r::Long3rModel& to) {
  std::map<std::string, at::Tensor> t;
  for (const auto& kv : from.module().named_parameters()) t[kv.key()] = kv.value().detach();
  to.load_weights(t, "copy");
}

std::vector<long3r::StreamOutput> run_stream(long3r::StreamingModel& model, int64_t n,
                                             double phase = 0.0) {
  std::vector<long3r::StreamOutput> out;
  for (int64_t t = 0; t < n; ++t) {
    auto o = model.push(frame(t, 64, 64, phase));
    if (o) out.push_back(*o);
  }
  auto last = model.flush();
  if (last) out.push_back(*last);
  return out;
}

void expect_same(const std::vector<long3r::StreamOutput>& a,
                 const std::vector<long3r::StreamOutput>& b) {
  ASSERT_EQ(a.size(), b.size());
  for (std::size_t i = 0; i < a.size(); ++i) {
    EXPECT_EQ(a[i].frame_index, b[i].frame_index);
    EXPECT_TRUE(at::equal(a[i].pts3d, b[i].pts3d)) << "frame " << i;
    EXPECT_TRUE(at::equal(a[i].conf, b[i].conf)) << "frame " << i;
  }
}

void randomize_norms(torch::nn::Module& module) {
  for (auto& kv : module.named_parameters()) {
    if (kv.key().find("norm") == std::string::npos) continue;
    at::NoGradGuard g;
    kv.value().copy_(at::randn_like(kv.value()) * 0.3 +
                     (kv.key().find("weight") != std::string::npos ? 1.0 : 0.0));
  }
}

// Layer norm by hand.
at::Tensor ln(const at::Tensor& x, const long3r::model::LayerNorm& n) {
  const at::Tensor mu = x.mean(-1, true);
  const at::Tensor var = (x - mu).pow(2).mean(-1, true);
  return (x - mu) / at::sqrt(var + n->options.eps()) * n->weight + n->bias;
}

at::Tensor lin(const at::Tensor& x, const torch::nn::Linear& l) {
  return at::matmul(x, l->weight.t()) + l->bias;
}

}  // namespace

// With tau = 0 every memory token is relevant, so the memory block's
// cross-attention is a plain attention over the whole memory.
TEST(Long3rModel, MemoryBlockTauZeroEqualsAttentionOverWholeMemory) {
  at::manual_seed(3);
  const int64_t C = 16, Cm = 24, heads = 2, S = 37, P = 12;
  m::MemoryBlock block(C, Cm, heads, 4 * C, 1e-6, 1e-6);
  randomize_norms(*block);
  c10::InferenceMode guard;
  const at::Tensor x = at::randn({1, P, C});
  const at::Tensor keys = at::randn({1, S, Cm}), values = at::randn({1, S, Cm});
  const at::Tensor query = at::randn({1, P, Cm}), feats = at::randn({1, P, Cm});
  const long3r::GatingNorms norms{{at::ones({Cm}), at::zeros({Cm}), 1e-5},
                                  {at::ones({Cm}), at::zeros({Cm}), 1e-5},
                                  {at::ones({Cm}), at::zeros({Cm}), 1e-5}};
  const long3r::GatingResult g =
      long3r::memory_gating(query, keys, values, feats, norms, /*tau=*/0.0, /*training=*/false);
  ASSERT_EQ(g.relevant_index.size(1), S);
  const at::Tensor kr = long3r::gather_tokens(keys, g.relevant_index);
  const at::Tensor vr = long3r::gather_tokens(values, g.relevant_index);
  const m::RopeTable rope;  // no RoPE: the self-attention part is shared anyway
  const at::Tensor got = block(x, rope, kr, vr, at::Tensor());

  // Hand computation over all memory tokens.
  at::Tensor h = x + block->attn(block->norm1(x), rope);
  const int64_t Dh = C / heads;
  const at::Tensor q = lin(ln(h, block->norm2), block->cross_attn->projq);
  const at::Tensor k = lin(ln(keys, block->norm_mem_k), block->cross_attn->projk);
  const at::Tensor v = lin(ln(values, block->norm_mem_v), block->cross_attn->projv);
  std::vector<at::Tensor> per_head;
  for (int64_t i = 0; i < heads; ++i) {
    const at::Tensor qi = q.narrow(2, i * Dh, Dh), ki = k.narrow(2, i * Dh, Dh);
    const at::Tensor a = at::softmax(at::matmul(qi, ki.transpose(1, 2)) / std::sqrt(Dh), -1);
    per_head.push_back(at::matmul(a, v.narrow(2, i * Dh, Dh)));
  }
  h = h + lin(at::cat(per_head, -1), block->cross_attn->proj);
  const at::Tensor n3 = ln(h, block->norm3);
  const at::Tensor want = h + lin(at::gelu(lin(n3, block->mlp->fc1)), block->mlp->fc2);
  EXPECT_TRUE(at::allclose(got, want, 1e-4, 1e-5)) << (got - want).abs().max();

  // No memory: zero cross-attention residual.
  const at::Tensor h0 = x + block->attn(block->norm1(x), rope);
  const at::Tensor none = h0 + block->mlp(block->norm3(h0));
  EXPECT_TRUE(at::allclose(block(x, rope, at::Tensor(), at::Tensor(), at::Tensor()), none));
  EXPECT_TRUE(at::allclose(
      block(x, rope, keys.narrow(1, 0, 0), values.narrow(1, 0, 0), at::Tensor()), none));

  // Key padding: stream 0 sees only its first 20 tokens, stream 1 none.
  const at::Tensor valid = at::arange(S).lt(20).view({1, S}).repeat({2, 1});
  valid[1].fill_(false);
  const at::Tensor batched =
      block(x.repeat({2, 1, 1}), rope, keys.repeat({2, 1, 1}), values.repeat({2, 1, 1}), valid);
  const at::Tensor first20 =
      block(x, rope, keys.narrow(1, 0, 20), values.narrow(1, 0, 20), at::Tensor());
  EXPECT_TRUE(at::allclose(batched[0], first20[0], 1e-5, 1e-6));
  EXPECT_TRUE(at::allclose(batched[1], none[0], 1e-5, 1e-6));
}

// With tau = 0 the whole model treats every memory token as relevant.
TEST(Long3rModel, TauZeroMakesWholeMemoryRelevant) {
  at::manual_seed(4);
  long3r::ModelConfig c = tiny();
  c.long3r.tau = 0.0;
  long3r::Long3rModel model(c);
  int64_t steps = 0;
  int64_t memory_before = 0;
  for (int64_t t = 0; t < 6; ++t) {
    auto o = model.push(frame(t));
    if (!o) continue;
    EXPECT_EQ(o->stats.relevant_tokens, memory_before) << "step " << o->frame_index;
    memory_before = o->stats.mem_short_tokens + o->stats.mem_long_tokens;
    ++steps;
  }
  EXPECT_EQ(steps, 5);
  EXPECT_GT(memory_before, 0);
}

TEST(Long3rModel, ShapesAndOneFrameLatency) {
  at::manual_seed(5);
  long3r::Long3rModel model(tiny());
  EXPECT_EQ(model.variant(), "long3r");
  EXPECT_FALSE(model.push(frame(0)).has_value());
  EXPECT_EQ(model.frames_pushed(), 1);
  auto o = model.push(frame(1));
  ASSERT_TRUE(o.has_value());
  EXPECT_EQ(o->frame_index, 0);
  EXPECT_FALSE(o->from_coarse_head);
  EXPECT_EQ(o->pts3d.sizes(), (std::vector<int64_t>{1, 64, 64, 3}));
  EXPECT_EQ(o->conf.sizes(), (std::vector<int64_t>{1, 64, 64}));
  EXPECT_GE(o->conf.min().item<float>(), 1.0f);
  EXPECT_EQ(o->stats.relevant_tokens, 0);    // no memory at step 0
  EXPECT_EQ(o->stats.mem_short_tokens, 16);  // frame 0 written, P = 4 x 4
  auto o2 = model.push(frame(2));
  ASSERT_TRUE(o2.has_value());
  EXPECT_EQ(o2->frame_index, 1);
  EXPECT_GT(o2->stats.relevant_tokens, 0);
  EXPECT_EQ(model.memory().frames_added(), 2);
  EXPECT_THROW(model.push(frame(3, 64, 80)), std::invalid_argument);
  EXPECT_THROW(model.push(at::zeros({1, 3, 60, 64})), std::invalid_argument);
}

// flush() returns the last frame as head 2 predicted it at the last step.
TEST(Long3rModel, FlushReturnsCoarseHeadPrediction) {
  at::manual_seed(6);
  long3r::Long3rModel model(tiny());
  EXPECT_FALSE(model.push(frame(0)).has_value());
  EXPECT_FALSE(model.flush().has_value());  // a single frame has no pair
  std::vector<at::Tensor> frames;
  for (int64_t t = 0; t < 4; ++t) frames.push_back(frame(t));
  std::vector<long3r::StreamOutput> coarse;
  const auto seq = model.forward_sequence(frames, &coarse);
  ASSERT_EQ(seq.size(), 4u);
  ASSERT_EQ(coarse.size(), 3u);
  EXPECT_TRUE(seq.back().from_coarse_head);
  EXPECT_EQ(seq.back().frame_index, 3);
  EXPECT_EQ(coarse.back().frame_index, 3);
  EXPECT_TRUE(at::equal(seq.back().pts3d, coarse.back().pts3d));

  const auto streamed = run_stream(model, 4);
  expect_same(streamed, seq);
  // Head 1 and head 2 are different heads: the coarse map of frame 3 differs
  // from what head 1 gives for frame 3 in a longer stream.
  const auto longer = run_stream(model, 5);
  EXPECT_FALSE(at::allclose(longer[3].pts3d, streamed[3].pts3d));
  EXPECT_FALSE(model.flush().has_value());  // the stream ended
}

// peek_last() is a pause in the input, not its end: it returns what flush()
// would, and the stream then goes on exactly as if it had not been called.
TEST(Long3rModel, PeekLastKeepsTheStream) {
  at::manual_seed(8);
  long3r::Long3rModel model(tiny());
  const auto reference = run_stream(model, 6);
  std::vector<long3r::StreamOutput> peeked;
  for (int64_t t = 0; t < 6; ++t) {
    auto o = model.push(frame(t));
    if (o) expect_same({*o}, {reference[o->frame_index]});
    if (auto p = model.peek_last()) {
      EXPECT_EQ(p->frame_index, t);
      EXPECT_TRUE(p->from_coarse_head);
      peeked.push_back(*p);
    } else {
      EXPECT_EQ(t, 0);  // a single frame has no pair yet
    }
    EXPECT_EQ(model.frames_pushed(), t + 1);
  }
  ASSERT_EQ(peeked.size(), 5u);
  expect_same({peeked.back()}, {reference.back()});  // the last peek is the flush
  EXPECT_EQ(model.memory().frames_added(), 5);
  expect_same({*model.flush()}, {reference.back()});
  EXPECT_EQ(model.frames_pushed(), 0);
}

TEST(Long3rModel, ResetAndRepeatGiveIdenticalOutputs) {
  at::manual_seed(7);
  long3r::Long3rModel model(tiny());
  const auto first = run_stream(model, 7);
  const auto second = run_stream(model, 7);  // flush ended the first stream
  expect_same(first, second);
  for (int64_t t = 0; t < 4; ++t) model.push(frame(t, 64, 64, 1.0));
  model.reset();
  EXPECT_EQ(model.frames_pushed(), 0);
  EXPECT_TRUE(model.memory().empty());
  expect_same(first, run_stream(model, 7));
}

// The memory projection cache (each token's projected key/value computed once,
// when it is written) against the reference that projects the relevant tokens
// at every step: same outputs to float rounding over a stream long enough for
// long-term memory, pruning and a changing relevant set, for B = 1 and B = 2.
TEST(Long3rModel, MemoryProjectionCacheMatchesRecomputation) {
  at::manual_seed(11);
  long3r::ModelConfig c = tiny();
  c.long3r.short_term_frames = 2;
  c.long3r.long_term_capacity = 20;
  long3r::Long3rModel model(c);
  randomize_norms(model.module());
  EXPECT_TRUE(model.memory_projection_cache());
  const int64_t n = 30;
  for (const bool batched : {false, true}) {
    auto run = [&](bool cache) {
      model.set_memory_projection_cache(cache);
      std::vector<long3r::StreamOutput> out;
      std::vector<int64_t> relevant;
      for (int64_t t = 0; t < n; ++t) {
        const at::Tensor img = batched ? at::cat({frame(t), frame(t, 64, 64, 2.0)}) : frame(t);
        auto o = model.push(img);
        if (!o) continue;
        EXPECT_EQ(model.memory().has_payload(), cache);
        relevant.push_back(o->stats.relevant_tokens);
        out.push_back(*o);
      }
      out.push_back(*model.flush());
      return std::make_pair(out, relevant);
    };
    const auto cached = run(true);
    const auto reference = run(false);
    ASSERT_EQ(cached.first.size(), reference.first.size());
    EXPECT_EQ(cached.second, reference.second);
    for (std::size_t i = 0; i < cached.first.size(); ++i) {
      EXPECT_TRUE(at::allclose(cached.first[i].pts3d, reference.first[i].pts3d, 1e-4, 1e-5))
          << "frame " << i << (batched ? " (B = 2)" : "");
      EXPECT_TRUE(at::allclose(cached.first[i].conf, reference.first[i].conf, 1e-4, 1e-5))
          << "frame " << i << (batched ? " (B = 2)" : "");
    }
    // The stream reached long-term memory and read from it.
    EXPECT_GT(cached.second.back(), 2 * 16);
  }
  // Training always recomputes: nothing cached.
  model.set_training(true);
  model.push(frame(0));
  model.push(frame(1));
  model.push(frame(2));
  EXPECT_FALSE(model.memory().has_payload());
}

// A model that streamed in inference first (so its cached RoPE tables were
// made under InferenceMode) can then train: back-propagation must not meet an
// inference tensor.
TEST(Long3rModel, TrainsAfterInference) {
  at::manual_seed(12);
  long3r::Long3rModel model(tiny());
  run_stream(model, 4);
  model.set_training(true);
  const std::vector<at::Tensor> frames = {frame(0), frame(1), frame(2)};
  const auto outs = model.forward_sequence(frames);
  at::Tensor loss = at::zeros({});
  for (const auto& o : outs) loss = loss + o.pts3d.abs().mean();
  ASSERT_NO_THROW(loss.backward());
  const at::Tensor& g = model.module().named_parameters()["dust3r.patch_embed.proj.weight"].grad();
  ASSERT_TRUE(g.defined());
  EXPECT_TRUE(g.isfinite().all().item<bool>());
}

// Two different streams batched give what each gives alone (long-term
// memories differ per stream, so this exercises the padding masks).
TEST(Long3rModel, BatchOfStreamsEqualsSingleStreams) {
  at::manual_seed(8);
  long3r::Long3rModel model(tiny());
  const int64_t n = 9;
  const auto a = run_stream(model, n, 0.0);
  const auto b = run_stream(model, n, 2.0);
  std::vector<long3r::StreamOutput> ab;
  for (int64_t t = 0; t < n; ++t) {
    auto o = model.push(at::cat({frame(t, 64, 64, 0.0), frame(t, 64, 64, 2.0)}));
    if (o) ab.push_back(*o);
  }
  ab.push_back(*model.flush());
  ASSERT_EQ(ab.size(), a.size());
  for (std::size_t i = 0; i < ab.size(); ++i) {
    EXPECT_TRUE(at::allclose(ab[i].pts3d[0], a[i].pts3d[0], 1e-4, 1e-5)) << "frame " << i;
    EXPECT_TRUE(at::allclose(ab[i].pts3d[1], b[i].pts3d[0], 1e-4, 1e-5)) << "frame " << i;
    EXPECT_TRUE(at::allclose(ab[i].conf[1], b[i].conf[0], 1e-4, 1e-5)) << "frame " << i;
  }
  // Identical streams in a batch equal B = 1.
  std::vector<long3r::StreamOutput> aa;
  for (int64_t t = 0; t < n; ++t) {
    auto o = model.push(frame(t).repeat({2, 1, 1, 1}));
    if (o) aa.push_back(*o);
  }
  aa.push_back(*model.flush());
  for (std::size_t i = 0; i < aa.size(); ++i) {
    EXPECT_TRUE(at::allclose(aa[i].pts3d[1], a[i].pts3d[0], 1e-4, 1e-5)) << "frame " << i;
  }
}

// The memory never holds more than K*P + L tokens, and reaches that bound.
TEST(Long3rModel, MemoryBoundedOnLongStream) {
  at::manual_seed(9);
  long3r::ModelConfig c = tiny();
  c.long3r.short_term_frames = 3;
  c.long3r.long_term_capacity = 40;
  long3r::Long3rModel model(c);
  const int64_t P = 16, bound = 3 * P + 40;
  int64_t peak = 0;
  for (int64_t t = 0; t < 300; ++t) {
    auto o = model.push(frame(t));
    if (!o) continue;
    const int64_t total = o->stats.mem_short_tokens + o->stats.mem_long_tokens;
    ASSERT_LE(total, bound) << "frame " << t;
    ASSERT_EQ(model.memory().total_sizes().at(0), total);
    peak = std::max(peak, total);
  }
  EXPECT_EQ(peak, bound);
  EXPECT_EQ(model.memory().frames_added(), 299);
}

// Training: gradients reach encoder, both decoder branches, memory blocks and
// the memory encoders; the latter only through the memory written at step 0,
// which shows the memory is not detached across steps.
TEST(Long3rModel, TrainingGradientsReachAllParts) {
  at::manual_seed(10);
  long3r::Long3rModel model(tiny());
  model.set_training(true);
  std::vector<at::Tensor> frames{frame(0), frame(1), frame(2)};
  std::vector<long3r::StreamOutput> coarse;
  const auto out = model.forward_sequence(frames, &coarse);
  ASSERT_EQ(out.size(), 3u);
  ASSERT_EQ(coarse.size(), 2u);
  // Frame 1 reads the memory of frame 0.
  const at::Tensor loss =
      out[1].pts3d.abs().mean() + out[1].conf.mean() + coarse[1].pts3d.abs().mean();
  loss.backward();
  const std::vector<std::string> names{"dust3r.patch_embed.proj.weight",
                                       "dust3r.enc_blocks.0.attn.qkv.weight",
                                       "dust3r.dec_blocks.0.cross_attn.projq.weight",
                                       "dust3r.dec_blocks.1.cross_attn.projk.weight",
                                       "dust3r.dec_blocks.1.norm_mem_v.weight",
                                       "dust3r.dec_blocks.3.mlp.fc1.weight",
                                       "dust3r.dec_blocks2.0.attn.qkv.weight",
                                       "dust3r.downstream_head1.dpt.head.0.weight",
                                       "dust3r.downstream_head2.dpt.head.0.weight",
                                       "attn_head_1.0.weight",
                                       "attn_head_2.0.weight",
                                       "value_encoder.0.attn.qkv.weight",
                                       "pos_patch_embed.proj.weight",
                                       "norm_q.weight",
                                       "norm_k.weight",
                                       "norm_v.weight"};
  const auto params = model.module().named_parameters();
  for (const std::string& n : names) {
    const at::Tensor* p = params.find(n);
    ASSERT_NE(p, nullptr) << n;
    ASSERT_TRUE(p->grad().defined()) << n;
    EXPECT_GT(p->grad().abs().sum().item<double>(), 0.0) << n;
  }
  model.set_training(false);
  EXPECT_FALSE(params.find("norm_q.weight")->requires_grad());
}

// Cross-view completion: the encoder sees the visible patches of the masked
// view only (hidden pixels change nothing, bit for bit), the reference is
// seen whole, every patch gets a decoder token, and in training the
// gradients reach the encoder, mask_token and the coarse branch but not the
// refined one, which the task does not run.
TEST(Long3rModel, CompleteViewSeesOnlyTheVisiblePatches) {
  at::manual_seed(11);
  long3r::Long3rModel model(tiny());
  const int64_t p = model.config().dust3r.patch_size;
  const int64_t n = (64 / p) * (64 / p);
  const at::Tensor visible = at::tensor({0, 2, 5, 7}, at::kLong);
  const at::Tensor masked = frame(1), reference = frame(0);
  const at::Tensor out = model.complete_view(masked, reference, visible);
  EXPECT_EQ(out.sizes(), (std::vector<int64_t>{1, n, model.config().dust3r.dec_embed_dim}));
  EXPECT_EQ(model.frames_pushed(), 0);

  auto patch_changed = [&](int64_t index) {
    at::Tensor m = masked.clone();
    const int64_t gw = 64 / p;
    m.narrow(2, (index / gw) * p, p).narrow(3, (index % gw) * p, p).mul_(-1.0).add_(0.3);
    return m;
  };
  EXPECT_TRUE(at::equal(model.complete_view(patch_changed(1), reference, visible), out));
  EXPECT_TRUE(at::equal(model.complete_view(patch_changed(n - 1), reference, visible), out));
  EXPECT_FALSE(at::allclose(model.complete_view(patch_changed(5), reference, visible), out));
  EXPECT_FALSE(at::allclose(model.complete_view(masked, frame(3), visible), out));
  // The visible tokens keep their grid positions: the same pixels shown at
  // another place of the grid decode differently.
  EXPECT_FALSE(at::allclose(
      model.complete_view(masked, reference, at::tensor({1, 2, 5, 7}, at::kLong)), out));
  EXPECT_THROW(model.complete_view(masked, reference, at::tensor({0.5F})), c10::Error);
  EXPECT_THROW(model.complete_view(masked, reference, at::empty({0}, at::kLong)), c10::Error);

  model.set_training(true);
  model.complete_view(masked, reference, visible).pow(2).mean().backward();
  const auto params = model.module().named_parameters();
  for (const char* name :
       {"dust3r.patch_embed.proj.weight", "dust3r.enc_blocks.0.attn.qkv.weight",
        "dust3r.mask_token", "dust3r.decoder_embed.weight",
        "dust3r.dec_blocks2.0.cross_attn.projk.weight", "dust3r.dec_norm.weight"}) {
    ASSERT_NE(params.find(name), nullptr) << name;
    ASSERT_TRUE(params.find(name)->grad().defined()) << name;
    EXPECT_GT(params.find(name)->grad().abs().sum().item<double>(), 0.0) << name;
  }
  for (const char* name : {"dust3r.dec_blocks.0.attn.qkv.weight",
                           "dust3r.downstream_head1.dpt.head.0.weight", "attn_head_1.0.weight"}) {
    ASSERT_NE(params.find(name), nullptr) << name;
    EXPECT_FALSE(params.find(name)->grad().defined()) << name;
  }
}

TEST(Long3rModel, StrictLoadRoundTrip) {
  at::manual_seed(11);
  long3r::Long3rModel model(tiny());
  const std::string path = std::string(LONG3R_BINARY_DIR) + "/test_long3r_roundtrip.safetensors";
  model.save(path);
  const long3r::TensorFile file = long3r::load_safetensors(path);
  EXPECT_EQ(file.tensors.size(), model.module().named_parameters().size());
  // Memory blocks under the documented names; width C_m -> C_d.
  EXPECT_EQ(file.tensors.at("dust3r.dec_blocks.1.cross_attn.projk.weight").sizes(),
            (std::vector<int64_t>{32, 32}));
  EXPECT_EQ(file.tensors.count("dust3r.dec_blocks.1.norm_mem_k.weight"), 1u);
  EXPECT_EQ(file.tensors.count("dust3r.dec_blocks.0.norm_y.weight"), 1u);
  EXPECT_EQ(file.tensors.count("dust3r.dec_blocks.1.norm_y.weight"), 0u);
  auto loaded = long3r::Long3rModel::from_file(path);
  EXPECT_EQ(long3r::model_config_to_json(loaded->config()),
            long3r::model_config_to_json(model.config()));
  expect_same(run_stream(model, 5), run_stream(*loaded, 5));
  // The streaming factory builds the same model from the file.
  const std::unique_ptr<long3r::StreamingModel> streaming = long3r::make_streaming_model(path);
  EXPECT_EQ(streaming->variant(), "long3r");
  EXPECT_TRUE(streaming->accepts_portrait());
  expect_same(run_stream(model, 5), run_stream(*streaming, 5));

  // A missing tensor is an error (strict).
  std::map<std::string, at::Tensor> partial = file.tensors;
  partial.erase("dust3r.dec_blocks.1.cross_attn.projv.bias");
  EXPECT_ANY_THROW(loaded->load_weights(partial, "partial"));
  std::remove(path.c_str());

  // Copying weights gives the same outputs too (and a fresh model differs).
  long3r::Long3rModel other(tiny());
  EXPECT_FALSE(at::allclose(run_stream(other, 3)[0].pts3d, run_stream(model, 3)[0].pts3d));
  copy_weights(model, other);
  expect_same(run_stream(model, 3), run_stream(other, 3));
}

TEST(Long3rConfig, NamedConfigsAndJsonRoundTrip) {
  for (const char* name : {"long3r_paper", "long3r_small", "long3r_tiny"}) {
    const long3r::ModelConfig c = long3r::named_model_config(name);
    EXPECT_EQ(c.kind, long3r::ModelKind::kLong3r);
    const std::string text = long3r::model_config_to_json(c);
    const long3r::ModelConfig back = long3r::parse_model_config(text);
    EXPECT_EQ(long3r::model_config_to_json(back), text) << name;
    EXPECT_EQ(back.long3r.short_term_frames, c.long3r.short_term_frames);
    EXPECT_EQ(back.long3r.long_term_capacity, c.long3r.long_term_capacity);
    EXPECT_EQ(back.dust3r.dpt.layer_dims, c.dust3r.dpt.layer_dims);
    EXPECT_EQ(back.memory_dim(), c.memory_dim());
  }
  const long3r::ModelConfig p = long3r::named_model_config("long3r_paper");
  EXPECT_EQ(p.dust3r.enc_embed_dim, 1024);
  EXPECT_EQ(p.dust3r.enc_depth, 24);
  EXPECT_EQ(p.dust3r.dec_embed_dim, 768);
  EXPECT_EQ(p.dust3r.dec_depth, 12);
  EXPECT_EQ(p.spann3r.value_encoder.depth, 6);
  EXPECT_EQ(p.memory_dim(), 1024);
  EXPECT_EQ(p.long3r.short_term_frames, 10);
  EXPECT_EQ(p.long3r.long_term_capacity, 3000);
  EXPECT_DOUBLE_EQ(p.long3r.tau, 5e-4);
  EXPECT_THROW(long3r::named_model_config("long3r_huge"), long3r::ModelConfigError);

  const std::string base = R"({"model": "LONG3R", "dust3r": {"enc_embed_dim": 64,
      "enc_num_heads": 4, "enc_depth": 1, "dec_embed_dim": 32, "dec_num_heads": 2,
      "dec_depth": 2}, )";
  const long3r::ModelConfig c = long3r::parse_model_config(
      base + R"("long3r": {"short_term_frames": 4, "long_term_capacity": 100, "tau": 0.001,
      "voxel_statistic": "percentile", "voxel_percentile": 10}})");
  EXPECT_EQ(c.long3r.short_term_frames, 4);
  EXPECT_EQ(c.long3r.voxel_statistic, long3r::VoxelStatistic::kPercentile);
  EXPECT_EQ(c.memory_dim(), 64);
  EXPECT_DOUBLE_EQ(c.long3r.voxel_percentile, 10.0);
  EXPECT_THROW(long3r::parse_model_config(base + R"("long3r": {"short_frames": 4}})"),
               long3r::ModelConfigError);
  EXPECT_THROW(long3r::parse_model_config(base + R"("long3r": {"voxel_statistic": "max"}})"),
               long3r::ModelConfigError);
  EXPECT_THROW(long3r::parse_model_config(base + R"("spatial_memory": {}})"),
               long3r::ModelConfigError);
  EXPECT_THROW(long3r::Long3rModel(long3r::parse_model_config(
                   R"({"model": "Spann3R", "dust3r": {"enc_embed_dim": 64, "enc_num_heads": 4,
                   "dec_embed_dim": 32, "dec_num_heads": 2}})")),
               long3r::ModelConfigError);
}

// A seeded initialisation gives the parameters it gave when the network was
// built by replacing a full DUSt3R refined branch (figures from that code):
// from-scratch training runs and the untrained baseline stay reproducible.
TEST(Long3rModel, SeededInitialisationIsUnchanged) {
  at::manual_seed(1);
  long3r::Long3rModel model(tiny());
  double sum = 0.0, weighted = 0.0;
  int64_t index = 0;
  for (const auto& kv : model.module().named_parameters()) {
    const double s = kv.value().to(at::kDouble).sum().item<double>();
    sum += s;
    weighted += static_cast<double>(++index) * s;
  }
  const double after = at::rand({1}, at::kDouble).item<double>();
  EXPECT_EQ(index, 385);
  EXPECT_EQ(sum, 1443.1137214990852);
  EXPECT_EQ(weighted, 208876.79350837914);
  EXPECT_EQ(after, 0.016064954518941632);
}

// The draws a left-out DecoderBlock would have made are exactly those skipped.
TEST(Long3rModel, SkippedInitDrawsMatchADecoderBlock) {
  const int64_t C = 32, hidden = 128;
  at::manual_seed(5);
  const m::DecoderBlock block(C, 2, hidden, 1e-6, /*norm_mem=*/true);
  const at::Tensor after_block = at::rand({8});
  at::manual_seed(5);
  m::skip_init_draws(m::decoder_block_init_draws(C, hidden));
  EXPECT_TRUE(at::rand({8}).equal(after_block));
}

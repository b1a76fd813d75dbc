// Stream states (StreamingModel::stream_state / restore_stream_state, the
// model side of sessions): a state taken at any point of a stream and
// restored into a fresh model loaded from the same file continues the stream
// (LONG3R with its long-term memory bit for bit, and to float rounding with
// its recomputed projection cache; Spann3R bit for bit); a malformed state is
// refused by entry and leaves the stream as it was; identities tell
// checkpoints apart.
#include <ATen/ATen.h>
#include <gtest/gtest.h>

#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "long3r/model/loading/safetensors.hpp"
#include "long3r/model/network/long3r_model.hpp"
#include "long3r/model/network/spann3r_model.hpp"
#include "support/test_support.hpp"

namespace long3r {
namespace {

const std::string kGolden = std::string(LONG3R_GOLDEN_DIR) + "/";

// The input frames: test::pixel_wave_frame with this file's wave.
at::Tensor frame(int64_t t, int64_t H, int64_t W) {
  test::PixelWave wave;
  wave.step = 0.23;
  wave.x_rate = 0.13;
  wave.y_rate = 0.05;
  wave.channel_rate = 1.1;
  wave.amplitude = 0.7;
  wave.cos_y_rate = 0.09;
  wave.cos_amplitude = 0.2;
  return test::pixel_wave_frame(t, H, W, wave);
}

std::string tiny_long3r_file() {
  static const std::string path = [] {
    at::manual_seed(7);
    Long3rModel m(test::tiny_long3r_config());
    const std::string p = test::scratch_dir("stream_state") + "/long3r_tiny.safetensors";
    m.save(p);
    return p;
  }();
  return path;
}

// Bit for bit when max_rel is 0, else within max_rel (test::rel_diff).
void expect_equal(const std::optional<StreamOutput>& a, const std::optional<StreamOutput>& b,
                  const std::string& what, double max_rel = 0.0) {
  ASSERT_EQ(a.has_value(), b.has_value()) << what;
  if (!a) return;
  EXPECT_EQ(a->frame_index, b->frame_index) << what;
  if (max_rel > 0.0) {
    EXPECT_LT(test::rel_diff(b->pts3d, a->pts3d), max_rel) << what;
    EXPECT_LT(test::rel_diff(b->conf, a->conf), max_rel) << what;
  } else {
    EXPECT_TRUE(at::equal(a->pts3d, b->pts3d))
        << what << ": relative difference " << test::rel_diff(b->pts3d, a->pts3d);
    EXPECT_TRUE(at::equal(a->conf, b->conf)) << what;
  }
  EXPECT_EQ(a->stats.mem_short_tokens, b->stats.mem_short_tokens) << what;
  EXPECT_EQ(a->stats.mem_long_tokens, b->stats.mem_long_tokens) << what;
}

// Model `a` streams n frames; at frame `at` its state goes into a fresh model
// `b` (after peek_last(), as a session save does), which then takes the
// remaining frames beside it.
template <class Model>
void expect_continues(
    const std::string& path, int64_t H, int64_t W, int at_frame, int n, double max_rel = 0.0,
    const std::function<void(Model&)>& configure = [](Model&) {}) {
  auto a = Model::from_file(path);
  auto b = Model::from_file(path);
  configure(*a);
  configure(*b);
  for (int t = 0; t < at_frame; ++t) a->push(frame(t, H, W));
  a->peek_last();
  b->push(frame(99, H, W));  // b's own stream, replaced by the restore
  b->push(frame(98, H, W));
  b->restore_stream_state(a->stream_state());
  EXPECT_EQ(b->frames_pushed(), a->frames_pushed());
  for (int t = at_frame; t < n; ++t) {
    expect_equal(a->push(frame(t, H, W)), b->push(frame(t, H, W)),
                 "frame " + std::to_string(t) + " after a restore at " + std::to_string(at_frame),
                 max_rel);
  }
  expect_equal(a->peek_last(), b->peek_last(), "peek_last", max_rel);
}

// Without the projection cache (the reference path) a restored stream goes on
// bit for bit. With it, the restore recomputes the cached projections of all
// tokens in one batch where the stream computed them frame by frame: the same
// to float rounding (measured 2.5e-7 relative on this model).
TEST(StreamState, Long3rContinuesFromAnyPoint) {
  const ModelConfig c = test::tiny_long3r_config();
  const int n = static_cast<int>(c.long3r.short_term_frames) + 6;  // long-term memory in use
  const auto uncached = [](Long3rModel& m) { m.set_memory_projection_cache(false); };
  for (const int at_frame : {0, 1, 2, 5, n - 1}) {
    SCOPED_TRACE("restore at " + std::to_string(at_frame));
    expect_continues<Long3rModel>(tiny_long3r_file(), 64, 64, at_frame, n, 0.0, uncached);
    expect_continues<Long3rModel>(tiny_long3r_file(), 64, 64, at_frame, n, 1e-5);
  }
  auto m = Long3rModel::from_file(tiny_long3r_file());
  for (int t = 0; t < n; ++t) m->push(frame(t, 64, 64));
  ASSERT_GT(m->memory().long_sizes().at(0), 0);  // the test reached long-term memory
}

TEST(StreamState, Long3rStatesMoveBetweenCachedAndUncachedModels) {
  auto cached = Long3rModel::from_file(tiny_long3r_file());
  auto uncached = Long3rModel::from_file(tiny_long3r_file());
  uncached->set_memory_projection_cache(false);
  for (int t = 0; t < 7; ++t) cached->push(frame(t, 64, 64));
  uncached->restore_stream_state(cached->stream_state());
  for (int t = 7; t < 10; ++t) {
    expect_equal(cached->push(frame(t, 64, 64)), uncached->push(frame(t, 64, 64)),
                 "frame " + std::to_string(t), 1e-5);
  }
}

TEST(StreamState, Spann3rContinuesExactlyFromAnyPoint) {
  const std::string path = kGolden + "spann3r_seq_land96x64/weights.safetensors";
  for (const int at_frame : {0, 1, 2, 6}) {
    SCOPED_TRACE("restore at " + std::to_string(at_frame));
    expect_continues<Spann3rModel>(path, 64, 96, at_frame, 9);
  }
}

TEST(StreamState, AMalformedStateIsRefusedByEntryAndTheStreamGoesOn) {
  auto a = Long3rModel::from_file(tiny_long3r_file());
  auto control = Long3rModel::from_file(tiny_long3r_file());
  for (int t = 0; t < 6; ++t) {
    a->push(frame(t, 64, 64));
    control->push(frame(t, 64, 64));
  }
  const StateDict good = a->stream_state();
  auto refused = [&](StateDict s, const std::string& expect) {
    try {
      a->restore_stream_state(s);
      ADD_FAILURE() << "accepted: " << expect;
    } catch (const StateError& e) {
      EXPECT_NE(std::string(e.what()).find(expect), std::string::npos) << e.what();
    }
  };
  StateDict s = good;
  s.erase("memory.short.keys");
  refused(s, "long3r stream state: memory.short.keys: missing");
  s = good;
  s["feat"] = at::zeros({1, 16, 5});
  refused(s, "feat: shape [1, 16, 5], expected [1, 16, 32]");
  s = good;
  s["memory.short.keys"] = good.at("memory.short.keys") * NAN;
  refused(s, "memory.short.keys: holds non-finite values");
  s = good;
  s["height"] = at::scalar_tensor(int64_t{65}, at::kLong);
  refused(s, "long3r stream state: height:");
  s = good;
  s["frames"] = at::scalar_tensor(2.5, at::kDouble);
  refused(s, "frames: expected an int64 scalar");
  s = good;
  s["memory.short.frame_sizes"] = at::full({9}, 16, at::kLong);
  refused(s, "short-term frames, more than this memory's K");
  for (int t = 6; t < 9; ++t) {
    expect_equal(a->push(frame(t, 64, 64)), control->push(frame(t, 64, 64)), "after refusals");
  }
}

TEST(StreamState, IdentitiesTellCheckpointsApart) {
  auto a = Long3rModel::from_file(tiny_long3r_file());
  auto same = Long3rModel::from_file(tiny_long3r_file());
  EXPECT_EQ(a->identity().weights, same->identity().weights);
  EXPECT_EQ(a->identity().weights.size(), 16u);
  EXPECT_EQ(a->identity().variant, "long3r");
  a->to(at::Device(at::kCPU), at::kBFloat16);  // precision is not identity
  EXPECT_EQ(a->identity().weights, same->identity().weights);

  // One weight changed in its first elements: another fingerprint.
  TensorFile f = load_safetensors(tiny_long3r_file());
  at::Tensor& w = f.tensors.begin()->second;
  w = w.clone();
  w.view({-1})[0] += 1.0;
  const std::string other = test::scratch_dir("stream_state_other") + "/other.safetensors";
  save_safetensors(other, f.tensors, f.metadata);
  EXPECT_NE(Long3rModel::from_file(other)->identity().weights, same->identity().weights);
  // A model whose weights came from no file has none.
  EXPECT_EQ(Long3rModel(test::tiny_long3r_config()).identity().weights, "");
}

}  // namespace
}  // namespace long3r

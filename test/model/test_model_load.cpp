// Tests of the public model classes on the golden checkpoints
// (test/data/golden): strict loading (success, renamed and missing tensors),
// pair inference against the reference outputs, and the Spann3R streaming
// semantics (latency of one frame, flush from the coarse head, reset).
#include <ATen/ATen.h>
#include <gtest/gtest.h>
#include <torch/nn/module.h>

#include <stdexcept>
#include <string>

#include "long3r/model/loading/safetensors.hpp"
#include "long3r/model/network/dust3r_model.hpp"
#include "long3r/model/network/spann3r_model.hpp"
#include "support/test_support.hpp"

namespace {

const std::string kGolden = std::string(LONG3R_GOLDEN_DIR) + "/";

using long3r::test::rel_diff;

// The message of the CheckpointError that loading `tensors` throws.
template <typename Model>
std::string load_error(Model& model, const long3r::TensorMap& tensors) {
  try {
    model.load_weights(tensors, "test.safetensors");
  } catch (const long3r::CheckpointError& e) {
    return e.what();
  }
  return "";
}

// Loading maps the file (map_safetensors): the same tensors as reading it,
// copy-on-write views that never change the file, pages given back after the
// copy, and a tensor the mapping cannot hold aligned read on its own.
TEST(ModelLoad, MappedCheckpointGivesTheSameTensorsAndModel) {
  const std::string path = kGolden + "spann3r_seq_land96x64/weights.safetensors";
  const long3r::TensorFile read = long3r::load_safetensors(path);
  long3r::TensorFile mapped = long3r::map_safetensors(path);
  EXPECT_EQ(mapped.metadata, read.metadata);
  ASSERT_EQ(mapped.tensors.size(), read.tensors.size());
  for (const auto& [name, t] : read.tensors) {
    const at::Tensor& m = mapped.tensors.at(name);
    EXPECT_EQ(m.scalar_type(), t.scalar_type()) << name;
    EXPECT_TRUE(m.equal(t)) << name;
  }
  // Given back, read again from the file: the same values.
  const std::string some = read.tensors.begin()->first;
  long3r::release_mapped(mapped.tensors.at(some));
  EXPECT_TRUE(mapped.tensors.at(some).equal(read.tensors.at(some)));
  // A tensor of the heap is left alone.
  at::Tensor heap = read.tensors.at(some).clone();
  long3r::release_mapped(heap);
  EXPECT_TRUE(heap.equal(read.tensors.at(some)));
  // Writing to a view changes neither the file nor another mapping of it.
  mapped.tensors.at(some).add_(1.0);
  EXPECT_TRUE(long3r::map_safetensors(path).tensors.at(some).equal(read.tensors.at(some)));
  // The model loaded from the mapping is the model loaded from the read file.
  const long3r::ModelConfig config = long3r::model_config_from_metadata(read.metadata, path);
  long3r::Spann3rModel a(config), b(config);
  a.load_weights(read.tensors, path);
  b.load_weights(long3r::map_safetensors(path).tensors, path);
  const auto pb = b.module().named_parameters();
  for (const auto& p : a.module().named_parameters()) {
    EXPECT_TRUE(p.value().equal(pb[p.key()])) << p.key();
  }
  EXPECT_EQ(a.weights_fingerprint(), b.weights_fingerprint());

  // F32 data at an offset that is not a multiple of 4 (after 3 bytes of U8).
  std::string header = R"({"a":{"dtype":"U8","shape":[3],"data_offsets":[0,3]},)"
                       R"("b":{"dtype":"F32","shape":[2],"data_offsets":[3,11]}})";
  header.append((8 - header.size() % 8) % 8, ' ');
  std::string bytes(8, '\0');
  for (int i = 0; i < 8; ++i) bytes[i] = static_cast<char>((header.size() >> (8 * i)) & 0xff);
  const float values[2] = {1.5f, -2.25f};
  bytes += header + std::string("\x01\x02\x03", 3) +
           std::string(reinterpret_cast<const char*>(values), sizeof values);
  const std::string odd = long3r::test::scratch_dir("model_load/mapped") + "/unaligned.safetensors";
  long3r::test::write_file(odd, bytes);
  const long3r::TensorFile u = long3r::map_safetensors(odd);
  EXPECT_TRUE(u.tensors.at("b").equal(at::tensor({1.5f, -2.25f})));
  EXPECT_EQ(u.tensors.at("a")[2].item<int64_t>(), 3);
  EXPECT_THROW(long3r::map_safetensors(odd + ".missing"), long3r::CheckpointError);
}

TEST(ModelLoad, Dust3rGoldenWeightsLoadStrictly) {
  const std::string path = kGolden + "dust3r_pair_port80x112/weights.safetensors";
  const long3r::TensorFile file = long3r::load_safetensors(path);
  long3r::Dust3rModel model(long3r::model_config_from_metadata(file.metadata, path));
  EXPECT_NO_THROW(model.load_weights(file.tensors, path));
  // Every file tensor maps onto a module tensor (the layer_rn alias included).
  EXPECT_EQ(model.module().named_parameters().size(), file.tensors.size());
  const at::Tensor w = file.tensors.at("dec_blocks2.3.cross_attn.projq.weight");
  bool found = false;
  for (const auto& kv : model.module().named_parameters()) {
    if (kv.key() == "dec_blocks2.3.cross_attn.projq.weight") {
      found = true;
      EXPECT_TRUE(kv.value().equal(w));
    }
  }
  EXPECT_TRUE(found);

  long3r::TensorMap renamed = file.tensors;
  renamed["enc_blocks.0.attn.qkvx.weight"] = renamed.at("enc_blocks.0.attn.qkv.weight");
  renamed.erase("enc_blocks.0.attn.qkv.weight");
  const std::string msg = load_error(model, renamed);
  EXPECT_NE(msg.find("missing: enc_blocks.0.attn.qkv.weight"), std::string::npos) << msg;
  EXPECT_NE(msg.find("unexpected: enc_blocks.0.attn.qkvx.weight"), std::string::npos) << msg;

  for (const char* name : {"downstream_head2.dpt.head.4.bias", "mask_token",
                           "downstream_head1.dpt.scratch.layer_rn.0.weight"}) {
    long3r::TensorMap missing = file.tensors;
    missing.erase(name);
    EXPECT_NE(load_error(model, missing).find(std::string("missing: ") + name), std::string::npos)
        << name;
  }
  long3r::TensorMap reshaped = file.tensors;
  reshaped["dec_norm.weight"] = at::zeros({17});
  EXPECT_NE(load_error(model, reshaped).find("shape mismatch: dec_norm.weight"), std::string::npos);
}

TEST(ModelLoad, Dust3rPairMatchesGoldenPortrait) {
  const std::string dir = kGolden + "dust3r_pair_port80x112/";
  const long3r::Dust3rModel model = long3r::Dust3rModel::from_file(dir + "weights.safetensors");
  const long3r::TensorFile io = long3r::load_safetensors(dir + "io.safetensors");
  const long3r::PairPrediction p =
      model.infer(io.tensors.at("view1.img"), io.tensors.at("view2.img"));
  // Portrait input (H = 112, W = 80): outputs [1, W, H, .] as the reference.
  EXPECT_EQ(p.pts3d1.sizes(), (std::vector<int64_t>{1, 80, 112, 3}));
  EXPECT_LE(rel_diff(p.pts3d1, io.tensors.at("res1.pts3d")), 1e-4);
  EXPECT_LE(rel_diff(p.conf1, io.tensors.at("res1.conf")), 1e-4);
  EXPECT_LE(rel_diff(p.pts3d2, io.tensors.at("res2.pts3d_in_other_view")), 1e-4);
  EXPECT_LE(rel_diff(p.conf2, io.tensors.at("res2.conf")), 1e-4);
  // Swapped inputs give other results (the test can tell them apart).
  const long3r::PairPrediction s =
      model.infer(io.tensors.at("view2.img"), io.tensors.at("view1.img"));
  EXPECT_GT(rel_diff(s.pts3d1, io.tensors.at("res1.pts3d")), 1e-2);
  // Views of different sizes are encoded separately (each on its own grid).
  const long3r::PairPrediction d =
      model.infer(io.tensors.at("view1.img"), io.tensors.at("view2.img").narrow(2, 0, 96));
  EXPECT_EQ(d.pts3d1.sizes(), (std::vector<int64_t>{1, 80, 112, 3}));
  EXPECT_EQ(d.pts3d2.sizes(), (std::vector<int64_t>{1, 80, 96, 3}));
  EXPECT_TRUE(at::isfinite(d.pts3d2).all().item<bool>());
  EXPECT_THROW(model.infer(io.tensors.at("view1.img"), io.tensors.at("view1.img").narrow(3, 0, 70)),
               std::invalid_argument);
}

TEST(ModelLoad, Spann3rGoldenWeightsLoadStrictly) {
  const std::string path = kGolden + "spann3r_seq_land96x64/weights.safetensors";
  const long3r::TensorFile file = long3r::load_safetensors(path);
  long3r::Spann3rModel model(long3r::model_config_from_metadata(file.metadata, path));
  EXPECT_NO_THROW(model.load_weights(file.tensors, path));
  EXPECT_EQ(model.module().named_parameters().size(), file.tensors.size());

  long3r::TensorMap renamed = file.tensors;
  renamed["dust3r.enc_norm.weights"] = renamed.at("dust3r.enc_norm.weight");
  renamed.erase("dust3r.enc_norm.weight");
  const std::string msg = load_error(model, renamed);
  EXPECT_NE(msg.find("missing: dust3r.enc_norm.weight"), std::string::npos) << msg;
  EXPECT_NE(msg.find("unexpected: dust3r.enc_norm.weights"), std::string::npos) << msg;
  for (const char* name : {"norm_q.bias", "attn_head_2.2.weight", "pos_patch_embed.proj.bias",
                           "value_encoder.1.mlp.fc2.weight"}) {
    long3r::TensorMap missing = file.tensors;
    missing.erase(name);
    EXPECT_NE(load_error(model, missing).find(std::string("missing: ") + name), std::string::npos)
        << name;
  }
  // A DUSt3R checkpoint is not a Spann3R one.
  EXPECT_THROW(long3r::Spann3rModel::from_file(kGolden + "dust3r_pair_sq224/weights.safetensors"),
               long3r::ModelConfigError);
  EXPECT_THROW(long3r::Dust3rModel::from_file(path), long3r::ModelConfigError);

  // The streaming factory builds the variant the file names and refuses a pair
  // model by name.
  const std::unique_ptr<long3r::StreamingModel> streaming = long3r::make_streaming_model(path);
  EXPECT_EQ(streaming->variant(), "spann3r");
  EXPECT_EQ(streaming->accepts_portrait(), !model.config().dust3r.landscape_only);
  try {
    long3r::make_streaming_model(kGolden + "dust3r_pair_sq224/weights.safetensors");
    ADD_FAILURE() << "a DUSt3R pair model loaded as a streaming model";
  } catch (const long3r::CheckpointError& e) {
    EXPECT_NE(std::string(e.what()).find("not a streaming model"), std::string::npos) << e.what();
  }
}

TEST(ModelLoad, Spann3rStreamSemantics) {
  const std::string dir = kGolden + "spann3r_seq_land96x64/";
  auto model = long3r::Spann3rModel::from_file(dir + "weights.safetensors");
  const long3r::TensorFile io = long3r::load_safetensors(dir + "io.safetensors");
  const at::Tensor frames = io.tensors.at("frames.img");
  const at::Tensor pred = io.tensors.at("pred.pts3d");
  EXPECT_EQ(model->variant(), "spann3r");

  EXPECT_FALSE(model->push(frames.narrow(0, 0, 1)).has_value());  // one frame of latency
  EXPECT_EQ(model->frames_pushed(), 1);
  const auto o0 = model->push(frames.narrow(0, 1, 1));
  ASSERT_TRUE(o0.has_value());
  EXPECT_EQ(o0->frame_index, 0);
  EXPECT_FALSE(o0->from_coarse_head);
  EXPECT_LE(rel_diff(o0->pts3d, pred.narrow(0, 0, 1)), 1e-4);
  EXPECT_EQ(o0->stats.mem_short_tokens + o0->stats.mem_long_tokens, 24);
  const auto o1 = model->push(frames.narrow(0, 2, 1));
  ASSERT_TRUE(o1.has_value());
  EXPECT_EQ(o1->frame_index, 1);
  EXPECT_LE(rel_diff(o1->pts3d, pred.narrow(0, 1, 1)), 1e-4);
  EXPECT_LE(rel_diff(o1->conf, io.tensors.at("pred.conf").narrow(0, 1, 1)), 1e-4);
  EXPECT_EQ(model->memory().size(), 48);
  EXPECT_EQ(o1->stats.mem_short_tokens, 24);  // work_mem_size 1
  EXPECT_EQ(o1->stats.mem_long_tokens, 24);
  EXPECT_THROW(model->push(frames.narrow(0, 3, 1).narrow(3, 0, 64)), std::invalid_argument);

  // A pause: the coarse head's frame 2 now, the stream kept.
  const auto peeked = model->peek_last();
  ASSERT_TRUE(peeked.has_value());
  EXPECT_EQ(peeked->frame_index, 2);
  EXPECT_EQ(model->frames_pushed(), 3);
  EXPECT_EQ(model->memory().size(), 48);

  const auto last = model->flush();  // frame 2 from the coarse head of step 1
  ASSERT_TRUE(last.has_value());
  EXPECT_TRUE(last->pts3d.equal(peeked->pts3d));
  EXPECT_EQ(last->frame_index, 2);
  EXPECT_TRUE(last->from_coarse_head);
  EXPECT_EQ(last->pts3d.sizes(), (std::vector<int64_t>{1, 64, 96, 3}));
  EXPECT_EQ(model->frames_pushed(), 0);
  EXPECT_TRUE(model->memory().empty());

  // A new stream starts from scratch: the same first output again.
  model->push(frames.narrow(0, 0, 1));
  const auto again = model->push(frames.narrow(0, 1, 1));
  ASSERT_TRUE(again.has_value());
  EXPECT_TRUE(again->pts3d.equal(o0->pts3d));
  model->reset();
  EXPECT_EQ(model->frames_pushed(), 0);
  model->push(frames.narrow(0, 0, 1));
  EXPECT_FALSE(model->flush().has_value());  // a single frame has no pair
}

}  // namespace

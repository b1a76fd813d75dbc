// Tests of load_module_strict (include/long3r/model/loading/checkpoint.hpp) on a small
// hand-built module that has the DPT head's peculiarity: one conv registered
// under two names.
#include <gtest/gtest.h>
#include <torch/nn/module.h>
#include <torch/nn/modules/container/modulelist.h>
#include <torch/nn/modules/conv.h>
#include <torch/nn/modules/linear.h>

#include <map>
#include <string>

#include "long3r/model/loading/checkpoint.hpp"

namespace {

using long3r::CheckpointError;

// head.layer1_rn and head.layer_rn.0 are the same conv.
struct Head : torch::nn::Module {
  Head() {
    layer1_rn = register_module("layer1_rn",
                                torch::nn::Conv2d(torch::nn::Conv2dOptions(2, 3, 3).bias(false)));
    layer_rn = register_module("layer_rn", torch::nn::ModuleList());
    layer_rn->push_back(layer1_rn);
    out = register_module("out", torch::nn::Linear(4, 2));
  }
  torch::nn::Conv2d layer1_rn{nullptr};
  torch::nn::ModuleList layer_rn{nullptr};
  torch::nn::Linear out{nullptr};
};

struct Net : torch::nn::Module {
  Net() {
    embed = register_module("embed", torch::nn::Linear(3, 4));
    head = register_module("head", std::make_shared<Head>());
    steps = register_buffer("steps", torch::zeros({2}, torch::kLong));
  }
  torch::nn::Linear embed{nullptr};
  std::shared_ptr<Head> head;
  at::Tensor steps;
};

// A complete, matching set of tensors with values unlike the module's.
std::map<std::string, at::Tensor> good_tensors(const std::string& prefix = "") {
  std::map<std::string, at::Tensor> t;
  const at::Tensor conv = torch::arange(54, torch::kFloat).reshape({3, 2, 3, 3}) * 0.5;
  t[prefix + "embed.weight"] = torch::full({4, 3}, 1.5);
  t[prefix + "embed.bias"] = torch::full({4}, -2.0);
  t[prefix + "head.layer1_rn.weight"] = conv;
  t[prefix + "head.layer_rn.0.weight"] = conv.clone();
  t[prefix + "head.out.weight"] = torch::full({2, 4}, 3.0);
  t[prefix + "head.out.bias"] = torch::full({2}, 4.0);
  t[prefix + "steps"] = torch::tensor({7, 9}, torch::kLong);
  return t;
}

// Snapshot of every parameter and buffer, to prove a failed load changed nothing.
std::map<std::string, at::Tensor> snapshot(Net& net) {
  std::map<std::string, at::Tensor> s;
  for (const auto& kv : net.named_parameters()) s[kv.key()] = kv.value().detach().clone();
  for (const auto& kv : net.named_buffers()) s[kv.key()] = kv.value().clone();
  return s;
}

bool unchanged(Net& net, const std::map<std::string, at::Tensor>& before) {
  const auto now = snapshot(net);
  if (now.size() != before.size()) return false;
  for (const auto& kv : before) {
    if (!torch::equal(kv.second, now.at(kv.first))) return false;
  }
  return true;
}

// Loads and returns the error message ("" if it loaded), checking that a
// failed load left the module untouched.
std::string load_error(Net& net, const std::map<std::string, at::Tensor>& t,
                       const std::string& strip = "", const std::vector<std::string>& ignore = {}) {
  const auto before = snapshot(net);
  try {
    long3r::load_module_strict(net, t, "ckpt.safetensors", strip, ignore);
  } catch (const CheckpointError& e) {
    EXPECT_TRUE(unchanged(net, before)) << "module modified by a failed load";
    return e.what();
  }
  return "";
}

#define EXPECT_CONTAINS(haystack, needle)                          \
  EXPECT_NE(std::string(haystack).find(needle), std::string::npos) \
      << "expected \"" << (needle) << "\" in: \"" << (haystack) << "\""

}  // namespace

TEST(LoadModuleStrict, ModuleExposesBothNamesOfTheSharedConv) {
  Net net;
  const auto params = net.named_parameters();
  ASSERT_NE(params.find("head.layer1_rn.weight"), nullptr);
  ASSERT_NE(params.find("head.layer_rn.0.weight"), nullptr);
  EXPECT_TRUE(params["head.layer1_rn.weight"].is_same(params["head.layer_rn.0.weight"]));
}

TEST(LoadModuleStrict, LoadsEverything) {
  Net net;
  const auto t = good_tensors();
  EXPECT_EQ(load_error(net, t), "");
  EXPECT_TRUE(torch::equal(net.embed->weight, t.at("embed.weight")));
  EXPECT_TRUE(torch::equal(net.embed->bias, t.at("embed.bias")));
  EXPECT_TRUE(torch::equal(net.head->layer1_rn->weight, t.at("head.layer1_rn.weight")));
  EXPECT_TRUE(torch::equal(net.head->out->bias, t.at("head.out.bias")));
  EXPECT_TRUE(torch::equal(net.steps, t.at("steps")));
  // Copies, not aliases of the file tensors; parameters still require grad.
  EXPECT_FALSE(net.embed->weight.is_same(t.at("embed.weight")));
  EXPECT_TRUE(net.embed->weight.requires_grad());
  EXPECT_FALSE(net.embed->weight.grad_fn());
}

TEST(LoadModuleStrict, StripAndIgnorePrefixes) {
  Net net;
  auto t = good_tensors("dust3r.");
  t["value_encoder.w"] = torch::ones({1});
  t["dust3r.downstream_head2.x"] = torch::ones({1});
  EXPECT_EQ(load_error(net, t, "dust3r.", {"value_encoder.", "downstream_head2."}), "");
  EXPECT_TRUE(torch::equal(net.steps, t.at("dust3r.steps")));
  // Without the ignore list both extras are reported, by their file names.
  Net net2;
  const std::string e = load_error(net2, t, "dust3r.");
  EXPECT_CONTAINS(e, "unexpected: dust3r.downstream_head2.x");
  EXPECT_CONTAINS(e, "unexpected: value_encoder.w");
  EXPECT_CONTAINS(e, "2 problems");
}

TEST(LoadModuleStrict, MissingTensorIsNamed) {
  Net net;
  auto t = good_tensors();
  t.erase("head.out.bias");
  const std::string e = load_error(net, t);
  EXPECT_CONTAINS(e, "ckpt.safetensors");
  EXPECT_CONTAINS(e, "missing: head.out.bias (module Float [2])");
  EXPECT_CONTAINS(e, "1 problem)");
}

TEST(LoadModuleStrict, BothAliasNamesAreRequired) {
  Net net;
  auto t = good_tensors();
  t.erase("head.layer_rn.0.weight");
  EXPECT_CONTAINS(load_error(net, t), "missing: head.layer_rn.0.weight");
}

TEST(LoadModuleStrict, AliasNamesMustAgree) {
  Net net;
  auto t = good_tensors();
  t["head.layer_rn.0.weight"] = t["head.layer_rn.0.weight"] + 1;
  EXPECT_CONTAINS(load_error(net, t),
                  "conflicting values: head.layer1_rn.weight and head.layer_rn.0.weight");
}

TEST(LoadModuleStrict, UnexpectedTensorIsNamed) {
  Net net;
  auto t = good_tensors();
  t["head.extra.weight"] = torch::ones({5, 2});
  EXPECT_CONTAINS(load_error(net, t), "unexpected: head.extra.weight (Float [5, 2])");
}

TEST(LoadModuleStrict, ShapeMismatchIsNamed) {
  Net net;
  auto t = good_tensors();
  t["embed.weight"] = torch::ones({3, 4});
  EXPECT_CONTAINS(load_error(net, t),
                  "shape mismatch: embed.weight: file Float [3, 4], module Float [4, 3]");
}

TEST(LoadModuleStrict, IntegerIntoFloatIsAnError) {
  Net net;
  auto t = good_tensors();
  t["head.out.bias"] = torch::ones({2}, torch::kLong);
  EXPECT_CONTAINS(load_error(net, t), "dtype mismatch: head.out.bias: file Long, module Float");
  Net net2;
  auto t2 = good_tensors();
  t2["steps"] = torch::ones({2});  // float into an integer buffer
  EXPECT_CONTAINS(load_error(net2, t2), "dtype mismatch: steps: file Float, module Long");
}

// Floating tensors load as the file declares them: a float16 or bfloat16
// tensor becomes the parameter, in its dtype, bit for bit (no conversion at
// load; the model converts once, to the precision it runs in).
TEST(LoadModuleStrict, HalfPrecisionTensorsLoadAsStored) {
  Net net;
  auto t = good_tensors();
  t["embed.weight"] = t["embed.weight"].to(torch::kHalf);
  t["head.out.weight"] = t["head.out.weight"].to(torch::kBFloat16);
  EXPECT_EQ(load_error(net, t), "");
  EXPECT_EQ(net.embed->weight.scalar_type(), torch::kHalf);
  EXPECT_EQ(net.head->out->weight.scalar_type(), torch::kBFloat16);
  EXPECT_EQ(net.embed->bias.scalar_type(), torch::kFloat);
  EXPECT_TRUE(torch::equal(net.embed->weight, t["embed.weight"]));
  EXPECT_TRUE(torch::equal(net.head->out->weight, t["head.out.weight"]));
  // The parameters own their data (not the file's tensors).
  t["embed.weight"].fill_(0);
  EXPECT_TRUE(torch::equal(net.embed->weight, torch::full({4, 3}, 1.5, torch::kHalf)));
}

TEST(LoadModuleStrict, AllProblemsReportedAtOnce) {
  Net net;
  auto t = good_tensors();
  t.erase("embed.bias");                                // missing
  t["bogus"] = torch::ones({1});                        // unexpected
  t["head.out.weight"] = torch::ones({4, 2});           // shape
  t["head.out.bias"] = torch::ones({2}, torch::kLong);  // dtype
  const std::string e = load_error(net, t);
  EXPECT_CONTAINS(e, "4 problems");
  EXPECT_CONTAINS(e, "missing: embed.bias");
  EXPECT_CONTAINS(e, "unexpected: bogus");
  EXPECT_CONTAINS(e, "shape mismatch: head.out.weight");
  EXPECT_CONTAINS(e, "dtype mismatch: head.out.bias");
}

TEST(LoadModuleStrict, LongListsAreCapped) {
  Net net;
  auto t = good_tensors();
  for (int i = 0; i < 70; ++i) t["extra." + std::to_string(100 + i)] = torch::ones({1});
  const std::string e = load_error(net, t);
  EXPECT_CONTAINS(e, "70 problems");
  EXPECT_CONTAINS(e, "unexpected: extra.149");
  EXPECT_EQ(e.find("extra.150"), std::string::npos);
  EXPECT_CONTAINS(e, "... and 20 more");
}

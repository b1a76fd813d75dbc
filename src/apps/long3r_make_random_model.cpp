// long3r_make_random_model: writes a small Spann3R checkpoint with random
// (default-initialised, seeded) weights and its configuration in the
// metadata, flagged random_weights=true. A placeholder so that the pipeline,
// CLI and ROS node run end to end before trained weights exist; its outputs
// are meaningless.
//
// Sizes (measured at 224 x 224 on 2 shared CPU cores: tiny ~10 FPS, small ~1 FPS):
//   tiny:  encoder 32 wide x 2 blocks (2 heads), decoder 16 x 2 (2 heads),
//          DPT 12/8, value encoder 1 block;
//   small: encoder 128 x 4 (4 heads), decoder 64 x 4 (4 heads), DPT 64/32,
//          value encoder 2 blocks.
// Head widths stay multiples of 4 (2D RoPE).
#include <torch/torch.h>

#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <map>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "long3r/config/cli_options.hpp"
#include "long3r/model/loading/safetensors.hpp"
#include "long3r/model/network/long3r_model.hpp"
#include "long3r/model/network/model_config.hpp"
#include "long3r/model/network/spann3r_model.hpp"
#include "long3r/pipeline/reconstruction.hpp"

namespace {

std::string config_json(const std::string& size, int img) {
  int enc = 32, enc_depth = 2, enc_heads = 2, dec = 16, dec_depth = 2, dec_heads = 2;
  int feat = 12, last = 8, value_depth = 1;
  std::vector<int> layers{8, 12, 16, 16};
  if (size == "small") {
    enc = 128, enc_depth = 4, enc_heads = 4, dec = 64, dec_depth = 4, dec_heads = 4;
    feat = 64, last = 32, value_depth = 2, layers = {32, 48, 64, 64};
  }
  using Json = nlohmann::ordered_json;
  Json dust3r = {{"img_size", {img, img}},
                 {"patch_size", 16},
                 {"enc_embed_dim", enc},
                 {"enc_depth", enc_depth},
                 {"enc_num_heads", enc_heads},
                 {"dec_embed_dim", dec},
                 {"dec_depth", dec_depth},
                 {"dec_num_heads", dec_heads},
                 {"landscape_only", true},
                 {"depth_mode", {"exp", "-inf", "inf"}},
                 {"conf_mode", {"exp", 1, "inf"}},
                 {"dpt_head", {{"feature_dim", feat}, {"last_dim", last}, {"layer_dims", layers}}}};
  Json spann3r = {
      {"use_feat", false},
      {"mem_pos_enc", false},
      {"value_encoder",
       {{"depth", value_depth}, {"embed_dim", enc}, {"num_heads", enc_heads}, {"out_dim", enc}}}};
  Json root = {
      {"model", "Spann3R"},
      {"note", "random weights (long3r_make_random_model --size " + size + ")"},
      {"dust3r", std::move(dust3r)},
      {"spann3r", std::move(spann3r)},
      {"spatial_memory", {{"long_mem_size", 2000}, {"top_k", 2000}, {"work_mem_size", 5}}}};
  return root.dump();
}

}  // namespace

int main(int argc, char** argv) {
  std::string out, variant = "spann3r", size = "tiny", named;
  int img = 224;
  long long seed = 0;
  long3r::CliOptions cli("long3r_make_random_model",
                         "Writes a Spann3R checkpoint with RANDOM weights (a placeholder for "
                         "testing the pipeline; its outputs are meaningless).");
  cli.option("--out", "FILE", &out, "the safetensors file to write").required();
  cli.option("--variant", "", &variant, "model type").choices({"spann3r"});
  cli.option("--size", "", &size, "tiny: ~10 FPS, small: ~1 FPS at 224 x 224 on 2 cores")
      .choices({"tiny", "small"});
  cli.option("--img-size", "N", &img, "input size N x N, a multiple of 16");
  cli.option("--config", "NAME", &named,
             "instead: a LONG3R model of a named configuration (long3r_tiny, long3r_small, "
             "long3r_ship, long3r_paper: the paper's 668 M parameters, a 2.7 GB file), e.g. "
             "to measure loading (long3r_load_bench)");
  cli.option("--seed", "N", &seed, "initialisation seed");
  if (const auto rc = cli.parse_or_exit(argc, argv)) return *rc;
  if (img <= 0 || img % 16 != 0)
    return cli.usage_error("--img-size must be a positive multiple of 16");
  try {
    const long3r::ModelConfig config = named.empty()
                                           ? long3r::parse_model_config(config_json(size, img))
                                           : long3r::named_model_config(named);
    const std::string json =
        named.empty() ? config_json(size, img) : long3r::model_config_to_json(config);
    torch::manual_seed(static_cast<uint64_t>(seed));
    std::unique_ptr<long3r::ModelShell> shell;
    if (named.empty()) {
      shell = std::make_unique<long3r::Spann3rModel>(config);
    } else {
      shell = std::make_unique<long3r::Long3rModel>(config);
    }
    long3r::ModelShell& model = *shell;
    std::map<std::string, at::Tensor> tensors;
    int64_t count = 0;
    for (const auto& kv : model.module().named_parameters(true)) {
      tensors[kv.key()] = kv.value().detach().contiguous();
      count += kv.value().numel();
    }
    for (const auto& kv : model.module().named_buffers(true)) {
      tensors[kv.key()] = kv.value().detach().contiguous();
    }
    long3r::save_safetensors(out, tensors,
                             {{"config", json},
                              {long3r::kRandomWeightsMetadataKey, "true"},
                              {"seed", std::to_string(seed)}});
    std::printf("wrote %s: %s, %zu tensors, %lld parameters, seed %lld\n", out.c_str(),
                named.empty() ? ("Spann3R " + size).c_str() : named.c_str(), tensors.size(),
                static_cast<long long>(count), seed);
    std::printf(
        "WARNING: THE WEIGHTS ARE RANDOM. This checkpoint is a placeholder for testing the "
        "pipeline; its pointmaps, poses and maps are meaningless.\n");
  } catch (const std::exception& e) {
    std::fprintf(stderr, "long3r_make_random_model: %s\n", e.what());
    return 1;
  }
  return 0;
}

// The model on a CUDA device. Each test needs a GPU and this libtorch built
// with CUDA; where either is missing it is skipped, saying which
// (scripts/gpu_check.sh runs these on a GPU machine).
#include <ATen/ATen.h>
#include <ATen/Context.h>
#include <gtest/gtest.h>
#include <torch/cuda.h>
#include <torch/nn/module.h>

#include <algorithm>
#include <cstdio>
#include <string>
#include <vector>

#include "long3r/model/loading/safetensors.hpp"
#include "long3r/model/network/dust3r_model.hpp"
#include "long3r/model/network/long3r_model.hpp"
#include "long3r/model/runtime/inference.hpp"
#include "support/test_support.hpp"

namespace {

const std::string kGolden = std::string(LONG3R_GOLDEN_DIR) + "/";

// Empty when a GPU is usable, else why not.
std::string no_gpu_reason() {
  if (!at::hasCUDA()) return "this libtorch has no CUDA (CPU-only build)";
  if (!torch::cuda::is_available()) return "no CUDA device visible";
  return "";
}
#define SKIP_WITHOUT_GPU()                                         \
  do {                                                             \
    const std::string why = no_gpu_reason();                       \
    if (!why.empty()) GTEST_SKIP() << "needs a CUDA GPU: " << why; \
  } while (0)

// float32 matmuls and convolutions in full float32 (no TF32) for the scope.
class NoTf32 {
 public:
  NoTf32()
      : cublas_(at::globalContext().allowTF32CuBLAS()),
        cudnn_(at::globalContext().allowTF32CuDNN()) {
    at::globalContext().setAllowTF32CuBLAS(false);
    at::globalContext().setAllowTF32CuDNN(false);
  }
  ~NoTf32() {
    at::globalContext().setAllowTF32CuBLAS(cublas_);
    at::globalContext().setAllowTF32CuDNN(cudnn_);
  }

 private:
  bool cublas_, cudnn_;
};

}  // namespace

// The golden DUSt3R pair on the GPU in float32 (TF32 off) against the same
// model on the CPU, at the golden cases' tolerance (1e-4 relative).
TEST(Cuda, Dust3rPairMatchesTheCpuInFloat32) {
  SKIP_WITHOUT_GPU();
  const NoTf32 no_tf32;
  const std::string dir = kGolden + "dust3r_pair_sq224/";
  const long3r::TensorFile io = long3r::load_safetensors(dir + "io.safetensors");
  const at::Tensor img1 = io.tensors.at("view1.img"), img2 = io.tensors.at("view2.img");
  long3r::Dust3rModel cpu = long3r::Dust3rModel::from_file(dir + "weights.safetensors");
  long3r::Dust3rModel gpu = long3r::Dust3rModel::from_file(dir + "weights.safetensors");
  gpu.to(at::Device(at::kCUDA));
  const long3r::PairPrediction a = cpu.infer(img1, img2);
  const long3r::PairPrediction b = gpu.infer(img1.cuda(), img2.cuda());
  EXPECT_TRUE(b.pts3d1.is_cuda());
  const double dev = std::max(long3r::test::rel_diff(b.pts3d1.cpu(), a.pts3d1),
                              long3r::test::rel_diff(b.pts3d2.cpu(), a.pts3d2));
  std::printf("DUSt3R pair 224x224 on CUDA vs CPU, float32: max relative deviation %.3e\n", dev);
  EXPECT_LT(dev, 1e-4);
}

// A LONG3R stream on the GPU in each precision: weights, memory and work on
// the device (convolutions converted too: the CPU's float32 exception does
// not apply), outputs float32 and finite.
TEST(Cuda, Long3rStreamRunsOnTheDeviceInEveryPrecision) {
  SKIP_WITHOUT_GPU();
  for (at::ScalarType dtype : {at::kFloat, at::kBFloat16, at::kHalf}) {
    at::manual_seed(5);
    long3r::Long3rModel model(long3r::test::tiny_long3r_config());
    model.to(at::Device(at::kCUDA), dtype);
    for (const auto& p : model.module().named_parameters()) {
      EXPECT_TRUE(p.value().is_cuda()) << p.key();
      EXPECT_EQ(p.value().scalar_type(), dtype) << p.key();
    }
    int outputs = 0;
    for (int64_t t = 0; t < 5; ++t) {
      if (auto o = model.push(long3r::test::grid_wave_frame(t, 64, 64))) {
        ++outputs;
        EXPECT_EQ(o->pts3d.scalar_type(), at::kFloat);
        EXPECT_TRUE(o->pts3d.is_cuda());
        EXPECT_TRUE(o->pts3d.isfinite().all().item<bool>()) << c10::toString(dtype);
      }
    }
    EXPECT_EQ(outputs, 4);
    EXPECT_TRUE(model.memory().keys().is_cuda());
    EXPECT_EQ(model.memory().keys().scalar_type(), dtype);
  }
}

// DUSt3R pair inference; see include/long3r/model/network/dust3r_model.hpp.
#include "long3r/model/network/dust3r_model.hpp"

#include <ATen/ATen.h>
#include <c10/core/InferenceMode.h>

#include <stdexcept>

#include "long3r/model/network/modules.hpp"

namespace long3r {

struct Dust3rModel::Impl {
  explicit Impl(const Dust3rConfig& c) : net(c) {
    for (auto& p : net->parameters()) p.set_requires_grad(false);
    net->eval();
  }
  model::Dust3rNet net;
};

Dust3rModel::Dust3rModel(const ModelConfig& config)
    : ModelShell(config, ModelKind::kDust3r, "Dust3rModel needs an AsymmetricCroCo3DStereo config"),
      impl_(std::make_unique<Impl>(config.dust3r)) {
  set_module(impl_->net.ptr());
}

Dust3rModel::~Dust3rModel() = default;
Dust3rModel::Dust3rModel(Dust3rModel&&) noexcept = default;
Dust3rModel& Dust3rModel::operator=(Dust3rModel&&) noexcept = default;

Dust3rModel Dust3rModel::from_file(const std::string& path) {
  return std::move(*model_from_checkpoint<Dust3rModel>(read_model_checkpoint(path), path));
}

PairPrediction Dust3rModel::infer(const at::Tensor& img1, const at::Tensor& img2,
                                  const Trace& trace) const {
  if (img1.dim() != 4 || img1.size(1) != 3 || img2.dim() != 4 || img2.size(1) != 3 ||
      img1.size(0) != img2.size(0)) {
    throw std::invalid_argument(
        "Dust3rModel::infer: expected two [B, 3, H, W] images with one batch size");
  }
  c10::InferenceMode guard;
  model::Dust3rNet& net = impl_->net;
  const at::Device dev = device();
  const int64_t B = img1.size(0);
  const int64_t H1 = img1.size(2), W1 = img1.size(3), H2 = img2.size(2), W2 = img2.size(3);
  const model::Grid g1 = net->grid(H1, W1), g2 = net->grid(H2, W2);

  at::Tensor f1, f2;
  if (img1.sizes().equals(img2.sizes())) {
    // One batch of 2B, as the official _encode_image_pairs does for equal shapes.
    TensorMap records;
    const at::Tensor feats = net->encode(at::cat({img1, img2}).to(dev, dtype()),
                                         trace.enabled() ? Trace(&records) : Trace());
    for (const auto& kv : records) {
      trace.put("img1." + kv.first, kv.second.narrow(0, 0, B));
      trace.put("img2." + kv.first, kv.second.narrow(0, B, B));
    }
    f1 = feats.narrow(0, 0, B);
    f2 = feats.narrow(0, B, B);
  } else {
    f1 = net->encode(img1.to(dev, dtype()), trace.child("img1."));
    f2 = net->encode(img2.to(dev, dtype()), trace.child("img2."));
  }

  const auto dec = net->decode(f1, g1, f2, g2, trace);
  const model::HeadOutput r1 = net->head(1, dec.first, H1, W1, trace.child("head1."));
  const model::HeadOutput r2 = net->head(2, dec.second, H2, W2, trace.child("head2."));
  if (trace.enabled()) {
    trace.put("res1.pts3d", r1.pts3d);
    trace.put("res2.pts3d_in_other_view", r2.pts3d);
    if (r1.conf.defined()) {
      trace.put("res1.conf", r1.conf);
      trace.put("res2.conf", r2.conf);
    }
  }
  return {r1.pts3d, r1.conf, r2.pts3d, r2.conf};
}

}  // namespace long3r

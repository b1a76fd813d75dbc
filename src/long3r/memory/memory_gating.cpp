// Memory gating and read-out; see include/long3r/memory/memory_gating.hpp.
#include "long3r/memory/memory_gating.hpp"

#include <ATen/ATen.h>

#include <cmath>
#include <limits>

namespace long3r {

at::Tensor apply_layer_norm(const at::Tensor& x, const LayerNormParams& p) {
  const bool in_float32 = x.is_cpu() && x.scalar_type() == at::kBFloat16 &&
                          (!p.weight.defined() || p.weight.scalar_type() == at::kBFloat16);
  auto param = [in_float32](const at::Tensor& t) -> c10::optional<at::Tensor> {
    if (!t.defined()) return c10::nullopt;
    return in_float32 ? t.to(at::kFloat) : t;
  };
  if (in_float32) {
    return at::layer_norm(x.to(at::kFloat), {x.size(-1)}, param(p.weight), param(p.bias), p.eps)
        .to(x.scalar_type());
  }
  const bool cast = p.weight.defined() && x.scalar_type() != p.weight.scalar_type();
  return at::layer_norm(cast ? x.to(p.weight.scalar_type()) : x, {x.size(-1)}, param(p.weight),
                        param(p.bias), p.eps);
}

GatedRead gated_read(const at::Tensor& queries, const at::Tensor& keys, const at::Tensor& values,
                     const GatingNorms& norms, std::optional<double> threshold,
                     const at::Tensor& valid) {
  const int64_t channels = queries.size(2);
  // Out-of-place throughout: memory snapshots stay unchanged and autograd keeps
  // what it needs.
  at::Tensor logits = at::matmul(apply_layer_norm(queries, norms.q),
                                 apply_layer_norm(keys, norms.k).transpose(1, 2)) /
                      static_cast<double>(std::sqrt(static_cast<float>(channels)));
  at::Tensor invalid;
  if (valid.defined()) {
    invalid = valid.logical_not().unsqueeze(1).to(logits.device());
    logits = logits.masked_fill(invalid, -std::numeric_limits<double>::infinity());
  }
  GatedRead r;
  // float32 weights whatever the precision: tau (5e-4) and the attention
  // statistics the memories accumulate need them.
  r.weights = at::softmax(logits, -1, at::kFloat);
  if (valid.defined()) {
    // Exact zeros at padding; also clears the NaN rows of a stream whose memory
    // is all padding.
    r.weights = r.weights.masked_fill(invalid, 0.0);
  }
  r.gated_weights = r.weights;
  if (threshold) {
    const at::Tensor gated = r.weights.masked_fill(r.weights < *threshold, 0.0);
    const at::Tensor row_sum = gated.sum(-1, /*keepdim=*/true);
    r.empty_rows = row_sum == 0;
    // A row with nothing left reads nothing instead of dividing 0 by 0.
    r.gated_weights = gated / row_sum.masked_fill(r.empty_rows, 1.0);
  }
  const at::Tensor v = apply_layer_norm(values, norms.v);
  r.readout = at::matmul(r.gated_weights.to(v.scalar_type()), v);
  return r;
}

GatingResult memory_gating(const at::Tensor& queries, const at::Tensor& keys,
                           const at::Tensor& values, const at::Tensor& features,
                           const GatingNorms& norms, double tau, bool training,
                           const at::Tensor& valid) {
  TORCH_CHECK(queries.dim() == 3, "memory_gating: queries must be [B,P,C]");
  TORCH_CHECK(keys.dim() == 3, "memory_gating: keys must be [B,S,C]");
  TORCH_CHECK(values.sizes() == keys.sizes(), "memory_gating: values must match keys");
  TORCH_CHECK(features.sizes() == queries.sizes(), "memory_gating: features must match queries");
  const int64_t batch = queries.size(0);
  const int64_t num_queries = queries.size(1);
  const int64_t channels = queries.size(2);
  const int64_t num_memory = keys.size(1);
  TORCH_CHECK(num_queries > 0, "memory_gating: no query tokens");
  TORCH_CHECK(keys.size(0) == batch && keys.size(2) == channels,
              "memory_gating: keys must be [B,S,C] with the queries' B and C");
  TORCH_CHECK(tau >= 0.0, "memory_gating: tau must be >= 0");
  if (valid.defined()) {
    TORCH_CHECK(valid.scalar_type() == at::kBool && valid.dim() == 2 && valid.size(0) == batch &&
                    valid.size(1) == num_memory,
                "memory_gating: valid must be a [B,S] bool mask");
  }

  // Training: threshold 0 as Spann3R trains (no zeroing, no renormalisation).
  const GatedRead read = gated_read(queries, keys, values, norms,
                                    training ? std::nullopt : std::optional<double>(tau), valid);
  GatingResult r;
  r.weights = read.weights;
  if (training) {
    // Every valid token takes part in the refined decoder.
    r.relevant_mask = valid.defined()
                          ? valid.to(read.weights.device())
                          : at::ones({batch, num_memory}, read.weights.options().dtype(at::kBool));
  } else {
    r.relevant_mask = std::get<0>(read.weights.max(1)) > tau;
  }
  r.gated_weights = read.gated_weights;
  r.fused = features + read.readout;
  r.attention_increment = r.gated_weights.sum(1);

  // Padded index form of R: relevant indices first in ascending order (stable
  // sort on "not relevant"), cut to the largest set, padding set to index 0.
  r.relevant_count = r.relevant_mask.sum(1);
  const int64_t max_count = num_memory == 0 ? 0 : r.relevant_count.max().item<int64_t>();
  const at::Tensor order = std::get<1>(at::sort(r.relevant_mask.logical_not().to(at::kInt),
                                                /*stable=*/true, /*dim=*/1, /*descending=*/false));
  r.relevant_valid = at::arange(max_count, r.relevant_count.options()).unsqueeze(0) <
                     r.relevant_count.unsqueeze(1);
  r.relevant_index = order.narrow(1, 0, max_count).masked_fill(r.relevant_valid.logical_not(), 0);
  return r;
}

at::Tensor gather_tokens(const at::Tensor& x, const at::Tensor& index) {
  TORCH_CHECK(x.dim() == 3, "gather_tokens: x must be [B,S,D]");
  TORCH_CHECK(index.dim() == 2 && index.size(0) == x.size(0),
              "gather_tokens: index must be [B,R] with the batch of x");
  return x.gather(1,
                  index.to(x.device()).unsqueeze(-1).expand({x.size(0), index.size(1), x.size(2)}));
}

}  // namespace long3r

// Optional capture of named intermediate tensors during inference (encoder
// blocks, decoder layers, DPT stages, memory reads, ...), for parity checks
// against reference outputs and for debugging. A default-constructed Trace is
// off and costs one branch per capture point.
//
// Names follow the golden-data conventions (docs in test/data/golden/README.md):
// "img1.enc_block0", "dec2.block3", "head1.refinenet4", ...; child() prepends a
// prefix so that a sub-module records under its caller's namespace.
#pragma once

#include <ATen/core/Tensor.h>

#include <map>
#include <string>
#include <utility>

namespace long3r {

using TensorMap = std::map<std::string, at::Tensor>;

class Trace {
 public:
  Trace() = default;  // off
  explicit Trace(TensorMap* sink, std::string prefix = "")
      : sink_(sink), prefix_(std::move(prefix)) {}

  bool enabled() const { return sink_ != nullptr; }
  // A trace recording under prefix() + p (off if this one is off).
  Trace child(const std::string& p) const {
    return enabled() ? Trace(sink_, prefix_ + p) : Trace();
  }
  const std::string& prefix() const { return prefix_; }

  // Stores a detached copy (so later in-place updates of `t` do not change
  // the record) under prefix() + name; replaces an earlier record.
  void put(const std::string& name, const at::Tensor& t) const;

 private:
  TensorMap* sink_ = nullptr;
  std::string prefix_;
};

}  // namespace long3r

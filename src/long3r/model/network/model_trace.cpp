// Trace capture; see include/long3r/model/network/model_trace.hpp.
#include "long3r/model/network/model_trace.hpp"

#include <ATen/ATen.h>

namespace long3r {

void Trace::put(const std::string& name, const at::Tensor& t) const {
  if (sink_ == nullptr) return;
  (*sink_)[prefix_ + name] = t.detach().clone(at::MemoryFormat::Contiguous);
}

}  // namespace long3r

// Strict checkpoint -> module loading; see include/long3r/model/loading/checkpoint.hpp.
//
// Name mapping: a file name that starts with `strip_prefix` loses it; a name
// that does not (with a non-empty prefix) is never matched. The result is
// dropped if it starts with one of `ignore_prefixes`; every other one must be
// a parameter or buffer of the module (named as named_parameters() /
// named_buffers() name them, recursively), and every parameter and buffer must
// be present.
//
// dtype policy: a tensor is loaded as the file declares it, never converted.
// An integer tensor must have its buffer's dtype. A floating tensor of the
// parameter's dtype is copied in; one of another floating dtype (a bfloat16
// or float16 checkpoint) replaces the parameter's data, which then has the
// file's dtype (the model converts once, to the precision it runs in:
// ModelShell). Integer <-> floating is an error.
//
// A tensor reachable under two names (one submodule registered twice, as the
// DPT head's `scratch.layerN_rn` / `scratch.layer_rn.{N-1}`) needs both names
// in the file, holding the same bits.
#include <torch/nn/module.h>
#include <torch/utils.h>

#include <algorithm>
#include <cstring>
#include <set>
#include <unordered_map>

#include "long3r/model/loading/checkpoint.hpp"
#include "long3r/model/loading/safetensors.hpp"

namespace long3r {

namespace {

constexpr std::size_t kMaxListedProblems = 50;

bool starts_with(const std::string& s, const std::string& prefix) {
  return s.size() >= prefix.size() && s.compare(0, prefix.size(), prefix) == 0;
}

std::string describe(const at::Tensor& t) {
  std::string s = std::string(c10::toString(t.scalar_type())) + " [";
  for (int64_t k = 0; k < t.dim(); ++k) s += (k ? ", " : "") + std::to_string(t.size(k));
  return s + "]";
}

// Bit equality of two tensors of equal dtype and shape.
bool same_bits(const at::Tensor& a, const at::Tensor& b) {
  if (a.scalar_type() != b.scalar_type() || !a.sizes().equals(b.sizes())) return false;
  const at::Tensor ca = a.detach().cpu().contiguous();
  const at::Tensor cb = b.detach().cpu().contiguous();
  const std::size_t n = static_cast<std::size_t>(ca.numel()) * ca.element_size();
  return n == 0 || std::memcmp(ca.data_ptr(), cb.data_ptr(), n) == 0;
}

struct Target {
  std::string name;
  at::Tensor tensor;
  const at::Tensor* source = nullptr;  // file tensor, once matched
};

}  // namespace

void load_module_strict(torch::nn::Module& module, const std::map<std::string, at::Tensor>& tensors,
                        const std::string& source_name, const std::string& strip_prefix,
                        const std::vector<std::string>& ignore_prefixes) {
  std::vector<Target> targets;
  for (const auto& kv : module.named_parameters(/*recurse=*/true)) {
    targets.push_back({kv.key(), kv.value()});
  }
  for (const auto& kv : module.named_buffers(/*recurse=*/true)) {
    targets.push_back({kv.key(), kv.value()});
  }

  // File name -> module name.
  std::map<std::string, const at::Tensor*> by_key;
  std::vector<std::string> unexpected;
  for (const auto& kv : tensors) {
    std::string key = kv.first;
    if (!strip_prefix.empty()) {
      if (!starts_with(key, strip_prefix)) {
        bool ignored = false;
        for (const std::string& p : ignore_prefixes) ignored = ignored || starts_with(key, p);
        if (!ignored) unexpected.push_back(kv.first + " (" + describe(kv.second) + ")");
        continue;
      }
      key = key.substr(strip_prefix.size());
    }
    bool ignored = false;
    for (const std::string& p : ignore_prefixes) ignored = ignored || starts_with(key, p);
    if (ignored) continue;
    by_key.emplace(key, &kv.second);
  }

  std::vector<std::string> problems;
  std::set<std::string> used;
  for (Target& t : targets) {
    const auto it = by_key.find(t.name);
    if (it == by_key.end()) {
      problems.push_back("missing: " + strip_prefix + t.name + " (module " + describe(t.tensor) +
                         ")");
      continue;
    }
    used.insert(t.name);
    const at::Tensor& src = *it->second;
    if (!src.defined()) {
      problems.push_back("undefined tensor: " + strip_prefix + t.name);
      continue;
    }
    bool ok = true;
    if (!src.sizes().equals(t.tensor.sizes())) {
      problems.push_back("shape mismatch: " + strip_prefix + t.name + ": file " + describe(src) +
                         ", module " + describe(t.tensor));
      ok = false;
    }
    const bool both_floating = src.is_floating_point() && t.tensor.is_floating_point();
    if (src.scalar_type() != t.tensor.scalar_type() && !both_floating) {
      problems.push_back("dtype mismatch: " + strip_prefix + t.name + ": file " +
                         c10::toString(src.scalar_type()) + ", module " +
                         c10::toString(t.tensor.scalar_type()) +
                         " (integer and floating tensors do not convert)");
      ok = false;
    }
    if (ok) t.source = &src;
  }
  for (const auto& kv : by_key) {
    if (used.count(kv.first) == 0) {
      unexpected.push_back(strip_prefix + kv.first + " (" + describe(*kv.second) + ")");
    }
  }
  std::sort(unexpected.begin(), unexpected.end());
  for (const std::string& u : unexpected) problems.push_back("unexpected: " + u);

  // Shared tensors: every name must carry the same bits, or which one wins
  // would depend on the copy order.
  std::unordered_map<const void*, const Target*> first_of;
  for (const Target& t : targets) {
    if (t.source == nullptr) continue;
    const auto ins = first_of.emplace(t.tensor.unsafeGetTensorImpl(), &t);
    if (!ins.second && !same_bits(*ins.first->second->source, *t.source)) {
      problems.push_back("conflicting values: " + strip_prefix + ins.first->second->name + " and " +
                         strip_prefix + t.name +
                         " are the same module tensor but differ in the file");
    }
  }

  if (!problems.empty()) {
    std::string msg = source_name + ": checkpoint does not match the module (" +
                      std::to_string(problems.size()) + " problem" +
                      (problems.size() == 1 ? "" : "s") + "):";
    for (std::size_t i = 0; i < problems.size() && i < kMaxListedProblems; ++i) {
      msg += "\n  " + problems[i];
    }
    if (problems.size() > kMaxListedProblems) {
      msg += "\n  ... and " + std::to_string(problems.size() - kMaxListedProblems) + " more";
    }
    throw CheckpointError(msg);
  }

  torch::NoGradGuard no_grad;
  for (Target& t : targets) {
    if (t.source->scalar_type() == t.tensor.scalar_type()) {
      t.tensor.copy_(*t.source);
    } else {
      t.tensor.set_data(t.source->to(t.tensor.device(), t.source->scalar_type(),
                                     /*non_blocking=*/false, /*copy=*/true));
    }
    release_mapped(*t.source);  // a mapped file's pages go as soon as they are copied
  }
}

}  // namespace long3r

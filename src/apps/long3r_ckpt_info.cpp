// long3r_ckpt_info: validates a safetensors checkpoint and prints its
// metadata (the model config pretty-printed when it is JSON) and a table of
// its tensors. Exits 1 with the error message if the file is unreadable or
// invalid, 2 on bad usage.
#include <ATen/ATen.h>

#include <cstdio>
#include <cstring>
#include <iostream>
#include <nlohmann/json.hpp>
#include <string>

#include "long3r/config/cli_options.hpp"
#include "long3r/model/loading/safetensors.hpp"

namespace {

std::string shape_string(const at::Tensor& t) {
  std::string s = "[";
  for (int64_t k = 0; k < t.dim(); ++k) s += (k ? ", " : "") + std::to_string(t.size(k));
  return s + "]";
}

const char* safetensors_dtype(const at::Tensor& t) {
  switch (t.scalar_type()) {
    case at::kFloat:
      return "F32";
    case at::kHalf:
      return "F16";
    case at::kBFloat16:
      return "BF16";
    case at::kLong:
      return "I64";
    default:
      return "?";
  }
}

}  // namespace

int main(int argc, char** argv) {
  bool tensors = true, metadata = true;
  std::string path;
  long3r::CliOptions cli("long3r_ckpt_info",
                         "Validates the file and prints its metadata and tensor table.");
  cli.positional("FILE.safetensors", &path, "the checkpoint").required();
  cli.flag("--no-tensors", &tensors, "leave out the tensor table (the totals stay)", false);
  cli.flag("--no-metadata", &metadata, "leave out the metadata", false);
  if (const auto rc = cli.parse_or_exit(argc, argv)) return *rc;

  long3r::TensorFile f;
  try {
    f = long3r::load_safetensors(path);
  } catch (const std::exception& e) {
    std::cerr << "error: " << e.what() << "\n";
    return 1;
  }

  if (metadata) {
    std::cout << "metadata (" << f.metadata.size() << " keys):\n";
    for (const auto& kv : f.metadata) {
      std::string shown = kv.second;
      // Pretty-print JSON values (the model config); leave other strings as is.
      try {
        const auto v = nlohmann::ordered_json::parse(kv.second);
        if (v.is_object() || v.is_array()) shown = v.dump(2);
      } catch (const nlohmann::ordered_json::exception&) {
      }
      std::cout << "  " << kv.first << ": " << shown << "\n";
    }
  }

  uint64_t total = 0;
  std::size_t name_w = 4;
  for (const auto& kv : f.tensors) name_w = std::max(name_w, kv.first.size());
  if (tensors) {
    std::printf("%-*s  %-5s  %-20s  %12s\n", static_cast<int>(name_w), "name", "dtype", "shape",
                "bytes");
  }
  for (const auto& kv : f.tensors) {
    const uint64_t bytes = static_cast<uint64_t>(kv.second.numel()) * kv.second.element_size();
    total += bytes;
    if (tensors) {
      std::printf("%-*s  %-5s  %-20s  %12llu\n", static_cast<int>(name_w), kv.first.c_str(),
                  safetensors_dtype(kv.second), shape_string(kv.second).c_str(),
                  static_cast<unsigned long long>(bytes));
    }
  }
  std::printf("%zu tensors, %llu bytes of tensor data\n", f.tensors.size(),
              static_cast<unsigned long long>(total));
  return 0;
}

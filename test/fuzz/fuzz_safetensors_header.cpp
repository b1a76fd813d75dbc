// Fuzz entry point for the torch-free checkpoint I/O: the safetensors header
// validator and the JSON (nlohmann) parse / dump round trip. Built with libFuzzer under clang
// (cmake/Long3rFuzzers.cmake) and, with test/fuzz/replay_main.cpp, as a plain
// corpus-replay test under any compiler (test/fuzz/fuzz.cmake).
//
// Expected rejections (CheckpointError, nlohmann parse errors) are fine; anything else
// escaping, a sanitizer report, or a broken invariant (__builtin_trap) is a
// bug.
#include <cstddef>
#include <cstdint>
#include <nlohmann/json.hpp>
#include <string>

#include "long3r/io/safetensors_header.hpp"

namespace {

void check(bool ok) {
  if (!ok) __builtin_trap();
}

// What a successful parse promises to the loader.
void check_header(const long3r::SafetensorsHeader& h, uint64_t file_size) {
  check(h.data_offset >= 8 && h.data_offset <= file_size);
  const uint64_t data_size = file_size - h.data_offset;
  uint64_t prev_end = 0;
  for (std::size_t i = 0; i < h.tensors.size(); ++i) {
    const auto& t = h.tensors[i];
    check(t.begin <= t.end && t.end <= data_size);
    uint64_t bytes = long3r::dtype_size(t.dtype);
    int64_t span = static_cast<int64_t>(bytes);  // contiguous strides fit in int64
    for (const int64_t d : t.shape) {
      check(d >= 0);
      check(!__builtin_mul_overflow(span, d > 1 ? d : 1, &span));
      check(!__builtin_mul_overflow(bytes, static_cast<uint64_t>(d), &bytes));
    }
    check(bytes == t.end - t.begin);
    if (i > 0) check(h.tensors[i - 1].begin <= t.begin);
    if (t.begin != t.end) {
      check(t.begin >= prev_end);
      prev_end = t.end;
    }
  }
}

void fuzz_json(const char* p, std::size_t n) {
  using Json = nlohmann::ordered_json;
  Json v = Json::parse(p, p + n, nullptr, /*allow_exceptions=*/false);
  if (v.is_discarded()) return;
  // Whatever parses (valid UTF-8 included) must serialise and parse back to an
  // equal value.
  check(Json::parse(v.dump()) == v);
  check(Json::parse(v.dump(1)) == v);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, std::size_t size) {
  // As a whole file.
  try {
    check_header(long3r::parse_safetensors_header(data, size, size), size);
  } catch (const long3r::CheckpointError&) {
  }
  // As the header read from a larger file: nothing past `size` may be read.
  try {
    check_header(long3r::parse_safetensors_header(data, size, size + 4096), size + 4096);
  } catch (const long3r::CheckpointError&) {
  }
  // The JSON parser on the whole input and on the header region of a
  // safetensors-like input.
  const char* p = reinterpret_cast<const char*>(data);
  fuzz_json(p, size);
  if (size > 8) {
    const uint64_t n = long3r::decode_header_length(data);
    fuzz_json(p + 8, static_cast<std::size_t>(n < size - 8 ? n : size - 8));
  }
  return 0;
}

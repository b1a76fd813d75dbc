// safetensors header parsing and validation, torch-free so it can be fuzzed
// on its own.
//
// Layout: 8-byte little-endian u64 header length N, N bytes of JSON
// {name: {"dtype", "shape", "data_offsets": [begin, end]}, "__metadata__": {str: str}},
// then the raw little-endian tensor bytes; offsets are relative to byte 8 + N.
#pragma once

#include <cstddef>
#include <cstdint>
#include <map>
#include <stdexcept>
#include <string>
#include <vector>

namespace long3r {

// Any problem with a checkpoint file: unreadable, corrupt, hostile, or not
// matching the model it is loaded into.
class CheckpointError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// F64 and U8 carry sessions' stamps, poses and colours (pipeline/session.hpp).
enum class DType { kF32, kF16, kBF16, kI64, kF64, kU8 };
const char* dtype_name(DType d);
std::size_t dtype_size(DType d);

struct TensorEntry {
  std::string name;
  DType dtype = DType::kF32;
  std::vector<int64_t> shape;
  uint64_t begin = 0;  // byte range inside the data section
  uint64_t end = 0;
};

struct SafetensorsHeader {
  std::vector<TensorEntry> tensors;  // sorted by begin offset
  std::map<std::string, std::string> metadata;
  uint64_t data_offset = 0;  // absolute file offset of the data section
};

// Largest accepted header (JSON) length; real headers are well below 1 MB.
constexpr uint64_t kMaxSafetensorsHeaderBytes = 100ull << 20;

// The 8-byte little-endian header length at the start of a file (`p` holds at
// least 8 bytes), and its encoding.
uint64_t decode_header_length(const uint8_t* p);
void encode_header_length(uint64_t n, uint8_t out[8]);

// A JSON string literal of `s` (quotes included), for messages naming tensors.
std::string quoted(const std::string& s);

// Validates everything that can be checked before touching tensor data: the
// header length bound, JSON syntax (strict: no comments, byte-order mark,
// invalid UTF-8 or lone surrogates; at most 8 levels deep), duplicate keys at
// any level, known dtypes, shape x itemsize == byte
// range, ranges inside the file and non-overlapping. `data` holds at least the
// first min(size, 8 + N) bytes; `file_size` is the whole file's size.
SafetensorsHeader parse_safetensors_header(const uint8_t* data, std::size_t size,
                                           uint64_t file_size);

}  // namespace long3r

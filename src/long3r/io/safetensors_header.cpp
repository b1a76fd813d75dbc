// safetensors header validation; see include/long3r/io/safetensors_header.hpp.
//
// Rules beyond the format's own: only F32/F16/BF16/I64 tensors, at most
// kMaxTensorRank dimensions, every field present and no unknown ones,
// duplicate tensor names rejected, tensor byte ranges must not overlap (gaps
// between them are tolerated), and `__metadata__` maps strings to strings.
#include <algorithm>
#include <set>

#include "long3r/io/json.hpp"
#include "long3r/io/safetensors_header.hpp"

namespace long3r {

namespace {

constexpr std::size_t kMaxTensorRank = 16;

[[noreturn]] void fail(const std::string& what) { throw CheckpointError(what); }

[[noreturn]] void fail_tensor(const std::string& name, const std::string& what) {
  fail("tensor " + json::quote(name) + ": " + what);
}

bool parse_dtype(const std::string& s, DType* d) {
  if (s == "F32") {
    *d = DType::kF32;
  } else if (s == "F16") {
    *d = DType::kF16;
  } else if (s == "BF16") {
    *d = DType::kBF16;
  } else if (s == "I64") {
    *d = DType::kI64;
  } else {
    return false;
  }
  return true;
}

std::string shape_string(const std::vector<int64_t>& shape) {
  std::string s = "[";
  for (std::size_t i = 0; i < shape.size(); ++i) s += (i ? ", " : "") + std::to_string(shape[i]);
  return s + "]";
}

TensorEntry parse_entry(const std::string& name, const json::Value& v, uint64_t data_size) {
  if (!v.is_object()) {
    fail_tensor(
        name, std::string("entry has type ") + json::type_name(v.type()) + ", expected an object");
  }
  const json::Value* dtype = nullptr;
  const json::Value* shape = nullptr;
  const json::Value* offsets = nullptr;
  for (const json::Member& m : v.as_object()) {
    if (m.first == "dtype") {
      dtype = &m.second;
    } else if (m.first == "shape") {
      shape = &m.second;
    } else if (m.first == "data_offsets") {
      offsets = &m.second;
    } else {
      fail_tensor(name, "unknown field " + json::quote(m.first));
    }
  }
  if (dtype == nullptr) fail_tensor(name, "missing field \"dtype\"");
  if (shape == nullptr) fail_tensor(name, "missing field \"shape\"");
  if (offsets == nullptr) fail_tensor(name, "missing field \"data_offsets\"");

  TensorEntry e;
  e.name = name;
  if (!dtype->is_string()) fail_tensor(name, "\"dtype\" is not a string");
  if (!parse_dtype(dtype->as_string(), &e.dtype)) {
    fail("unsupported dtype " + json::quote(dtype->as_string()) + " for tensor " +
         json::quote(name) + " (supported: F32, F16, BF16, I64)");
  }

  if (!shape->is_array()) fail_tensor(name, "\"shape\" is not a list");
  if (shape->size() > kMaxTensorRank) {
    fail_tensor(name, "rank " + std::to_string(shape->size()) + " exceeds the limit of " +
                          std::to_string(kMaxTensorRank));
  }
  // The byte size of the tensor with every empty dimension counted as 1 must
  // fit in int64: otherwise the contiguous strides (and, for non-empty
  // tensors, the byte count) overflow, even when a zero makes it empty.
  int64_t span = static_cast<int64_t>(dtype_size(e.dtype));
  bool empty = false;
  for (const json::Value& d : shape->as_array()) {
    if (!d.is_int()) fail_tensor(name, "\"shape\" holds a non-integer: " + d.dump());
    const int64_t dim = d.as_int();
    if (dim < 0) fail_tensor(name, "negative dimension " + std::to_string(dim) + " in shape");
    e.shape.push_back(dim);
    empty = empty || dim == 0;
    if (__builtin_mul_overflow(span, std::max<int64_t>(dim, 1), &span)) {
      fail_tensor(name, "shape " + shape->dump() + " overflows the byte count");
    }
  }
  const uint64_t nbytes = empty ? 0 : static_cast<uint64_t>(span);

  if (!offsets->is_array() || offsets->size() != 2) {
    fail_tensor(name, "\"data_offsets\" is not a list [begin, end]");
  }
  const json::Value& b = offsets->at(0);
  const json::Value& en = offsets->at(1);
  if (!b.is_int() || !en.is_int() || b.as_int() < 0 || en.as_int() < 0) {
    fail_tensor(name, "\"data_offsets\" " + offsets->dump() + " are not non-negative integers");
  }
  e.begin = static_cast<uint64_t>(b.as_int());
  e.end = static_cast<uint64_t>(en.as_int());
  if (e.begin > e.end) {
    fail_tensor(
        name, "data_offsets begin " + std::to_string(e.begin) + " > end " + std::to_string(e.end));
  }
  if (e.end - e.begin != nbytes) {
    fail_tensor(name, "data_offsets " + offsets->dump() + " span " +
                          std::to_string(e.end - e.begin) + " bytes but " + dtype_name(e.dtype) +
                          " " + shape_string(e.shape) + " needs " + std::to_string(nbytes));
  }
  if (e.end > data_size) {
    fail_tensor(name, "data_offsets end " + std::to_string(e.end) +
                          " is past the end of the data section (" + std::to_string(data_size) +
                          " bytes); the file is truncated or corrupt");
  }
  return e;
}

}  // namespace

SafetensorsHeader parse_safetensors_header(const uint8_t* data, std::size_t size,
                                           uint64_t file_size) {
  if (file_size < 8 || size < 8) {
    fail("file too short (" + std::to_string(std::min<uint64_t>(file_size, size)) +
         " bytes) to hold the 8-byte header length");
  }
  uint64_t n = 0;
  for (int i = 7; i >= 0; --i) n = (n << 8) | data[i];  // little-endian u64
  if (n > kMaxSafetensorsHeaderBytes) {
    fail("header length " + std::to_string(n) + " exceeds the limit of " +
         std::to_string(kMaxSafetensorsHeaderBytes) + " bytes (not a safetensors file?)");
  }
  if (n > file_size - 8) {
    fail("header length " + std::to_string(n) + " exceeds the " + std::to_string(file_size - 8) +
         " bytes that follow it; the file is truncated or not a safetensors file");
  }
  if (size - 8 < n) {
    fail("only " + std::to_string(size - 8) + " of the " + std::to_string(n) +
         " header bytes were provided");
  }

  json::ParseOptions opt;
  opt.max_depth = 8;  // the format needs 3 levels
  opt.max_size = kMaxSafetensorsHeaderBytes;
  opt.allow_duplicate_keys = true;  // reported below with the tensor name
  // About 10 values per tensor: room for 400k tensors, while a hostile
  // 100 MB header cannot make the parser allocate more than ~0.5 GB.
  opt.max_values = 4'000'000;
  json::Value root;
  try {
    root = json::parse(reinterpret_cast<const char*>(data + 8), static_cast<std::size_t>(n), opt);
  } catch (const json::ParseError& e) {
    fail(std::string("header is not valid JSON: ") + e.what() + " (file offset " +
         std::to_string(8 + e.offset()) + ")");
  }
  if (!root.is_object()) {
    fail(std::string("header has JSON type ") + json::type_name(root.type()) +
         ", expected an object");
  }

  SafetensorsHeader h;
  h.data_offset = 8 + n;
  const uint64_t data_size = file_size - h.data_offset;
  std::set<std::string> seen;
  bool have_metadata = false;
  for (const json::Member& m : root.as_object()) {
    if (m.first == "__metadata__") {
      if (have_metadata) fail("duplicate \"__metadata__\" entry");
      have_metadata = true;
      if (!m.second.is_object()) fail("\"__metadata__\" is not an object");
      for (const json::Member& kv : m.second.as_object()) {
        if (!kv.second.is_string()) {
          fail("\"__metadata__\" value for " + json::quote(kv.first) + " has type " +
               json::type_name(kv.second.type()) + ", expected a string");
        }
        if (!h.metadata.emplace(kv.first, kv.second.as_string()).second) {
          fail("duplicate \"__metadata__\" key " + json::quote(kv.first));
        }
      }
      continue;
    }
    if (!seen.insert(m.first).second) fail("duplicate tensor name " + json::quote(m.first));
    h.tensors.push_back(parse_entry(m.first, m.second, data_size));
  }

  std::sort(h.tensors.begin(), h.tensors.end(), [](const TensorEntry& a, const TensorEntry& b) {
    if (a.begin != b.begin) return a.begin < b.begin;
    if (a.end != b.end) return a.end < b.end;
    return a.name < b.name;
  });
  // Empty tensors occupy no bytes and overlap nothing.
  const TensorEntry* prev = nullptr;
  for (const TensorEntry& t : h.tensors) {
    if (t.begin == t.end) continue;
    if (prev != nullptr && t.begin < prev->end) {
      fail("tensors " + json::quote(prev->name) + " [" + std::to_string(prev->begin) + ", " +
           std::to_string(prev->end) + ") and " + json::quote(t.name) + " [" +
           std::to_string(t.begin) + ", " + std::to_string(t.end) + ") overlap");
    }
    prev = &t;
  }
  return h;
}

}  // namespace long3r

// safetensors header validation; see include/long3r/io/safetensors_header.hpp.
//
// Rules beyond the format's own: only F32/F16/BF16/I64 tensors, at most
// kMaxTensorRank dimensions, every field present and no unknown ones,
// duplicate keys rejected (tensor names, metadata keys, fields), tensor byte
// ranges must not overlap (gaps between them are tolerated), and
// `__metadata__` maps strings to strings.
//
// nlohmann keeps the last of duplicate keys silently, so its parser callback
// watches every key as it is read; the same callback bounds the nesting depth
// and the number of values.
#include <algorithm>
#include <nlohmann/json.hpp>
#include <set>
#include <vector>

#include "long3r/io/safetensors_header.hpp"

namespace long3r {

namespace {

using Json = nlohmann::ordered_json;

constexpr std::size_t kMaxTensorRank = 16;
// The format needs 3 levels (root, entry, shape / offsets).
constexpr int kMaxDepth = 8;
// About 10 values per tensor: room for 400k tensors, while a hostile 100 MB
// header cannot make the parser allocate more than ~0.5 GB.
constexpr std::size_t kMaxValues = 4'000'000;

[[noreturn]] void fail(const std::string& what) { throw CheckpointError(what); }

[[noreturn]] void fail_tensor(const std::string& name, const std::string& what) {
  fail("tensor " + quoted(name) + ": " + what);
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
  } else if (s == "F64") {
    *d = DType::kF64;
  } else if (s == "U8") {
    *d = DType::kU8;
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

// Integer written without fraction or exponent that fits in int64.
bool is_int64(const Json& v) {
  if (v.is_number_unsigned()) return v.get<uint64_t>() <= static_cast<uint64_t>(INT64_MAX);
  return v.is_number_integer();
}

TensorEntry parse_entry(const std::string& name, const Json& v, uint64_t data_size) {
  if (!v.is_object()) {
    fail_tensor(name, std::string("entry has type ") + v.type_name() + ", expected an object");
  }
  const Json* dtype = nullptr;
  const Json* shape = nullptr;
  const Json* offsets = nullptr;
  for (const auto& m : v.items()) {
    if (m.key() == "dtype") {
      dtype = &m.value();
    } else if (m.key() == "shape") {
      shape = &m.value();
    } else if (m.key() == "data_offsets") {
      offsets = &m.value();
    } else {
      fail_tensor(name, "unknown field " + quoted(m.key()));
    }
  }
  if (dtype == nullptr) fail_tensor(name, "missing field \"dtype\"");
  if (shape == nullptr) fail_tensor(name, "missing field \"shape\"");
  if (offsets == nullptr) fail_tensor(name, "missing field \"data_offsets\"");

  TensorEntry e;
  e.name = name;
  if (!dtype->is_string()) fail_tensor(name, "\"dtype\" is not a string");
  if (!parse_dtype(dtype->get<std::string>(), &e.dtype)) {
    fail("unsupported dtype " + quoted(dtype->get<std::string>()) + " for tensor " + quoted(name) +
         " (supported: F32, F16, BF16, I64)");
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
  for (const Json& d : *shape) {
    if (!is_int64(d)) fail_tensor(name, "\"shape\" holds a non-integer: " + d.dump());
    const int64_t dim = d.get<int64_t>();
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
  const Json& b = (*offsets)[0];
  const Json& en = (*offsets)[1];
  if (!is_int64(b) || !is_int64(en) || b.get<int64_t>() < 0 || en.get<int64_t>() < 0) {
    fail_tensor(name, "\"data_offsets\" " + offsets->dump() + " are not non-negative integers");
  }
  e.begin = static_cast<uint64_t>(b.get<int64_t>());
  e.end = static_cast<uint64_t>(en.get<int64_t>());
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

// Rejects duplicate keys (with the tensor or metadata key they belong to),
// nesting deeper than kMaxDepth and more than kMaxValues values while
// nlohmann parses.
class HeaderWatch {
 public:
  bool operator()(int depth, Json::parse_event_t event, Json& parsed) {
    switch (event) {
      case Json::parse_event_t::object_start:
      case Json::parse_event_t::array_start:
        if (depth >= kMaxDepth) {
          fail("header nesting is deeper than " + std::to_string(kMaxDepth) + " levels");
        }
        count_value();
        if (event == Json::parse_event_t::object_start) {
          keys_.emplace_back();
          owners_.push_back(depth == 1 ? last_root_key_ : std::string());
        } else {
          keys_.emplace_back();
          owners_.push_back("[]");
        }
        break;
      case Json::parse_event_t::object_end:
      case Json::parse_event_t::array_end:
        keys_.pop_back();
        owners_.pop_back();
        break;
      case Json::parse_event_t::key: {
        const std::string& k = parsed.get_ref<const std::string&>();
        if (!keys_.back().insert(k).second) duplicate(depth, k);
        if (depth == 1) last_root_key_ = k;
        break;
      }
      case Json::parse_event_t::value:
        count_value();
        break;
    }
    return true;
  }

 private:
  void count_value() {
    if (++values_ > kMaxValues) {
      fail("header holds more than " + std::to_string(kMaxValues) + " JSON values");
    }
  }
  [[noreturn]] void duplicate(int depth, const std::string& k) const {
    if (depth == 1) {
      if (k == "__metadata__") fail("duplicate \"__metadata__\" entry");
      fail("duplicate tensor name " + quoted(k));
    }
    const std::string& owner = owners_.back();
    if (depth == 2 && owner == "__metadata__") fail("duplicate \"__metadata__\" key " + quoted(k));
    if (depth == 2) fail_tensor(owner, "duplicate field " + quoted(k));
    fail("duplicate key " + quoted(k) + " in the header");
  }

  std::vector<std::set<std::string>> keys_;  // per open object (arrays: empty)
  std::vector<std::string> owners_;          // root key an open object belongs to
  std::string last_root_key_;
  std::size_t values_ = 0;
};

}  // namespace

uint64_t decode_header_length(const uint8_t* p) {
  uint64_t n = 0;
  for (int i = 7; i >= 0; --i) n = (n << 8) | p[i];
  return n;
}

void encode_header_length(uint64_t n, uint8_t out[8]) {
  for (int i = 0; i < 8; ++i, n >>= 8) out[i] = static_cast<uint8_t>(n & 0xFF);
}

std::string quoted(const std::string& s) {
  return Json(s).dump(-1, ' ', false, Json::error_handler_t::replace);
}

SafetensorsHeader parse_safetensors_header(const uint8_t* data, std::size_t size,
                                           uint64_t file_size) {
  if (file_size < 8 || size < 8) {
    fail("file too short (" + std::to_string(std::min<uint64_t>(file_size, size)) +
         " bytes) to hold the 8-byte header length");
  }
  const uint64_t n = decode_header_length(data);
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

  const uint8_t* begin = data + 8;
  const uint8_t* end = begin + n;
  // nlohmann skips a UTF-8 byte-order mark; JSON text (RFC 8259) has none.
  if (n >= 3 && begin[0] == 0xEF && begin[1] == 0xBB && begin[2] == 0xBF) {
    fail("header is not valid JSON: byte-order mark (file offset 8)");
  }
  Json root;
  try {
    root = Json::parse(begin, end, HeaderWatch(), /*allow_exceptions=*/true,
                       /*ignore_comments=*/false);
  } catch (const Json::parse_error& e) {
    // e.byte counts the bytes read, the offending one included.
    const std::size_t at = e.byte > 0 ? e.byte - 1 : 0;
    fail(std::string("header is not valid JSON: ") + e.what() + " (file offset " +
         std::to_string(8 + at) + ")");
  } catch (const Json::exception& e) {  // e.g. a number out of the double range
    fail(std::string("header is not valid JSON: ") + e.what());
  }
  if (!root.is_object()) {
    fail(std::string("header has JSON type ") + root.type_name() + ", expected an object");
  }

  SafetensorsHeader h;
  h.data_offset = 8 + n;
  const uint64_t data_size = file_size - h.data_offset;
  for (const auto& m : root.items()) {
    if (m.key() == "__metadata__") {
      if (!m.value().is_object()) fail("\"__metadata__\" is not an object");
      for (const auto& kv : m.value().items()) {
        if (!kv.value().is_string()) {
          fail("\"__metadata__\" value for " + quoted(kv.key()) + " has type " +
               kv.value().type_name() + ", expected a string");
        }
        h.metadata.emplace(kv.key(), kv.value().get<std::string>());
      }
      continue;
    }
    h.tensors.push_back(parse_entry(m.key(), m.value(), data_size));
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
      fail("tensors " + quoted(prev->name) + " [" + std::to_string(prev->begin) + ", " +
           std::to_string(prev->end) + ") and " + quoted(t.name) + " [" + std::to_string(t.begin) +
           ", " + std::to_string(t.end) + ") overlap");
    }
    prev = &t;
  }
  return h;
}

}  // namespace long3r

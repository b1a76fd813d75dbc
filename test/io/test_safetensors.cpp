// Tests of safetensors header validation (corrupt and hostile files), of
// load_safetensors / save_safetensors round trips, and of reading every golden
// checkpoint and io file.
#include <ATen/ATen.h>
#include <gtest/gtest.h>
#include <stdlib.h>
#include <sys/stat.h>
#include <unistd.h>

#include <dirent.h>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <nlohmann/json.hpp>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "long3r/model/loading/safetensors.hpp"

namespace {

using long3r::CheckpointError;
using long3r::parse_safetensors_header;

const std::string kGolden = std::string(LONG3R_GOLDEN_DIR) + "/";
const char* const kCases[] = {"dust3r_pair_sq224", "dust3r_pair_land112x80",
                              "dust3r_pair_port80x112", "spann3r_seq_sq224",
                              "spann3r_seq_land96x64"};

std::string le64(uint64_t n) {
  std::string s(8, '\0');
  for (int i = 0; i < 8; ++i) s[i] = static_cast<char>((n >> (8 * i)) & 0xFF);
  return s;
}

// A file image: length field, header, data.
std::string file_image(const std::string& header, const std::string& data) {
  return le64(header.size()) + header + data;
}

// Message of the CheckpointError thrown by parsing the first `size` bytes of
// `bytes` as a whole file, or "" if none.
std::string parse_error(const std::string& bytes, std::size_t size) {
  try {
    parse_safetensors_header(reinterpret_cast<const uint8_t*>(bytes.data()), size, size);
  } catch (const CheckpointError& e) {
    return e.what();
  }
  return "";
}

std::string parse_error(const std::string& bytes) { return parse_error(bytes, bytes.size()); }

std::string header_error(const std::string& header, std::size_t data_size = 64) {
  return parse_error(file_image(header, std::string(data_size, '\0')));
}

#define EXPECT_CONTAINS(haystack, needle)                          \
  EXPECT_NE(std::string(haystack).find(needle), std::string::npos) \
      << "expected \"" << (needle) << "\" in: \"" << (haystack) << "\""

std::string read_file(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

void write_file(const std::string& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

// A fresh empty folder per test.
class TempDir {
 public:
  TempDir() {
    std::string tmpl = ::testing::TempDir() + "long3r_st_XXXXXX";
    std::vector<char> buf(tmpl.begin(), tmpl.end());
    buf.push_back('\0');
    if (::mkdtemp(buf.data()) == nullptr) throw std::runtime_error("mkdtemp failed");
    path_ = buf.data();
  }
  ~TempDir() {
    for (const std::string& f : files()) ::unlink((path_ + "/" + f).c_str());
    ::rmdir(path_.c_str());
  }
  std::string file(const std::string& name) const { return path_ + "/" + name; }
  std::vector<std::string> files() const {
    std::vector<std::string> out;
    if (DIR* d = ::opendir(path_.c_str())) {
      while (dirent* e = ::readdir(d)) {
        const std::string n = e->d_name;
        if (n != "." && n != "..") out.push_back(n);
      }
      ::closedir(d);
    }
    return out;
  }

 private:
  std::string path_;
};

bool same_bits(const at::Tensor& a, const at::Tensor& b) {
  if (a.scalar_type() != b.scalar_type() || !a.sizes().equals(b.sizes())) return false;
  const at::Tensor ca = a.contiguous(), cb = b.contiguous();
  const std::size_t n = static_cast<std::size_t>(ca.numel()) * ca.element_size();
  return n == 0 || std::memcmp(ca.data_ptr(), cb.data_ptr(), n) == 0;
}

const char* kTwoTensors =
    R"({"__metadata__": {"k": "v"}, "b": {"dtype": "F32", "shape": [2], "data_offsets": [8, 16]},)"
    R"( "a": {"dtype": "I64", "shape": [1], "data_offsets": [0, 8]}})";

}  // namespace

TEST(SafetensorsHeader, ValidHeaderIsParsedAndSortedByOffset) {
  const std::string bytes = file_image(kTwoTensors, std::string(16, '\0'));
  const auto h = parse_safetensors_header(reinterpret_cast<const uint8_t*>(bytes.data()),
                                          bytes.size(), bytes.size());
  ASSERT_EQ(h.tensors.size(), 2u);
  EXPECT_EQ(h.tensors[0].name, "a");
  EXPECT_EQ(h.tensors[0].dtype, long3r::DType::kI64);
  EXPECT_EQ(h.tensors[1].name, "b");
  EXPECT_EQ(h.tensors[1].shape, std::vector<int64_t>{2});
  EXPECT_EQ(h.tensors[1].begin, 8u);
  EXPECT_EQ(h.tensors[1].end, 16u);
  EXPECT_EQ(h.metadata.at("k"), "v");
  EXPECT_EQ(h.data_offset, 8 + std::strlen(kTwoTensors));
}

TEST(SafetensorsHeader, FileShorterThanLengthField) {
  for (std::size_t n = 0; n < 8; ++n) {
    EXPECT_CONTAINS(parse_error(std::string(n, '\0')), "too short");
  }
}

TEST(SafetensorsHeader, HugeOrInconsistentHeaderLength) {
  EXPECT_CONTAINS(parse_error(le64(UINT64_MAX) + "{}"), "exceeds the limit");
  EXPECT_CONTAINS(parse_error(le64((100u << 20) + 1) + "{}"), "exceeds the limit");
  EXPECT_CONTAINS(parse_error(le64(3) + "{}"), "exceeds the 2 bytes");
  EXPECT_EQ(parse_error(le64(2) + "{}"), "");
  // The caller passed fewer bytes than the header needs.
  const std::string bytes = le64(2) + "{}";
  EXPECT_THROW(parse_safetensors_header(reinterpret_cast<const uint8_t*>(bytes.data()), 9, 10),
               CheckpointError);
}

TEST(SafetensorsHeader, TruncatedAtEveryCutPoint) {
  const std::string full = file_image(kTwoTensors, std::string(16, '\x11'));
  ASSERT_EQ(parse_error(full), "");
  for (std::size_t cut = 0; cut < full.size(); ++cut) {
    EXPECT_NE(parse_error(full.substr(0, cut)), "") << "cut at " << cut;
  }
}

TEST(SafetensorsHeader, GoldenFileTruncatedAtManyCutPoints) {
  const std::string full = read_file(kGolden + "dust3r_pair_sq224/weights.safetensors");
  ASSERT_GT(full.size(), 100000u);
  ASSERT_EQ(parse_error(full), "");
  std::vector<std::size_t> cuts;
  for (std::size_t c = 0; c < 64; ++c) cuts.push_back(c);
  for (std::size_t c = 64; c < full.size(); c += 2999) cuts.push_back(c);
  cuts.push_back(full.size() - 1);
  for (std::size_t cut : cuts) {
    EXPECT_NE(parse_error(full, cut), "") << "cut at " << cut;
  }
}

TEST(SafetensorsHeader, BadJson) {
  EXPECT_CONTAINS(header_error("{"), "not valid JSON");
  EXPECT_CONTAINS(header_error(R"({"a": })"), "file offset 14");  // 8 + 6
  EXPECT_CONTAINS(header_error(R"({"a": {"dtype": "F32",}})"), "not valid JSON");
  EXPECT_CONTAINS(header_error("[]"), "expected an object");
  EXPECT_CONTAINS(header_error("\"x\""), "expected an object");
  EXPECT_CONTAINS(header_error(std::string(64, '[') + std::string(64, ']')), "nesting");
  EXPECT_CONTAINS(header_error(""), "not valid JSON");
}

TEST(SafetensorsHeader, UnsupportedOrBadDtype) {
  EXPECT_CONTAINS(header_error(R"({"w": {"dtype": "C64", "shape": [1], "data_offsets": [0, 8]}})"),
                  "unsupported dtype \"C64\" for tensor \"w\"");
  EXPECT_CONTAINS(header_error(R"({"w": {"dtype": "f32", "shape": [1], "data_offsets": [0, 4]}})"),
                  "unsupported dtype \"f32\"");
  EXPECT_CONTAINS(header_error(R"({"w": {"dtype": 4, "shape": [1], "data_offsets": [0, 4]}})"),
                  "tensor \"w\": \"dtype\" is not a string");
}

TEST(SafetensorsHeader, ShapeAndOffsetsDisagree) {
  const std::string e =
      header_error(R"({"w": {"dtype": "F32", "shape": [2, 3], "data_offsets": [0, 20]}})");
  EXPECT_CONTAINS(e, "tensor \"w\"");
  EXPECT_CONTAINS(e, "span 20 bytes");
  EXPECT_CONTAINS(e, "needs 24");
  EXPECT_CONTAINS(header_error(R"({"w": {"dtype": "BF16", "shape": [3], "data_offsets": [0, 8]}})"),
                  "needs 6");
}

TEST(SafetensorsHeader, OffsetsOutOfRange) {
  EXPECT_CONTAINS(
      header_error(R"({"w": {"dtype": "F32", "shape": [4], "data_offsets": [56, 72]}})", 64),
      "past the end of the data section (64 bytes)");
  EXPECT_CONTAINS(header_error(R"({"w": {"dtype": "F32", "shape": [0], "data_offsets": [8, 0]}})"),
                  "begin 8 > end 0");
  EXPECT_CONTAINS(header_error(R"({"w": {"dtype": "F32", "shape": [1], "data_offsets": [-4, 0]}})"),
                  "non-negative integers");
  EXPECT_CONTAINS(
      header_error(R"({"w": {"dtype": "F32", "shape": [1], "data_offsets": [0, 4, 8]}})"),
      "[begin, end]");
  EXPECT_CONTAINS(header_error(R"({"w": {"dtype": "F32", "shape": [1], "data_offsets": [0]}})"),
                  "[begin, end]");
  EXPECT_CONTAINS(
      header_error(R"({"w": {"dtype": "F32", "shape": [1], "data_offsets": [0.0, 4]}})"),
      "non-negative integers");
  // Offsets near 2^64 must not wrap around.
  EXPECT_CONTAINS(header_error(R"({"w": {"dtype": "F32", "shape": [1], )"
                               R"("data_offsets": [18446744073709551612, 0]}})"),
                  "non-negative integers");
  EXPECT_CONTAINS(header_error(R"({"w": {"dtype": "F32", "shape": [1], )"
                               R"("data_offsets": [9223372036854775803, 9223372036854775807]}})"),
                  "past the end");
}

TEST(SafetensorsHeader, OverlappingRanges) {
  const std::string e =
      header_error(R"({"a": {"dtype": "F32", "shape": [4], "data_offsets": [0, 16]},)"
                   R"( "b": {"dtype": "F32", "shape": [4], "data_offsets": [8, 24]}})");
  EXPECT_CONTAINS(e, "\"a\" [0, 16) and \"b\" [8, 24) overlap");
  // Same range twice.
  EXPECT_CONTAINS(header_error(R"({"a": {"dtype": "F32", "shape": [4], "data_offsets": [0, 16]},)"
                               R"( "b": {"dtype": "I64", "shape": [2], "data_offsets": [0, 16]}})"),
                  "overlap");
  // A range inside another, listed first.
  EXPECT_CONTAINS(
      header_error(R"({"in": {"dtype": "F32", "shape": [1], "data_offsets": [4, 8]},)"
                   R"( "out": {"dtype": "F32", "shape": [8], "data_offsets": [0, 32]}})"),
      "overlap");
  // Touching ranges, gaps and empty tensors anywhere are fine.
  EXPECT_EQ(header_error(R"({"a": {"dtype": "F32", "shape": [4], "data_offsets": [0, 16]},)"
                         R"( "b": {"dtype": "F32", "shape": [2], "data_offsets": [16, 24]},)"
                         R"( "c": {"dtype": "F32", "shape": [2], "data_offsets": [32, 40]},)"
                         R"( "e": {"dtype": "F32", "shape": [0, 5], "data_offsets": [4, 4]},)"
                         R"( "f": {"dtype": "I64", "shape": [0], "data_offsets": [4, 4]}})"),
            "");
}

TEST(SafetensorsHeader, DuplicateNames) {
  EXPECT_CONTAINS(header_error(R"({"a": {"dtype": "F32", "shape": [1], "data_offsets": [0, 4]},)"
                               R"( "a": {"dtype": "F32", "shape": [1], "data_offsets": [4, 8]}})"),
                  "duplicate tensor name \"a\"");
  EXPECT_CONTAINS(header_error(R"({"__metadata__": {}, "__metadata__": {}})"),
                  "duplicate \"__metadata__\"");
  EXPECT_CONTAINS(header_error(R"({"__metadata__": {"k": "1", "k": "2"}})"),
                  "duplicate \"__metadata__\" key \"k\"");
}

// The header's JSON is RFC 8259 only; duplicate keys are refused at every
// level (nlohmann alone would keep the last one).
TEST(SafetensorsHeader, StrictJson) {
  const std::string w = R"("w": {"dtype": "F32", "shape": [1], "data_offsets": [0, 4]})";
  ASSERT_EQ(header_error("{" + w + "}"), "");
  for (const std::string& bad : std::vector<std::string>{
           "{" + w + ",}",         // trailing comma
           "{" + w + "} x",        // text after the value
           "{/* c */ " + w + "}",  // comment
           "{\"w\": {\"dtype\": \"F32\", \"shape\": [01], \"data_offsets\": [0, 4]}}",  // leading 0
           "{\"w\": {\"dtype\": \"F32\", \"shape\": [NaN], \"data_offsets\": [0, 4]}}",
           "{\"w\": {\"dtype\": \"F32\", \"shape\": [1e999], \"data_offsets\": [0, 4]}}",
           "{'w': 1}",                 // single quotes
           "{\"w\x01\": 1}",           // raw control character
           "{\"w\xff\": 1}",           // invalid UTF-8
           "{\"\\ud800\": 1}",         // lone surrogate
           "\xEF\xBB\xBF{" + w + "}",  // byte-order mark
       }) {
    EXPECT_CONTAINS(header_error(bad), "not valid JSON");
  }
  EXPECT_EQ(header_error(R"({"\u00e9\ud83d\ude00": {"dtype": "F32", "shape": [1], )"
                         R"("data_offsets": [0, 4]}})"),
            "");
  EXPECT_CONTAINS(
      header_error(
          R"({"w": {"dtype": "F32", "dtype": "F32", "shape": [1], "data_offsets": [0, 4]}})"),
      "tensor \"w\": duplicate field \"dtype\"");
  EXPECT_CONTAINS(header_error(std::string(9, '[') + std::string(9, ']')), "nesting");
  EXPECT_CONTAINS(header_error(std::string(8, '[') + std::string(8, ']')), "expected an object");
}

TEST(SafetensorsHeader, MetadataMustBeStrings) {
  EXPECT_CONTAINS(header_error(R"({"__metadata__": {"k": 1}})"),
                  "\"__metadata__\" value for \"k\" has type number, expected a string");
  EXPECT_CONTAINS(header_error(R"({"__metadata__": {"k": {"a": "b"}}})"), "has type object");
  EXPECT_CONTAINS(header_error(R"({"__metadata__": {"k": null}})"), "has type null");
  EXPECT_CONTAINS(header_error(R"({"__metadata__": ["k"]})"), "\"__metadata__\" is not an object");
  EXPECT_EQ(header_error(R"({"__metadata__": {"k": "{\"a\": [1]}"}})"), "");
}

TEST(SafetensorsHeader, BadShapes) {
  EXPECT_CONTAINS(
      header_error(R"({"w": {"dtype": "F32", "shape": [2, -1], "data_offsets": [0, 0]}})"),
      "negative dimension -1");
  EXPECT_CONTAINS(header_error(R"({"w": {"dtype": "F32", "shape": [4294967296, 4294967296, 4], )"
                               R"("data_offsets": [0, 0]}})"),
                  "overflows the byte count");
  // Product fits in int64 but not once multiplied by the item size.
  EXPECT_CONTAINS(header_error(R"({"w": {"dtype": "I64", "shape": [4611686018427387904], )"
                               R"("data_offsets": [0, 0]}})"),
                  "overflows");
  // Empty tensors may have large other dimensions, as long as their strides
  // stay representable.
  EXPECT_EQ(header_error(R"({"w": {"dtype": "F32", "shape": [0, 1000000000000000000], )"
                         R"("data_offsets": [0, 0]}})"),
            "");
  EXPECT_CONTAINS(header_error(R"({"w": {"dtype": "F32", "shape": [0, 9223372036854775807], )"
                               R"("data_offsets": [0, 0]}})"),
                  "overflows");
  EXPECT_CONTAINS(header_error(R"({"w": {"dtype": "F32", "shape": [4611686018427387904, 0], )"
                               R"("data_offsets": [0, 0]}})"),
                  "overflows");
  EXPECT_CONTAINS(header_error(R"({"w": {"dtype": "F32", "shape": [0, 4294967296, 4294967296], )"
                               R"("data_offsets": [0, 0]}})"),
                  "overflows");
  EXPECT_CONTAINS(
      header_error(R"({"w": {"dtype": "F32", "shape": [2.0], "data_offsets": [0, 8]}})"),
      "non-integer");
  EXPECT_CONTAINS(
      header_error(R"({"w": {"dtype": "F32", "shape": ["2"], "data_offsets": [0, 8]}})"),
      "non-integer");
  EXPECT_CONTAINS(header_error(R"({"w": {"dtype": "F32", "shape": 2, "data_offsets": [0, 8]}})"),
                  "\"shape\" is not a list");
  std::string rank17 = "[1";
  for (int i = 1; i < 17; ++i) rank17 += ", 1";
  rank17 += "]";
  EXPECT_CONTAINS(header_error(R"({"w": {"dtype": "F32", "shape": )" + rank17 +
                               R"(, "data_offsets": [0, 4]}})"),
                  "rank 17 exceeds");
  // Scalars (rank 0) are valid.
  EXPECT_EQ(header_error(R"({"w": {"dtype": "F32", "shape": [], "data_offsets": [0, 4]}})"), "");
}

TEST(SafetensorsHeader, MissingUnknownOrMistypedFields) {
  EXPECT_CONTAINS(header_error(R"({"w": {"shape": [1], "data_offsets": [0, 4]}})"),
                  "tensor \"w\": missing field \"dtype\"");
  EXPECT_CONTAINS(header_error(R"({"w": {"dtype": "F32", "data_offsets": [0, 4]}})"),
                  "missing field \"shape\"");
  EXPECT_CONTAINS(header_error(R"({"w": {"dtype": "F32", "shape": [1]}})"),
                  "missing field \"data_offsets\"");
  EXPECT_CONTAINS(
      header_error(R"({"w": {"dtype": "F32", "shape": [1], "data_offsets": [0, 4], "x": 1}})"),
      "unknown field \"x\"");
  EXPECT_CONTAINS(header_error(R"({"w": [1, 2]})"),
                  "tensor \"w\": entry has type array, expected an object");
  EXPECT_CONTAINS(header_error(R"({"w": "F32"})"), "entry has type string");
}

TEST(Safetensors, RoundTripEveryDtypeBitExact) {
  TempDir dir;
  std::map<std::string, at::Tensor> in;
  std::mt19937_64 rng(7);
  // Arbitrary bit patterns (NaNs with payloads, infinities, denormals, -0)
  // must come back unchanged.
  const auto random_bits = [&](at::ScalarType t, std::vector<int64_t> shape) {
    at::Tensor x = at::empty(shape, at::TensorOptions().dtype(t));
    auto* p = static_cast<uint8_t*>(x.data_ptr());
    for (int64_t i = 0; i < x.numel() * static_cast<int64_t>(x.element_size()); ++i) {
      p[i] = static_cast<uint8_t>(rng());
    }
    return x;
  };
  in["f32"] = random_bits(at::kFloat, {3, 5, 7});
  in["f16"] = random_bits(at::kHalf, {5, 3});
  in["bf16"] = random_bits(at::kBFloat16, {9});
  in["i64"] = random_bits(at::kLong, {2, 2});
  in["f64"] = random_bits(at::kDouble, {3, 2});  // sessions' stamps and poses
  in["u8"] = random_bits(at::kByte, {5});        // odd size: alignment of what follows
  in["special"] = at::tensor({0.0f, -0.0f, INFINITY, -INFINITY, NAN, 1e-45f, 3.4e38f});
  in["scalar"] = at::scalar_tensor(2.5, at::kFloat);
  in["empty"] = at::empty({0, 4}, at::kFloat);
  in["odd.f16"] = random_bits(at::kHalf, {3});  // 6 bytes: tests alignment of what follows
  in["strided"] = at::arange(12, at::kLong).reshape({3, 4}).t();  // non-contiguous
  const std::map<std::string, std::string> meta = {{"config", "{\"a\": [1, \"x\"]}"},
                                                   {"quote\"key", "line\nbreak \xC3\xA9"}};
  const std::string path = dir.file("rt.safetensors");
  long3r::save_safetensors(path, in, meta);
  EXPECT_EQ(dir.files(), std::vector<std::string>{"rt.safetensors"});  // no temp file left

  const long3r::TensorFile out = long3r::load_safetensors(path);
  EXPECT_EQ(out.metadata, meta);
  ASSERT_EQ(out.tensors.size(), in.size());
  for (const auto& kv : in) {
    SCOPED_TRACE(kv.first);
    const at::Tensor& t = out.tensors.at(kv.first);
    EXPECT_TRUE(t.is_contiguous());
    EXPECT_TRUE(same_bits(t, kv.second));
  }

  // Layout: header padded to 8, keys sorted, data without gaps, each tensor
  // aligned to its item size.
  const std::string bytes = read_file(path);
  const auto h = parse_safetensors_header(reinterpret_cast<const uint8_t*>(bytes.data()),
                                          bytes.size(), bytes.size());
  EXPECT_EQ(h.data_offset % 8, 0u);
  uint64_t expect_begin = 0;
  for (const auto& e : h.tensors) {
    EXPECT_EQ(e.begin, expect_begin) << e.name;
    EXPECT_EQ(e.begin % long3r::dtype_size(e.dtype), 0u) << e.name;
    expect_begin = e.end;
  }
  EXPECT_EQ(h.data_offset + expect_begin, bytes.size());
  const auto header =
      nlohmann::ordered_json::parse(bytes.substr(8, static_cast<std::size_t>(h.data_offset - 8)));
  std::vector<std::string> keys;
  for (const auto& m : header.items()) keys.push_back(m.key());
  ASSERT_EQ(keys.front(), "__metadata__");
  EXPECT_TRUE(std::is_sorted(keys.begin() + 1, keys.end()));
}

TEST(Safetensors, EmptyFileAndNoMetadata) {
  TempDir dir;
  const std::string path = dir.file("empty.safetensors");
  long3r::save_safetensors(path, {});
  const std::string bytes = read_file(path);
  EXPECT_EQ(bytes, le64(8) + "{}      ");
  const auto f = long3r::load_safetensors(path);
  EXPECT_TRUE(f.tensors.empty());
  EXPECT_TRUE(f.metadata.empty());
}

TEST(Safetensors, SaveRefusesBadInputWithoutLeavingFiles) {
  TempDir dir;
  const std::string path = dir.file("x.safetensors");
  try {
    long3r::save_safetensors(path, {{"ok", at::ones({2})}, {"bad", at::ones({2}, at::kInt)}});
    FAIL() << "no throw";
  } catch (const CheckpointError& e) {
    EXPECT_CONTAINS(e.what(), "\"bad\"");
    EXPECT_CONTAINS(e.what(), "Int");
  }
  EXPECT_THROW(long3r::save_safetensors(path, {{"__metadata__", at::ones({1})}}), CheckpointError);
  EXPECT_THROW(long3r::save_safetensors(path, {{"u", at::Tensor()}}), CheckpointError);
  EXPECT_TRUE(dir.files().empty());
  EXPECT_THROW(long3r::save_safetensors(dir.file("no/such/dir/x.safetensors"), {}),
               CheckpointError);
  EXPECT_TRUE(dir.files().empty());
}

TEST(Safetensors, SaveReplacesExistingFile) {
  TempDir dir;
  const std::string path = dir.file("x.safetensors");
  write_file(path, std::string(100000, 'z'));
  long3r::save_safetensors(path, {{"a", at::ones({2})}});
  const auto f = long3r::load_safetensors(path);
  ASSERT_EQ(f.tensors.size(), 1u);
  EXPECT_TRUE(at::equal(f.tensors.at("a"), at::ones({2})));
}

TEST(Safetensors, LoadReportsFileName) {
  TempDir dir;
  const std::string path = dir.file("trunc.safetensors");
  const std::string full = read_file(kGolden + "spann3r_seq_land96x64/weights.safetensors");
  for (std::size_t cut :
       {std::size_t{0}, std::size_t{7}, std::size_t{4000}, full.size() / 2, full.size() - 1}) {
    write_file(path, full.substr(0, cut));
    try {
      long3r::load_safetensors(path);
      FAIL() << "no throw at cut " << cut;
    } catch (const CheckpointError& e) {
      EXPECT_CONTAINS(e.what(), path);
    }
  }
  try {
    long3r::load_safetensors(dir.file("absent.safetensors"));
    FAIL() << "no throw";
  } catch (const CheckpointError& e) {
    EXPECT_CONTAINS(e.what(), "cannot open");
  }
  EXPECT_THROW(long3r::load_safetensors(dir.file("")), CheckpointError);  // a directory
}

// What is not a regular readable file is refused before anything is read,
// with the file named: a directory (whose read would return garbage), a FIFO
// (whose open would block the caller forever), an unreadable file.
TEST(Safetensors, RefusesWhatIsNotARegularReadableFile) {
  TempDir dir;
  auto expect_refused = [](const std::string& path, const std::string& why) {
    for (int reader = 0; reader < 2; ++reader) {
      try {
        if (reader == 0) {
          long3r::load_safetensors(path);
        } else {
          long3r::read_safetensors_metadata(path);
        }
        ADD_FAILURE() << "no throw for " << path;
      } catch (const CheckpointError& e) {
        EXPECT_CONTAINS(e.what(), path);
        EXPECT_CONTAINS(e.what(), why);
      }
    }
  };
  const std::string sub = dir.file("model.safetensors");
  ASSERT_EQ(::mkdir(sub.c_str(), 0755), 0);
  expect_refused(sub, "is a directory");
  const std::string fifo = dir.file("fifo.safetensors");
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0644), 0);
  expect_refused(fifo, "not a regular file");
  const std::string locked = dir.file("locked.safetensors");
  write_file(locked, read_file(kGolden + "spann3r_seq_land96x64/weights.safetensors"));
  ASSERT_EQ(::chmod(locked.c_str(), 0), 0);
  if (::access(locked.c_str(), R_OK) != 0) {  // root reads it anyway
    expect_refused(locked, "cannot open");
  }
}

TEST(Safetensors, MetadataAloneMatchesTheWholeFile) {
  const std::string path = kGolden + "spann3r_seq_land96x64/weights.safetensors";
  EXPECT_EQ(long3r::read_safetensors_metadata(path), long3r::load_safetensors(path).metadata);
}

TEST(Safetensors, LoadsEveryGoldenFileWithCaseJsonShapes) {
  for (const char* c : kCases) {
    SCOPED_TRACE(c);
    const auto cj = nlohmann::json::parse(read_file(kGolden + c + "/case.json"));
    const auto io = long3r::load_safetensors(kGolden + c + "/io.safetensors");
    EXPECT_EQ(io.metadata.at("case"), c);
    // case.json lists every io tensor with its dtype and shape.
    const auto& listed = cj.at("tensors");
    EXPECT_EQ(listed.size(), io.tensors.size());
    for (const auto& t : listed) {
      const std::string name = t.at("name").get<std::string>();
      SCOPED_TRACE(name);
      ASSERT_EQ(io.tensors.count(name), 1u);
      const at::Tensor& x = io.tensors.at(name);
      EXPECT_EQ(x.scalar_type(),
                t.at("dtype").get<std::string>() == "I64" ? at::kLong : at::kFloat);
      std::vector<int64_t> shape;
      for (const auto& d : t.at("shape")) shape.push_back(d.get<int64_t>());
      EXPECT_EQ(x.sizes().vec(), shape);
    }

    const auto w = long3r::load_safetensors(kGolden + c + "/weights.safetensors");
    EXPECT_EQ(nlohmann::json::parse(w.metadata.at("config")), cj.at("config"));
    const bool spann3r = std::string(c).rfind("spann3r", 0) == 0;
    const std::string p = spann3r ? "dust3r." : "";
    EXPECT_EQ(w.tensors.size(), spann3r ? 705u : 661u);
    EXPECT_EQ(w.tensors.at(p + "patch_embed.proj.weight").sizes().vec(),
              (std::vector<int64_t>{32, 3, 16, 16}));
    EXPECT_EQ(w.tensors.at(p + "enc_blocks.0.attn.qkv.weight").sizes().vec(),
              (std::vector<int64_t>{96, 32}));
    EXPECT_EQ(w.tensors.at(p + "dec_blocks2.9.cross_attn.projq.weight").sizes().vec(),
              (std::vector<int64_t>{16, 16}));
    // The DPT head's convs registered twice hold identical values.
    for (int n = 1; n <= 4; ++n) {
      const std::string base = p + "downstream_head1.dpt.scratch.";
      EXPECT_TRUE(same_bits(w.tensors.at(base + "layer" + std::to_string(n) + "_rn.weight"),
                            w.tensors.at(base + "layer_rn." + std::to_string(n - 1) + ".weight")));
    }
    // Total bytes agree with the file size recorded in case.json.
    int64_t data = 0;
    for (const auto& kv : w.tensors) data += kv.second.numel() * kv.second.element_size();
    EXPECT_LT(data, cj.at("file_bytes").at("weights").get<int64_t>());
    EXPECT_GT(data, cj.at("file_bytes").at("weights").get<int64_t>() - 80000);
  }
}

TEST(Safetensors, GoldenFilesRoundTripBitExact) {
  TempDir dir;
  for (const char* c : {"dust3r_pair_land112x80", "spann3r_seq_land96x64"}) {
    for (const char* f : {"/weights.safetensors", "/io.safetensors"}) {
      SCOPED_TRACE(std::string(c) + f);
      const auto a = long3r::load_safetensors(kGolden + c + f);
      const std::string path = dir.file("copy.safetensors");
      long3r::save_safetensors(path, a.tensors, a.metadata);
      const auto b = long3r::load_safetensors(path);
      EXPECT_EQ(a.metadata, b.metadata);
      ASSERT_EQ(a.tensors.size(), b.tensors.size());
      for (const auto& kv : a.tensors) {
        ASSERT_EQ(b.tensors.count(kv.first), 1u) << kv.first;
        EXPECT_TRUE(same_bits(kv.second, b.tensors.at(kv.first))) << kv.first;
      }
      // Same data section size: nothing added (no padding gaps) or lost.
      const auto data_size = [](const std::string& bytes) {
        const auto h = parse_safetensors_header(reinterpret_cast<const uint8_t*>(bytes.data()),
                                                bytes.size(), bytes.size());
        return bytes.size() - h.data_offset;
      };
      EXPECT_EQ(data_size(read_file(path)), data_size(read_file(kGolden + c + f)));
    }
  }
}

// The fuzz seeds (test/fuzz/make_corpus.py) are what their names claim, so
// the fuzzer starts from both sides of every rule.
TEST(SafetensorsHeader, FuzzCorpusSeedsAreWhatTheirNamesSay) {
  const std::string dir = std::string(LONG3R_SOURCE_DIR) + "/test/data/fuzz_corpus/";
  int valid = 0, bad = 0;
  DIR* d = ::opendir(dir.c_str());
  ASSERT_NE(d, nullptr);
  while (dirent* e = ::readdir(d)) {
    const std::string n = e->d_name;
    if (n.rfind("valid_", 0) == 0) {
      EXPECT_EQ(parse_error(read_file(dir + n)), "") << n;
      ++valid;
    } else if (n.rfind("bad_", 0) == 0) {
      EXPECT_NE(parse_error(read_file(dir + n)), "") << n;
      ++bad;
    }
  }
  ::closedir(d);
  EXPECT_GE(valid, 4);
  EXPECT_GE(bad, 10);
}

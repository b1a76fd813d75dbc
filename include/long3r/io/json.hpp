// A small strict JSON parser and writer (RFC 8259), torch-free and free of
// third-party dependencies so that the libtorch-only core can read checkpoint
// headers and model configurations anywhere libtorch builds.
//
// Strict means: no comments, no trailing commas, no NaN/Infinity, no leading
// zeros, no control characters or invalid UTF-8 inside strings, no lone UTF-16
// surrogates in \u escapes, nothing but whitespace after the value. Nesting
// depth and input size are bounded. Errors carry the byte offset.
//
// Accessors throw json::Error with a message that says what was expected and
// what was found, so a malformed configuration is reported by its key.
#pragma once

#include <cstddef>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

namespace long3r {
namespace json {

// Wrong type, missing key, out-of-range index or number.
class Error : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// Syntax error or limit exceeded while parsing; offset() is the byte offset
// (0-based) into the input where the problem was found.
class ParseError : public Error {
 public:
  ParseError(const std::string& what, std::size_t offset);
  std::size_t offset() const { return offset_; }

 private:
  std::size_t offset_;
};

enum class Type { kNull, kBool, kNumber, kString, kArray, kObject };
const char* type_name(Type t);

class Value;
using Array = std::vector<Value>;
// Objects keep their members in document order.
using Member = std::pair<std::string, Value>;
using Object = std::vector<Member>;

class Value {
 public:
  Value() = default;  // null
  Value(std::nullptr_t) {}
  Value(bool b) : type_(Type::kBool), bool_(b) {}
  template <typename T,
            typename std::enable_if<std::is_integral<T>::value && !std::is_same<T, bool>::value,
                                    int>::type = 0>
  Value(T i) : type_(Type::kNumber), is_int_(true) {
    // Unsigned values above INT64_MAX cannot be represented; refuse them
    // rather than wrapping silently.
    if constexpr (std::is_unsigned<T>::value) {
      if (static_cast<unsigned long long>(i) > static_cast<unsigned long long>(INT64_MAX)) {
        throw Error("json: integer " + std::to_string(i) + " does not fit in int64");
      }
    }
    int_ = static_cast<int64_t>(i);
    double_ = static_cast<double>(i);
  }
  Value(double d);  // throws on NaN/inf: JSON cannot hold them
  Value(const char* s) : type_(Type::kString), string_(s) {}
  Value(std::string s) : type_(Type::kString), string_(std::move(s)) {}
  Value(Array a) : type_(Type::kArray), array_(std::move(a)) {}
  Value(Object o) : type_(Type::kObject), object_(std::move(o)) {}

  Type type() const { return type_; }
  bool is_null() const { return type_ == Type::kNull; }
  bool is_bool() const { return type_ == Type::kBool; }
  bool is_number() const { return type_ == Type::kNumber; }
  // A number written without fraction or exponent that fits in int64.
  bool is_int() const { return type_ == Type::kNumber && is_int_; }
  bool is_string() const { return type_ == Type::kString; }
  bool is_array() const { return type_ == Type::kArray; }
  bool is_object() const { return type_ == Type::kObject; }

  bool as_bool() const;
  // Only integer-valued numbers written as integers (4, -2; not 4.0 or 4e0).
  int64_t as_int() const;
  // Any number (integers convert exactly up to 2^53).
  double as_double() const;
  const std::string& as_string() const;
  const Array& as_array() const;
  Array& as_array();
  const Object& as_object() const;
  Object& as_object();

  // Arrays of numbers (e.g. "hooks": [0, 5, 7, 10]); the error names the
  // offending index.
  std::vector<int64_t> as_int_vector() const;
  std::vector<double> as_double_vector() const;

  // Arrays and objects: number of elements / members. Others throw.
  std::size_t size() const;
  // Array element; throws if not an array or out of range.
  template <typename I,
            typename std::enable_if<std::is_integral<I>::value && !std::is_same<I, bool>::value,
                                    int>::type = 0>
  const Value& at(I i) const {
    if constexpr (std::is_signed<I>::value) {
      if (i < 0) throw Error("json: negative array index " + std::to_string(i));
    }
    return element(static_cast<std::size_t>(i));
  }
  // Object member; throws if not an object or the key is missing (the
  // message lists the keys that are present).
  const Value& at(const std::string& key) const;
  const Value& at(const char* key) const { return at(std::string(key)); }
  bool contains(const std::string& key) const;
  // Pointer to the member, or nullptr; throws if not an object.
  const Value* find(const std::string& key) const;

  // Member `key` converted, or `def` when the key is missing or null; a
  // present member of the wrong type still throws.
  bool get_bool_or(const std::string& key, bool def) const;
  int64_t get_int_or(const std::string& key, int64_t def) const;
  double get_double_or(const std::string& key, double def) const;
  std::string get_string_or(const std::string& key, const std::string& def) const;

  // Appends or replaces a member (objects only).
  void set(const std::string& key, Value v);
  // Appends an element (arrays only).
  void push_back(Value v);

  // Serialises to JSON. indent < 0: compact, one line, separators ", " and
  // ": " as Python's json.dumps writes them; indent >= 0: pretty-printed.
  // Numbers parsed as doubles are written in the shortest form that parses
  // back to the same double.
  std::string dump(int indent = -1) const;

  // Structural equality; numbers compare by value (1 == 1.0).
  friend bool operator==(const Value& a, const Value& b);
  friend bool operator!=(const Value& a, const Value& b) { return !(a == b); }

 private:
  friend class Parser;
  const Value& element(std::size_t i) const;
  void dump_to(std::string& out, int indent, int level) const;
  [[noreturn]] void type_error(const char* expected) const;

  Type type_ = Type::kNull;
  bool bool_ = false;
  bool is_int_ = false;
  int64_t int_ = 0;
  double double_ = 0.0;
  std::string string_;
  Array array_;
  Object object_;
};

struct ParseOptions {
  std::size_t max_depth = 64;         // nested arrays/objects
  std::size_t max_size = 100u << 20;  // input bytes
  bool allow_duplicate_keys = false;  // if true, all are kept in order
  // Values (scalars, arrays, objects) in the document. Each costs about 100
  // bytes in memory, so this bounds what a small hostile input can allocate.
  std::size_t max_values = 10'000'000;
};

// Parses exactly one JSON value (surrounded by optional whitespace).
Value parse(const char* data, std::size_t size, const ParseOptions& options = {});
Value parse(const std::string& text, const ParseOptions& options = {});

// Appends `s` to `out` as a JSON string literal (quotes included); non-ASCII
// UTF-8 is kept as is, control characters are escaped.
void append_quoted(std::string& out, const std::string& s);
std::string quote(const std::string& s);

}  // namespace json
}  // namespace long3r

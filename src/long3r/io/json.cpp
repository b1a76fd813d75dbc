// Strict JSON parser/writer; see include/long3r/io/json.hpp.
#include "long3r/io/json.hpp"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <system_error>

namespace long3r {
namespace json {

ParseError::ParseError(const std::string& what, std::size_t offset)
    : Error("JSON parse error at byte " + std::to_string(offset) + ": " + what), offset_(offset) {}

const char* type_name(Type t) {
  switch (t) {
    case Type::kNull:
      return "null";
    case Type::kBool:
      return "bool";
    case Type::kNumber:
      return "number";
    case Type::kString:
      return "string";
    case Type::kArray:
      return "array";
    case Type::kObject:
      return "object";
  }
  return "?";
}

namespace {

// Short, printable excerpt of a value for error messages.
std::string excerpt(const Value& v) {
  std::string s = v.dump();
  if (s.size() > 60) s = s.substr(0, 57) + "...";
  return s;
}

void append_utf8(std::string& out, uint32_t cp) {
  if (cp < 0x80) {
    out.push_back(static_cast<char>(cp));
  } else if (cp < 0x800) {
    out.push_back(static_cast<char>(0xC0 | (cp >> 6)));
    out.push_back(static_cast<char>(0x80 | (cp & 0x3F)));
  } else if (cp < 0x10000) {
    out.push_back(static_cast<char>(0xE0 | (cp >> 12)));
    out.push_back(static_cast<char>(0x80 | ((cp >> 6) & 0x3F)));
    out.push_back(static_cast<char>(0x80 | (cp & 0x3F)));
  } else {
    out.push_back(static_cast<char>(0xF0 | (cp >> 18)));
    out.push_back(static_cast<char>(0x80 | ((cp >> 12) & 0x3F)));
    out.push_back(static_cast<char>(0x80 | ((cp >> 6) & 0x3F)));
    out.push_back(static_cast<char>(0x80 | (cp & 0x3F)));
  }
}

// Length of the well-formed UTF-8 sequence starting at p (p < end, *p >= 0x80),
// or 0 if it is malformed (overlong, surrogate, above U+10FFFF, truncated).
std::size_t utf8_sequence_length(const unsigned char* p, const unsigned char* end) {
  const unsigned char c = p[0];
  std::size_t n;
  unsigned char lo = 0x80, hi = 0xBF;  // allowed range of the second byte
  if (c >= 0xC2 && c <= 0xDF) {
    n = 2;
  } else if (c >= 0xE0 && c <= 0xEF) {
    n = 3;
    if (c == 0xE0) lo = 0xA0;  // overlong
    if (c == 0xED) hi = 0x9F;  // UTF-16 surrogates
  } else if (c >= 0xF0 && c <= 0xF4) {
    n = 4;
    if (c == 0xF0) lo = 0x90;  // overlong
    if (c == 0xF4) hi = 0x8F;  // above U+10FFFF
  } else {
    return 0;
  }
  if (static_cast<std::size_t>(end - p) < n) return 0;
  if (p[1] < lo || p[1] > hi) return 0;
  for (std::size_t i = 2; i < n; ++i) {
    if ((p[i] & 0xC0) != 0x80) return 0;
  }
  return n;
}

// Decimal exponent of the leading significant digit of a valid, non-zero
// JSON number token: 12.5 -> 1, 0.03 -> -2, 7e-400 -> -400.
int64_t decimal_magnitude(const char* p, const char* end) {
  if (*p == '-') ++p;
  int64_t mag = 0;
  bool found = false;
  int64_t pos = 0;  // digit position: 0 = units, -1 = tenths, ...
  const char* q = p;
  while (q < end && *q >= '0' && *q <= '9') ++q;
  pos = static_cast<int64_t>(q - p) - 1;
  for (const char* r = p; r < end && *r != 'e' && *r != 'E'; ++r) {
    if (*r == '.') continue;
    if (*r != '0') {
      mag = pos;
      found = true;
      break;
    }
    --pos;
  }
  if (!found) return INT64_MIN / 2;
  const char* e = p;
  while (e < end && *e != 'e' && *e != 'E') ++e;
  if (e < end) {
    ++e;
    bool neg = false;
    if (*e == '+' || *e == '-') neg = (*e++ == '-');
    int64_t x = 0;
    for (; e < end; ++e) x = std::min<int64_t>(x * 10 + (*e - '0'), int64_t{1} << 40);
    mag += neg ? -x : x;
  }
  return mag;
}

// Shortest round-trip form, laid out as Python's repr(float) does (fixed
// notation for decimal exponents in [-4, 16), else d.ddde+XX), so that dumps
// of configs match what Python's json module writes.
std::string format_double(double d) {
  char buf[40];
  const auto r = std::to_chars(buf, buf + sizeof(buf), d, std::chars_format::scientific);
  const std::string sci(buf, r.ptr);  // e.g. "-1.25e-05"
  const std::size_t epos = sci.find('e');
  std::string mant = sci.substr(0, epos);
  const int exp = std::stoi(sci.substr(epos + 1));
  std::string sign;
  if (!mant.empty() && mant[0] == '-') {
    sign = "-";
    mant.erase(0, 1);
  }
  std::string digits;
  for (const char c : mant) {
    if (c != '.') digits.push_back(c);
  }
  std::string out = sign;
  if (exp >= -4 && exp < 16) {
    if (exp >= 0) {
      const std::size_t int_len = static_cast<std::size_t>(exp) + 1;
      if (digits.size() < int_len) digits.append(int_len - digits.size(), '0');
      out += digits.substr(0, int_len) + ".";
      out += digits.size() > int_len ? digits.substr(int_len) : "0";
    } else {
      out += "0." + std::string(static_cast<std::size_t>(-exp - 1), '0') + digits;
    }
  } else {
    out += digits.substr(0, 1);
    if (digits.size() > 1) out += "." + digits.substr(1);
    char e[16];
    std::snprintf(e, sizeof(e), "e%c%02d", exp < 0 ? '-' : '+', exp < 0 ? -exp : exp);
    out += e;
  }
  return out;
}

}  // namespace

// Recursive-descent parser over a byte range; recursion depth is bounded by
// ParseOptions::max_depth.
class Parser {
 public:
  Parser(const char* data, std::size_t size, const ParseOptions& opt)
      : p_(reinterpret_cast<const unsigned char*>(data)), n_(size), opt_(opt) {}

  Value parse_document() {
    if (n_ > opt_.max_size) {
      fail("input of " + std::to_string(n_) + " bytes exceeds the limit of " +
               std::to_string(opt_.max_size) + " bytes",
           0);
    }
    skip_ws();
    Value v = parse_value(0);
    skip_ws();
    if (i_ != n_) fail("unexpected " + describe_here() + " after the JSON value", i_);
    return v;
  }

 private:
  [[noreturn]] void fail(const std::string& what, std::size_t at) const {
    throw ParseError(what, at);
  }

  std::string describe_here() const {
    if (i_ >= n_) return "end of input";
    const unsigned char c = p_[i_];
    if (c >= 0x20 && c < 0x7F) return std::string("character '") + static_cast<char>(c) + "'";
    char buf[8];
    std::snprintf(buf, sizeof(buf), "0x%02X", c);
    return std::string("byte ") + buf;
  }

  void skip_ws() {
    while (i_ < n_ && (p_[i_] == ' ' || p_[i_] == '\t' || p_[i_] == '\n' || p_[i_] == '\r')) ++i_;
  }

  void expect_literal(const char* lit) {
    const std::size_t len = std::strlen(lit);
    if (n_ - i_ < len || std::memcmp(p_ + i_, lit, len) != 0) {
      fail(std::string("invalid literal, expected '") + lit + "'", i_);
    }
    i_ += len;
  }

  Value parse_value(std::size_t depth) {
    if (i_ >= n_) fail("unexpected end of input, expected a value", i_);
    if (++values_ > opt_.max_values) {
      fail("more than " + std::to_string(opt_.max_values) + " values in the document", i_);
    }
    switch (p_[i_]) {
      case '{':
        return parse_object(depth + 1);
      case '[':
        return parse_array(depth + 1);
      case '"': {
        Value v;
        v.type_ = Type::kString;
        v.string_ = parse_string();
        return v;
      }
      case 't':
        expect_literal("true");
        return Value(true);
      case 'f':
        expect_literal("false");
        return Value(false);
      case 'n':
        expect_literal("null");
        return Value();
      default:
        if (p_[i_] == '-' || (p_[i_] >= '0' && p_[i_] <= '9')) return parse_number();
        fail("unexpected " + describe_here() + ", expected a value", i_);
    }
  }

  void check_depth(std::size_t depth) const {
    if (depth > opt_.max_depth) {
      fail("nesting deeper than " + std::to_string(opt_.max_depth) + " levels", i_);
    }
  }

  Value parse_object(std::size_t depth) {
    check_depth(depth);
    Value v;
    v.type_ = Type::kObject;
    std::vector<std::size_t> key_offsets;
    ++i_;  // '{'
    skip_ws();
    if (i_ < n_ && p_[i_] == '}') {
      ++i_;
      return v;
    }
    for (;;) {
      skip_ws();
      if (i_ >= n_ || p_[i_] != '"') fail("expected '\"' to start an object key", i_);
      key_offsets.push_back(i_);
      std::string key = parse_string();
      skip_ws();
      if (i_ >= n_ || p_[i_] != ':') fail("expected ':' after object key", i_);
      ++i_;
      skip_ws();
      Value member = parse_value(depth);
      v.object_.emplace_back(std::move(key), std::move(member));
      skip_ws();
      if (i_ < n_ && p_[i_] == ',') {
        ++i_;
        continue;
      }
      if (i_ < n_ && p_[i_] == '}') {
        ++i_;
        break;
      }
      fail("expected ',' or '}' in object, got " + describe_here(), i_);
    }
    if (!opt_.allow_duplicate_keys && v.object_.size() > 1) {
      // Sort member indices by key; equal neighbours are duplicates. Report
      // the later occurrence in the document.
      std::vector<std::size_t> idx(v.object_.size());
      for (std::size_t k = 0; k < idx.size(); ++k) idx[k] = k;
      std::sort(idx.begin(), idx.end(), [&](std::size_t a, std::size_t b) {
        const int c = v.object_[a].first.compare(v.object_[b].first);
        return c != 0 ? c < 0 : a < b;
      });
      for (std::size_t k = 1; k < idx.size(); ++k) {
        if (v.object_[idx[k - 1]].first == v.object_[idx[k]].first) {
          fail("duplicate object key " + quote(v.object_[idx[k]].first), key_offsets[idx[k]]);
        }
      }
    }
    return v;
  }

  Value parse_array(std::size_t depth) {
    check_depth(depth);
    Value v;
    v.type_ = Type::kArray;
    ++i_;  // '['
    skip_ws();
    if (i_ < n_ && p_[i_] == ']') {
      ++i_;
      return v;
    }
    for (;;) {
      skip_ws();
      v.array_.push_back(parse_value(depth));
      skip_ws();
      if (i_ < n_ && p_[i_] == ',') {
        ++i_;
        continue;
      }
      if (i_ < n_ && p_[i_] == ']') {
        ++i_;
        break;
      }
      fail("expected ',' or ']' in array, got " + describe_here(), i_);
    }
    return v;
  }

  uint32_t parse_hex4() {
    if (n_ - i_ < 4) fail("truncated \\u escape", i_);
    uint32_t cp = 0;
    for (int k = 0; k < 4; ++k) {
      const unsigned char c = p_[i_ + k];
      uint32_t d;
      if (c >= '0' && c <= '9') {
        d = c - '0';
      } else if (c >= 'a' && c <= 'f') {
        d = c - 'a' + 10;
      } else if (c >= 'A' && c <= 'F') {
        d = c - 'A' + 10;
      } else {
        fail("invalid hex digit in \\u escape", i_ + k);
      }
      cp = cp * 16 + d;
    }
    i_ += 4;
    return cp;
  }

  std::string parse_string() {
    const std::size_t start = i_;
    ++i_;  // opening quote
    std::string out;
    for (;;) {
      if (i_ >= n_) fail("unterminated string", start);
      const unsigned char c = p_[i_];
      if (c == '"') {
        ++i_;
        return out;
      }
      if (c == '\\') {
        const std::size_t esc = i_;
        ++i_;
        if (i_ >= n_) fail("unterminated string", start);
        const unsigned char e = p_[i_++];
        switch (e) {
          case '"':
            out.push_back('"');
            break;
          case '\\':
            out.push_back('\\');
            break;
          case '/':
            out.push_back('/');
            break;
          case 'b':
            out.push_back('\b');
            break;
          case 'f':
            out.push_back('\f');
            break;
          case 'n':
            out.push_back('\n');
            break;
          case 'r':
            out.push_back('\r');
            break;
          case 't':
            out.push_back('\t');
            break;
          case 'u': {
            uint32_t cp = parse_hex4();
            if (cp >= 0xDC00 && cp <= 0xDFFF) fail("lone low surrogate in \\u escape", esc);
            if (cp >= 0xD800 && cp <= 0xDBFF) {
              if (n_ - i_ < 2 || p_[i_] != '\\' || p_[i_ + 1] != 'u') {
                fail("high surrogate not followed by a low surrogate escape", esc);
              }
              i_ += 2;
              const uint32_t lo = parse_hex4();
              if (lo < 0xDC00 || lo > 0xDFFF) {
                fail("high surrogate not followed by a low surrogate escape", esc);
              }
              cp = 0x10000 + ((cp - 0xD800) << 10) + (lo - 0xDC00);
            }
            append_utf8(out, cp);
            break;
          }
          default:
            fail("invalid escape sequence in string", esc);
        }
        continue;
      }
      if (c < 0x20) fail("unescaped control character in string", i_);
      if (c < 0x80) {
        out.push_back(static_cast<char>(c));
        ++i_;
        continue;
      }
      const std::size_t len = utf8_sequence_length(p_ + i_, p_ + n_);
      if (len == 0) fail("invalid UTF-8 in string", i_);
      out.append(reinterpret_cast<const char*>(p_ + i_), len);
      i_ += len;
    }
  }

  Value parse_number() {
    const std::size_t start = i_;
    bool integral = true;
    if (p_[i_] == '-') ++i_;
    if (i_ >= n_ || p_[i_] < '0' || p_[i_] > '9') fail("invalid number: expected a digit", i_);
    if (p_[i_] == '0') {
      ++i_;
      if (i_ < n_ && p_[i_] >= '0' && p_[i_] <= '9') fail("invalid number: leading zero", start);
    } else {
      while (i_ < n_ && p_[i_] >= '0' && p_[i_] <= '9') ++i_;
    }
    if (i_ < n_ && p_[i_] == '.') {
      integral = false;
      ++i_;
      if (i_ >= n_ || p_[i_] < '0' || p_[i_] > '9') {
        fail("invalid number: expected a digit after '.'", i_);
      }
      while (i_ < n_ && p_[i_] >= '0' && p_[i_] <= '9') ++i_;
    }
    if (i_ < n_ && (p_[i_] == 'e' || p_[i_] == 'E')) {
      integral = false;
      ++i_;
      if (i_ < n_ && (p_[i_] == '+' || p_[i_] == '-')) ++i_;
      if (i_ >= n_ || p_[i_] < '0' || p_[i_] > '9') {
        fail("invalid number: expected a digit in the exponent", i_);
      }
      while (i_ < n_ && p_[i_] >= '0' && p_[i_] <= '9') ++i_;
    }
    const char* first = reinterpret_cast<const char*>(p_ + start);
    const char* last = reinterpret_cast<const char*>(p_ + i_);
    Value v;
    v.type_ = Type::kNumber;
    if (integral) {
      int64_t x = 0;
      const auto r = std::from_chars(first, last, x);
      if (r.ec == std::errc() && r.ptr == last) {
        v.is_int_ = true;
        v.int_ = x;
        v.double_ = static_cast<double>(x);
        return v;
      }
      // Integers beyond int64 are kept as doubles (as_int refuses them).
    }
    double d = 0.0;
    const auto r = std::from_chars(first, last, d);
    if (r.ec == std::errc::result_out_of_range) {
      // from_chars reports both overflow and underflow; underflow becomes a
      // signed zero (as other JSON readers do), overflow is an error.
      if (decimal_magnitude(first, last) >= 0) {
        fail("number out of the range of a double", start);
      }
      v.double_ = *first == '-' ? -0.0 : 0.0;
      return v;
    }
    if (r.ec != std::errc() || r.ptr != last) fail("invalid number", start);
    v.double_ = d;
    return v;
  }

  const unsigned char* p_;
  std::size_t n_;
  std::size_t i_ = 0;
  std::size_t values_ = 0;
  const ParseOptions& opt_;
};

Value parse(const char* data, std::size_t size, const ParseOptions& options) {
  if (data == nullptr && size != 0) throw Error("json: null input");
  Parser parser(data == nullptr ? "" : data, size, options);
  return parser.parse_document();
}

Value parse(const std::string& text, const ParseOptions& options) {
  return parse(text.data(), text.size(), options);
}

// ---------------------------------------------------------------------------
// Value

Value::Value(double d) : type_(Type::kNumber), double_(d) {
  if (!std::isfinite(d)) throw Error("json: cannot represent a non-finite number");
}

void Value::type_error(const char* expected) const {
  throw Error(std::string("json: expected ") + expected + ", got " + type_name(type_) + " " +
              excerpt(*this));
}

bool Value::as_bool() const {
  if (type_ != Type::kBool) type_error("bool");
  return bool_;
}

int64_t Value::as_int() const {
  if (type_ != Type::kNumber) type_error("integer");
  if (!is_int_) type_error("integer (without fraction or exponent, within int64)");
  return int_;
}

double Value::as_double() const {
  if (type_ != Type::kNumber) type_error("number");
  return is_int_ ? static_cast<double>(int_) : double_;
}

const std::string& Value::as_string() const {
  if (type_ != Type::kString) type_error("string");
  return string_;
}

const Array& Value::as_array() const {
  if (type_ != Type::kArray) type_error("array");
  return array_;
}

Array& Value::as_array() {
  if (type_ != Type::kArray) type_error("array");
  return array_;
}

const Object& Value::as_object() const {
  if (type_ != Type::kObject) type_error("object");
  return object_;
}

Object& Value::as_object() {
  if (type_ != Type::kObject) type_error("object");
  return object_;
}

namespace {
template <typename T, typename F>
std::vector<T> convert_elements(const Array& a, F f) {
  std::vector<T> out;
  out.reserve(a.size());
  for (std::size_t i = 0; i < a.size(); ++i) {
    try {
      out.push_back(f(a[i]));
    } catch (const Error& e) {
      throw Error(std::string(e.what()) + " (array index " + std::to_string(i) + ")");
    }
  }
  return out;
}
}  // namespace

std::vector<int64_t> Value::as_int_vector() const {
  return convert_elements<int64_t>(as_array(), [](const Value& v) { return v.as_int(); });
}

std::vector<double> Value::as_double_vector() const {
  return convert_elements<double>(as_array(), [](const Value& v) { return v.as_double(); });
}

std::size_t Value::size() const {
  if (type_ == Type::kArray) return array_.size();
  if (type_ == Type::kObject) return object_.size();
  type_error("array or object");
}

const Value& Value::element(std::size_t i) const {
  const Array& a = as_array();
  if (i >= a.size()) {
    throw Error("json: index " + std::to_string(i) + " out of range for an array of " +
                std::to_string(a.size()) + " elements");
  }
  return a[i];
}

const Value* Value::find(const std::string& key) const {
  for (const Member& m : as_object()) {
    if (m.first == key) return &m.second;
  }
  return nullptr;
}

bool Value::contains(const std::string& key) const { return find(key) != nullptr; }

const Value& Value::at(const std::string& key) const {
  const Value* v = find(key);
  if (v == nullptr) {
    std::string keys;
    std::size_t listed = 0;
    for (const Member& m : object_) {
      if (listed == 20) {
        keys += ", ...";
        break;
      }
      keys += (listed++ ? ", " : "") + m.first;
    }
    throw Error("json: missing key " + quote(key) + " (present: " + keys + ")");
  }
  return *v;
}

namespace {
// Adds the key to a conversion error so that the message locates the value.
template <typename F>
auto with_key(const std::string& key, F f) -> decltype(f()) {
  try {
    return f();
  } catch (const Error& e) {
    throw Error(std::string(e.what()) + " (key " + quote(key) + ")");
  }
}
}  // namespace

bool Value::get_bool_or(const std::string& key, bool def) const {
  const Value* v = find(key);
  if (v == nullptr || v->is_null()) return def;
  return with_key(key, [&] { return v->as_bool(); });
}

int64_t Value::get_int_or(const std::string& key, int64_t def) const {
  const Value* v = find(key);
  if (v == nullptr || v->is_null()) return def;
  return with_key(key, [&] { return v->as_int(); });
}

double Value::get_double_or(const std::string& key, double def) const {
  const Value* v = find(key);
  if (v == nullptr || v->is_null()) return def;
  return with_key(key, [&] { return v->as_double(); });
}

std::string Value::get_string_or(const std::string& key, const std::string& def) const {
  const Value* v = find(key);
  if (v == nullptr || v->is_null()) return def;
  return with_key(key, [&] { return v->as_string(); });
}

void Value::set(const std::string& key, Value v) {
  Object& o = as_object();
  for (Member& m : o) {
    if (m.first == key) {
      m.second = std::move(v);
      return;
    }
  }
  o.emplace_back(key, std::move(v));
}

void Value::push_back(Value v) { as_array().push_back(std::move(v)); }

bool operator==(const Value& a, const Value& b) {
  if (a.type_ != b.type_) return false;
  switch (a.type_) {
    case Type::kNull:
      return true;
    case Type::kBool:
      return a.bool_ == b.bool_;
    case Type::kNumber:
      if (a.is_int_ && b.is_int_) return a.int_ == b.int_;
      return a.as_double() == b.as_double();
    case Type::kString:
      return a.string_ == b.string_;
    case Type::kArray:
      return a.array_ == b.array_;
    case Type::kObject: {
      // Member order does not matter.
      if (a.object_.size() != b.object_.size()) return false;
      for (const Member& m : a.object_) {
        const Value* o = b.find(m.first);
        if (o == nullptr || !(*o == m.second)) return false;
      }
      return true;
    }
  }
  return false;
}

void append_quoted(std::string& out, const std::string& s) {
  out.push_back('"');
  for (const char ch : s) {
    const unsigned char c = static_cast<unsigned char>(ch);
    switch (c) {
      case '"':
        out += "\\\"";
        break;
      case '\\':
        out += "\\\\";
        break;
      case '\n':
        out += "\\n";
        break;
      case '\r':
        out += "\\r";
        break;
      case '\t':
        out += "\\t";
        break;
      case '\b':
        out += "\\b";
        break;
      case '\f':
        out += "\\f";
        break;
      default:
        if (c < 0x20) {
          char buf[8];
          std::snprintf(buf, sizeof(buf), "\\u%04x", c);
          out += buf;
        } else {
          out.push_back(ch);
        }
    }
  }
  out.push_back('"');
}

std::string quote(const std::string& s) {
  std::string out;
  append_quoted(out, s);
  return out;
}

void Value::dump_to(std::string& out, int indent, int level) const {
  const auto newline = [&](int lvl) {
    if (indent < 0) return;
    out.push_back('\n');
    out.append(static_cast<std::size_t>(indent) * static_cast<std::size_t>(lvl), ' ');
  };
  switch (type_) {
    case Type::kNull:
      out += "null";
      break;
    case Type::kBool:
      out += bool_ ? "true" : "false";
      break;
    case Type::kNumber: {
      char buf[32];
      if (is_int_) {
        const auto r = std::to_chars(buf, buf + sizeof(buf), int_);
        out.append(buf, r.ptr);
      } else {
        out += format_double(double_);
      }
      break;
    }
    case Type::kString:
      append_quoted(out, string_);
      break;
    case Type::kArray: {
      // Pretty-printing keeps arrays of scalars on one line ([8, 12, 16]).
      const bool flat = indent < 0 || std::all_of(array_.begin(), array_.end(), [](const Value& e) {
                          return !e.is_array() && !e.is_object();
                        });
      if (flat) {
        out.push_back('[');
        for (std::size_t k = 0; k < array_.size(); ++k) {
          if (k) out += ", ";
          array_[k].dump_to(out, indent, level + 1);
        }
        out.push_back(']');
        break;
      }
      out.push_back('[');
      for (std::size_t k = 0; k < array_.size(); ++k) {
        if (k) out += ",";
        newline(level + 1);
        array_[k].dump_to(out, indent, level + 1);
      }
      newline(level);
      out.push_back(']');
      break;
    }
    case Type::kObject:
      out.push_back('{');
      for (std::size_t k = 0; k < object_.size(); ++k) {
        if (k) out += indent < 0 ? ", " : ",";
        newline(level + 1);
        append_quoted(out, object_[k].first);
        out += ": ";
        object_[k].second.dump_to(out, indent, level + 1);
      }
      if (!object_.empty()) newline(level);
      out.push_back('}');
      break;
  }
}

std::string Value::dump(int indent) const {
  std::string out;
  dump_to(out, indent, 0);
  return out;
}

}  // namespace json
}  // namespace long3r

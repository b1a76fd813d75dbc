// Reading and writing configuration structs as JSON (nlohmann), torch-free.
//
// Each config struct lists its fields once, in a function template
//   template <class S, class V> void visit_fields(S& s, V& v)   // S: T or const T
// that calls v("json_key", s.member) per field (nested structs, lists of
// structs, enums and a few custom encodings included). config::Reader, Writer
// and any other visitor (the ROS parameter reader) are driven by that one list:
//   - Reader: a missing or null key keeps the struct's default; a present one
//     must have the right type; keys that no field names are rejected by name
//     (except the comment key "note"); errors read
//     "<what>: <field path>: <problem>", e.g. "model config: dust3r.enc_depth:
//     expected an integer, found string", and throw ConfigError.
//   - Writer: every field, in list order (ordered_json keeps that order).
// Enums are JSON strings; each enum provides the table through an ADL-found
//   const std::array<std::pair<E, const char*>, N>& enum_names(E);
// A field with its own encoding passes a codec (derived from config::Codec,
// holding a reference to the member) with read(const Json&, const Reader&,
// const std::string& path) and Json write() members instead of the member
// itself; write() may return a discarded value to leave the key out.
#pragma once

#include <cmath>
#include <cstdint>
#include <limits>
#include <nlohmann/json.hpp>
#include <set>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include "long3r/config/config_fields.hpp"

namespace long3r {

namespace config {

using Json = nlohmann::ordered_json;

// Base of field codecs (see the file comment). A codec that sets
// kSeesMissing is also called, with null, when its key is missing.
struct Codec {
  static constexpr bool kSeesMissing = false;
};

// "a.b" or "b" at the top level.
std::string join(const std::string& path, const std::string& key);
// JSON type of `v` as the error messages name it ("string", "number", "bool", ...).
std::string type_of(const Json& v);
// Parses JSON text strictly (no comments, nothing after the value); syntax
// errors throw ConfigError("<what> is not valid JSON: ...").
Json parse(const std::string& text, const std::string& what);

// Reads a JSON object into a struct through its visit_fields list.
class Reader {
 public:
  struct Options {
    std::string what;                  // error prefix: "model config", "training config"
    bool inf_strings = false;          // doubles may be written "inf" / "-inf"
    std::string comment_key = "note";  // ignored wherever it appears
  };

  Reader(const Json& object, std::string path, Options options);

  const std::string& path() const { return path_; }
  const Options& options() const { return options_; }

  // Field `key`: read into `value` when present and not null.
  template <class T>
  void operator()(const char* key, T& value) {
    if (const Json* v = take(key)) read(*v, join(path_, key), value);
  }
  template <class T>
  void operator()(const char* key, T& value, const char* /*log_note*/) {
    (*this)(key, value);
  }
  // A nested struct: the object `key`.
  template <class T>
  void nested(const char* key, T& value, const char* /*flat_prefix*/) {
    (*this)(key, value);
  }
  // Codecs also see an explicit null (e.g. "conf_mode": null).
  template <class T, std::enable_if_t<std::is_base_of<Codec, T>::value, int> = 0>
  void operator()(const char* key, T&& codec) {
    taken_.insert(key);
    const auto it = object_.find(key);
    if (it != object_.end()) {
      codec.read(*it, *this, join(path_, key));
    } else if constexpr (std::decay_t<T>::kSeesMissing) {
      codec.read(Json(), *this, join(path_, key));
    }
  }
  // A nested object whose field list needs context (fields(Reader&) is called
  // with the object's reader); missing or null: nothing is read.
  template <class F>
  void section(const char* key, F&& fields) {
    if (const Json* v = take(key)) {
      Reader r = child(key, *v);
      fields(r);
      r.finish();
    }
  }
  // A key that is accepted and type-checked but not stored (training-only or
  // descriptive settings of the official configs).
  template <class T>
  void ignored(const char* key) {
    T unused{};
    (*this)(key, unused);
  }
  // A key whose only supported value is `value`.
  template <class T>
  void fixed(const char* key, const T& value, const std::string& what) {
    T v = value;
    (*this)(key, v);
    if (!(v == value)) fail(join(path_, key), what + ", found " + Json(v).dump());
  }
  // A default derived from fields read before (e.g. top_k = long_mem_size),
  // set at this point of the field list; writers skip it.
  template <class T, class U>
  void derive(T& field, U&& value) {
    field = std::forward<U>(value);
  }
  // A key that must be missing or null (a training setting of the official
  // configs that inference cannot honour).
  void reject(const char* key, const std::string& what) {
    if (take(key) != nullptr) fail(join(path_, key), what);
  }

  // The member, marked as known; nullptr when missing or null.
  const Json* take(const char* key);
  // Member `key` as an object reader (fails unless an object).
  Reader child(const char* key, const Json& object) const;
  // Rejects the keys no field took.
  void finish() const;
  [[noreturn]] void fail(const std::string& path, const std::string& what) const;

  // Value conversions; `path` names the value in errors.
  void read(const Json& v, const std::string& path, bool& out) const;
  void read(const Json& v, const std::string& path, std::string& out) const;
  void read(const Json& v, const std::string& path, double& out) const;
  void read(const Json& v, const std::string& path, int64_t& out) const;
  void read(const Json& v, const std::string& path, uint64_t& out) const;
  void read(const Json& v, const std::string& path, int& out) const {
    int64_t x = out;
    read(v, path, x);
    if (x < std::numeric_limits<int>::min() || x > std::numeric_limits<int>::max()) {
      fail(path, "integer out of range");
    }
    out = static_cast<int>(x);
  }
  template <class T>
  void read(const Json& v, const std::string& path, std::vector<T>& out) const {
    if (!v.is_array()) fail(path, "expected a list, found " + type_of(v));
    out.clear();
    for (std::size_t i = 0; i < v.size(); ++i) {
      T item{};
      read(v[i], path + "[" + std::to_string(i) + "]", item);
      out.push_back(std::move(item));
    }
  }
  template <class E, std::enable_if_t<std::is_enum<E>::value, int> = 0>
  void read(const Json& v, const std::string& path, E& out) const {
    std::string s;
    read(v, path, s);
    if (!enum_from_name(s, &out))
      fail(path, "must be " + enum_choices<E>() + ", got \"" + s + "\"");
  }
  template <class T, std::enable_if_t<std::is_class<T>::value, int> = 0,
            class = decltype(visit_fields(std::declval<T&>(), std::declval<Reader&>()))>
  void read(const Json& v, const std::string& path, T& out) const {
    if (!v.is_object()) fail(path, "expected an object, found " + type_of(v));
    Reader r(v, path, options_);
    visit_fields(out, r);
    r.finish();
  }

 private:
  const Json& object_;
  std::string path_;
  Options options_;
  std::set<std::string> taken_;
};

// Writes a struct's fields as a JSON object, in field-list order.
class Writer {
 public:
  template <class T>
  void operator()(const char* key, const T& value) {
    if constexpr (std::is_base_of<Codec, T>::value) {
      Json j = value.write();
      if (!j.is_discarded()) out_[key] = std::move(j);
    } else {
      out_[key] = write(value);
    }
  }
  template <class T>
  void operator()(const char* key, const T& value, const char* /*log_note*/) {
    (*this)(key, value);
  }
  template <class T>
  void nested(const char* key, const T& value, const char* /*flat_prefix*/) {
    (*this)(key, value);
  }
  template <class T>
  void ignored(const char*) {}
  template <class T>
  void fixed(const char*, const T&, const std::string&) {}
  template <class F>
  void section(const char* key, F&& fields) {
    Writer w;
    fields(w);
    out_[key] = std::move(w.out_);
  }
  template <class T, class U>
  void derive(const T&, U&&) {}
  void reject(const char*, const std::string&) {}

  Json& result() { return out_; }
  std::string path() const { return std::string(); }

  static Json write(bool v) { return v; }
  static Json write(const std::string& v) { return v; }
  static Json write(const char* v) { return v; }
  // Infinities as "inf" / "-inf" (JSON numbers cannot hold them).
  static Json write(double v) {
    if (std::isinf(v)) return v > 0 ? "inf" : "-inf";
    return v;
  }
  template <class T,
            std::enable_if_t<std::is_integral<T>::value && !std::is_same<T, bool>::value, int> = 0>
  static Json write(T v) {
    return v;
  }
  template <class T>
  static Json write(const std::vector<T>& v) {
    Json a = Json::array();
    for (const T& x : v) a.push_back(write(x));
    return a;
  }
  template <class E, std::enable_if_t<std::is_enum<E>::value, int> = 0>
  static Json write(E v) {
    return enum_name(v);
  }
  template <class T, std::enable_if_t<std::is_class<T>::value, int> = 0,
            class = decltype(visit_fields(std::declval<const T&>(), std::declval<Writer&>()))>
  static Json write(const T& v) {
    Writer w;
    visit_fields(v, w);
    return std::move(w.out_);
  }

 private:
  Json out_ = Json::object();
};

// `config` from a JSON object (fields it does not set keep their values).
template <class T>
void read_object(const Json& j, T& config, const Reader::Options& options,
                 const std::string& path = "") {
  if (!j.is_object()) {
    throw ConfigError(options.what + ": " + (path.empty() ? "(top level)" : path) +
                      ": expected an object, found " + type_of(j));
  }
  Reader r(j, path, options);
  visit_fields(config, r);
  r.finish();
}

template <class T>
Json to_json(const T& config) {
  return Writer::write(config);
}

}  // namespace config
}  // namespace long3r

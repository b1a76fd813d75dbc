// What a config struct's header needs to describe its fields, without any JSON
// library: the error type, a checker for validate() that names the field, and
// name lookups of enums (see include/long3r/config/config_json.hpp for the field
// lists and the JSON side).
#pragma once

#include <algorithm>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <utility>

namespace long3r {

// Malformed or unsupported configuration (model, training, nodelet parameters);
// the message names the field, e.g. "model config: dust3r.enc_num_heads: ...".
class ConfigError : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};

namespace config {

// Return type of a struct's field list, so that each struct's
//   template <class S, class V> config::FieldsOf<S, MyConfig> visit_fields(S& s, V& v)
// (S = MyConfig or const MyConfig) is an overload of its own. The list is the
// one place a field is named; JSON, ROS parameters and the start-up logs all
// read it. In it:
//   v("name", s.member);                   a field
//   v("name", s.member, "(no bound)");     with what a log shows for a 0 / empty value
//   v.nested("scale", s.scale, "scale_");  a struct: an object "scale" in JSON,
//                                          flat names "scale_<field>" in ROS
// A struct's validate(check) names its fields through check.field(name) and
// has its nested structs validated by validate_nested(*this, check), which
// takes their keys and prefixes from the list, so that errors name the field
// as the reader of the moment spells it.
template <class S, class T>
using FieldsOf = std::enable_if_t<std::is_same<std::remove_const_t<S>, T>::value>;

// For validate(): require(ok, "field", "must be positive") throws
// ConfigError("<what>: <path>.field: must be positive").
struct FieldCheck {
  std::string what;  // "model config", "training config"
  std::string path;  // of the struct, e.g. "spatial_memory"; empty at the top level
  // Flat names (ROS parameters): path is a prefix, e.g. "/long3r/scale_".
  bool flat = false;

  std::string field(const std::string& name) const {
    if (flat) return path + name;
    return path.empty() ? name : path + "." + name;
  }
  // The check of a nested struct (see visit_fields' nested()).
  FieldCheck nested(const std::string& key, const std::string& flat_prefix) const {
    return flat ? FieldCheck{what, path + flat_prefix, true} : FieldCheck{what, field(key)};
  }
  // "<what>: <path>.name: <problem>"; flat: "<what> <path>name <problem>"
  // ("parameter /long3r/queue_size must be in [1, 1000]").
  [[noreturn]] void fail(const std::string& name, const std::string& problem) const {
    if (flat) throw ConfigError(what + " " + field(name) + " " + problem);
    throw ConfigError(what + ": " + field(name) + ": " + problem);
  }
  void require(bool ok, const std::string& name, const std::string& problem) const {
    if (!ok) fail(name, problem);
  }
};

// Enum <-> name through the enum's ADL-found table
//   const std::array<std::pair<E, const char*>, N>& enum_names(E);
template <class E>
const char* enum_name(E value) {
  for (const auto& entry : enum_names(E{})) {
    if (entry.first == value) return entry.second;
  }
  return "?";
}
template <class E>
bool enum_from_name(const std::string& name, E* value) {
  for (const auto& entry : enum_names(E{})) {
    if (name == entry.second) {
      *value = entry.first;
      return true;
    }
  }
  return false;
}
// "\"a\" or \"b\"", for messages. A value named twice in the table has an
// older name after its own, still read (enum_from_name) but not offered.
template <class E>
std::string enum_choices() {
  std::string s;
  const auto& names = enum_names(E{});
  for (auto it = names.begin(); it != names.end(); ++it) {
    const auto same = [&](const auto& e) { return e.first == it->first; };
    if (std::find_if(names.begin(), it, same) != it) continue;  // an older name
    s += std::string(s.empty() ? "" : " or ") + "\"" + it->second + "\"";
  }
  return s;
}

// The flat names of a field list: f(flat_name, field, log_note) for every
// field, a nested struct's fields under its flat prefix (ROS parameters,
// command-line options, logs). T may be const.
template <class F>
class FlatVisitor {
 public:
  FlatVisitor(F& f, std::string prefix) : f_(f), prefix_(std::move(prefix)) {}
  template <class T>
  void operator()(const std::string& name, T& value, const char* log_note = nullptr) {
    f_(prefix_ + name, value, log_note);
  }
  template <class T>
  void nested(const char* /*key*/, T& value, const char* flat_prefix) {
    FlatVisitor sub(f_, prefix_ + flat_prefix);
    visit_fields(value, sub);
  }

 private:
  F& f_;
  std::string prefix_;
};
template <class T, class F>
void visit_flat(T& config, F&& f, const std::string& prefix = "") {
  FlatVisitor<std::remove_reference_t<F>> v(f, prefix);
  visit_fields(config, v);
}

// For a validate() whose struct nests others: validates each nested struct
// of its field list with the check its key and flat prefix give, so that
// those are written in the list only.
class NestedValidator {
 public:
  explicit NestedValidator(const FieldCheck& check) : check_(check) {}
  template <class U>
  void operator()(const std::string& /*name*/, const U& /*field*/, const char* = nullptr) {}
  template <class U>
  void nested(const char* key, const U& value, const char* flat_prefix) {
    value.validate(check_.nested(key, flat_prefix));
  }

 private:
  const FieldCheck& check_;
};
template <class T>
void validate_nested(const T& config, const FieldCheck& check) {
  NestedValidator v(check);
  visit_fields(config, v);
}

}  // namespace config
}  // namespace long3r

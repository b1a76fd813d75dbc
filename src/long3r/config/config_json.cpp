// Field readers of the configuration JSON; see include/long3r/config/config_json.hpp.
#include "long3r/config/config_json.hpp"

namespace long3r {
namespace config {

std::string join(const std::string& path, const std::string& key) {
  return path.empty() ? key : path + "." + key;
}

std::string type_of(const Json& v) {
  switch (v.type()) {
    case Json::value_t::null:
      return "null";
    case Json::value_t::boolean:
      return "bool";
    case Json::value_t::number_integer:
    case Json::value_t::number_unsigned:
    case Json::value_t::number_float:
      return "number";
    case Json::value_t::string:
      return "string";
    case Json::value_t::array:
      return "array";
    case Json::value_t::object:
      return "object";
    default:
      break;
  }
  return "invalid";
}

Json parse(const std::string& text, const std::string& what) {
  try {
    return Json::parse(text, nullptr, /*allow_exceptions=*/true, /*ignore_comments=*/false);
  } catch (const Json::exception& e) {
    throw ConfigError(what + " is not valid JSON: " + e.what());
  }
}

Reader::Reader(const Json& object, std::string path, Options options)
    : object_(object), path_(std::move(path)), options_(std::move(options)) {}

const Json* Reader::take(const char* key) {
  taken_.insert(key);
  const auto it = object_.find(key);
  if (it == object_.end() || it->is_null()) return nullptr;
  return &*it;
}

Reader Reader::child(const char* key, const Json& object) const {
  const std::string p = join(path_, key);
  if (!object.is_object()) fail(p, "expected an object, found " + type_of(object));
  return Reader(object, p, options_);
}

void Reader::finish() const {
  std::string unknown;
  for (const auto& m : object_.items()) {
    if (taken_.count(m.key()) == 0 && m.key() != options_.comment_key) {
      unknown += (unknown.empty() ? "\"" : ", \"") + m.key() + "\"";
    }
  }
  if (!unknown.empty()) fail(path_.empty() ? "(top level)" : path_, "unknown field(s) " + unknown);
}

void Reader::fail(const std::string& path, const std::string& what) const {
  throw ConfigError(options_.what + ": " + path + ": " + what);
}

void Reader::read(const Json& v, const std::string& path, bool& out) const {
  if (!v.is_boolean()) fail(path, "expected true/false, found " + type_of(v));
  out = v.get<bool>();
}

void Reader::read(const Json& v, const std::string& path, std::string& out) const {
  if (!v.is_string()) fail(path, "expected a string, found " + type_of(v));
  out = v.get<std::string>();
}

void Reader::read(const Json& v, const std::string& path, double& out) const {
  if (v.is_number()) {
    out = v.get<double>();
    return;
  }
  if (options_.inf_strings) {
    if (v.is_string() && v.get<std::string>() == "inf") {
      out = std::numeric_limits<double>::infinity();
      return;
    }
    if (v.is_string() && v.get<std::string>() == "-inf") {
      out = -std::numeric_limits<double>::infinity();
      return;
    }
    fail(path, "expected a number, \"inf\" or \"-inf\"");
  }
  fail(path, "expected a number, found " + type_of(v));
}

void Reader::read(const Json& v, const std::string& path, int64_t& out) const {
  if (v.is_number_unsigned() &&
      v.get<uint64_t>() > static_cast<uint64_t>(std::numeric_limits<int64_t>::max())) {
    fail(path, "integer out of range");
  }
  if (!v.is_number_integer()) {
    fail(path,
         "expected an integer, found " + (v.is_number() ? "a non-integer number" : type_of(v)));
  }
  out = v.get<int64_t>();
}

void Reader::read(const Json& v, const std::string& path, uint64_t& out) const {
  if (!v.is_number_integer()) {
    fail(path,
         "expected an integer, found " + (v.is_number() ? "a non-integer number" : type_of(v)));
  }
  if (!v.is_number_unsigned()) fail(path, "must be >= 0");
  out = v.get<uint64_t>();
}

}  // namespace config
}  // namespace long3r

// Tests of the configuration JSON helper (include/long3r/config/config_json.hpp):
// one field list drives reading (defaults, type checks, unknown keys named,
// the comment key, nested structs, lists, enums, "inf") and writing, and the
// strict parser.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <limits>
#include <string>
#include <utility>
#include <vector>

#include "long3r/config/config_json.hpp"

namespace demo {

enum class Mode { kFast, kSlow };
inline const std::array<std::pair<Mode, const char*>, 2>& enum_names(Mode) {
  static const std::array<std::pair<Mode, const char*>, 2> names{
      {{Mode::kFast, "fast"}, {Mode::kSlow, "slow"}}};
  return names;
}

struct Inner {
  int64_t n = 3;
  std::vector<int64_t> list{1, 2};
};
template <class S, class V>
long3r::config::FieldsOf<S, Inner> visit_fields(S& s, V& v) {
  v("n", s.n);
  v("list", s.list);
}

struct Outer {
  bool flag = false;
  double x = 0.5;
  uint64_t seed = 7;
  int small = 2;
  std::string name = "a";
  Mode mode = Mode::kFast;
  Inner inner;
  std::vector<Inner> items;
  int64_t derived = 0;
};
template <class S, class V>
long3r::config::FieldsOf<S, Outer> visit_fields(S& s, V& v) {
  v("flag", s.flag);
  v("x", s.x);
  v("seed", s.seed);
  v("small", s.small);
  v("name", s.name);
  v("mode", s.mode);
  v("inner", s.inner);
  v("items", s.items);
  v.derive(s.derived, s.inner.n * 10);
  v("derived", s.derived);
  v.template ignored<std::string>("descriptive");
  v.fixed("kind", std::string("demo"), "only \"demo\" is supported");
  v.reject("dropout", "a training setting; must be null");
}

}  // namespace demo

namespace {

using long3r::ConfigError;
using long3r::config::Json;

const long3r::config::Reader::Options kOpt{"demo config", /*inf_strings=*/false, "note"};

demo::Outer read(const std::string& text, const long3r::config::Reader::Options& opt = kOpt) {
  demo::Outer o;
  long3r::config::read_object(long3r::config::parse(text, opt.what), o, opt);
  return o;
}

std::string error_of(const std::string& text, const long3r::config::Reader::Options& opt = kOpt) {
  try {
    read(text, opt);
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "";
}

#define EXPECT_CONTAINS(s, sub) EXPECT_NE(std::string(s).find(sub), std::string::npos) << (s)

TEST(ConfigJson, MissingAndNullKeepDefaults) {
  const demo::Outer o = read(R"({"x": null, "note": "free text", "inner": {"note": 1}})");
  EXPECT_FALSE(o.flag);
  EXPECT_DOUBLE_EQ(o.x, 0.5);
  EXPECT_EQ(o.seed, 7u);
  EXPECT_EQ(o.name, "a");
  EXPECT_EQ(o.inner.n, 3);
  EXPECT_EQ(o.inner.list, (std::vector<int64_t>{1, 2}));
  EXPECT_EQ(o.derived, 30);  // derived from the fields read before it
}

TEST(ConfigJson, ReadsEveryKind) {
  const demo::Outer o = read(R"({"flag": true, "x": 2, "seed": 18446744073709551615,
      "small": -4, "name": "b", "mode": "slow", "inner": {"n": 5, "list": []},
      "items": [{"n": 1}, {"list": [9]}], "descriptive": "anything", "kind": "demo"})");
  EXPECT_TRUE(o.flag);
  EXPECT_DOUBLE_EQ(o.x, 2.0);  // integers are numbers
  EXPECT_EQ(o.seed, UINT64_MAX);
  EXPECT_EQ(o.small, -4);
  EXPECT_EQ(o.name, "b");
  EXPECT_EQ(o.mode, demo::Mode::kSlow);
  EXPECT_EQ(o.inner.n, 5);
  EXPECT_TRUE(o.inner.list.empty());
  ASSERT_EQ(o.items.size(), 2u);
  EXPECT_EQ(o.items[0].n, 1);
  EXPECT_EQ(o.items[1].n, 3);
  EXPECT_EQ(o.items[1].list, std::vector<int64_t>{9});
  EXPECT_EQ(o.derived, 50);
}

TEST(ConfigJson, ErrorsNameTheFieldPath) {
  EXPECT_CONTAINS(error_of(R"({"flgs": 1, "zz": 2})"),
                  "demo config: (top level): unknown field(s) \"flgs\", \"zz\"");
  EXPECT_CONTAINS(error_of(R"({"inner": {"m": 1}})"), "demo config: inner: unknown field(s) \"m\"");
  EXPECT_CONTAINS(error_of(R"({"items": [{}, {"n": 1.5}]})"),
                  "demo config: items[1].n: expected an integer, found a non-integer number");
  EXPECT_CONTAINS(error_of(R"({"inner": {"list": [1, "2"]}})"),
                  "inner.list[1]: expected an integer, found string");
  EXPECT_CONTAINS(error_of(R"({"flag": 1})"), "flag: expected true/false, found number");
  EXPECT_CONTAINS(error_of(R"({"name": 1})"), "name: expected a string");
  EXPECT_CONTAINS(error_of(R"({"x": "1"})"), "x: expected a number, found string");
  EXPECT_CONTAINS(error_of(R"({"seed": -1})"), "seed: must be >= 0");
  EXPECT_CONTAINS(error_of(R"({"small": 3000000000})"), "small: integer out of range");
  EXPECT_CONTAINS(error_of(R"({"derived": 9223372036854775808})"), "derived: integer out of range");
  EXPECT_CONTAINS(error_of(R"({"mode": "medium"})"),
                  "mode: must be \"fast\" or \"slow\", got \"medium\"");
  EXPECT_CONTAINS(error_of(R"({"inner": [1]})"), "inner: expected an object, found array");
  EXPECT_CONTAINS(error_of(R"({"items": {}})"), "items: expected a list, found object");
  EXPECT_CONTAINS(error_of(R"({"kind": "other"})"), "kind: only \"demo\" is supported");
  EXPECT_CONTAINS(error_of(R"({"descriptive": 3})"), "descriptive: expected a string");
  EXPECT_CONTAINS(error_of(R"({"dropout": 0.1})"), "dropout: a training setting");
  EXPECT_EQ(error_of(R"({"dropout": null})"), "");
  EXPECT_CONTAINS(error_of("[]"), "(top level): expected an object, found array");
  // The comment key is configurable.
  long3r::config::Reader::Options comment = kOpt;
  comment.comment_key = "comment";
  EXPECT_CONTAINS(error_of(R"({"note": 1})", comment), "unknown field(s) \"note\"");
  EXPECT_EQ(error_of(R"({"comment": 1})", comment), "");
}

TEST(ConfigJson, InfinityStringsOnlyWhenAllowed) {
  EXPECT_CONTAINS(error_of(R"({"x": "inf"})"), "x: expected a number");
  long3r::config::Reader::Options inf = kOpt;
  inf.inf_strings = true;
  EXPECT_TRUE(std::isinf(read(R"({"x": "inf"})", inf).x));
  EXPECT_LT(read(R"({"x": "-inf"})", inf).x, 0);
  EXPECT_CONTAINS(error_of(R"({"x": "nan"})", inf), "x: expected a number, \"inf\" or \"-inf\"");
}

TEST(ConfigJson, StrictParser) {
  for (const char* bad : {"{", "{\"a\": 1,}", "{\"a\": 1} x", "{/* c */}", "{\"a\": 01}",
                          "{\"a\": NaN}", "{\"a\": Infinity}", "{'a': 1}", "{\"a\": \"\x01\"}",
                          "{\"a\": \"\xff\"}", "{\"a\": \"\\ud800\"}", "{\"a\": 1e999}"}) {
    try {
      (void)long3r::config::parse(bad, "demo config");
      ADD_FAILURE() << "accepted " << bad;
    } catch (const ConfigError& e) {
      EXPECT_CONTAINS(e.what(), "demo config is not valid JSON");
    }
  }
}

TEST(ConfigJson, WriterFollowsTheFieldListAndRoundTrips) {
  demo::Outer o;
  o.x = -std::numeric_limits<double>::infinity();
  o.mode = demo::Mode::kSlow;
  o.items.resize(1);
  o.items[0].n = 8;
  const Json j = long3r::config::to_json(o);
  std::vector<std::string> keys;
  for (const auto& m : j.items()) keys.push_back(m.key());
  // Readers-only entries (ignored, fixed, reject) are not written.
  EXPECT_EQ(keys, (std::vector<std::string>{"flag", "x", "seed", "small", "name", "mode", "inner",
                                            "items", "derived"}));
  EXPECT_EQ(j.at("x"), "-inf");
  EXPECT_EQ(j.at("mode"), "slow");
  EXPECT_EQ(j.dump(),
            R"({"flag":false,"x":"-inf","seed":7,"small":2,"name":"a","mode":"slow",)"
            R"("inner":{"n":3,"list":[1,2]},"items":[{"n":8,"list":[1,2]}],"derived":0})");
  long3r::config::Reader::Options inf = kOpt;
  inf.inf_strings = true;
  const demo::Outer back = read(j.dump(), inf);
  EXPECT_EQ(long3r::config::to_json(back), j);
}

}  // namespace

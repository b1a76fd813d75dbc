// Tests of the strict JSON parser/writer (include/long3r/io/json.hpp): accepted
// syntax, every rejected construct with its error offset, limits, accessors,
// and the model config stored in the golden checkpoints.
#include <gtest/gtest.h>

#include <cstdint>
#include <fstream>
#include <sstream>
#include <string>

#include "long3r/io/json.hpp"
#include "long3r/model/safetensors.hpp"

namespace json = long3r::json;

namespace {

// Offset reported for a rejected document, or -1 if it parsed.
long error_offset(const std::string& text, const json::ParseOptions& opt = {}) {
  try {
    json::parse(text, opt);
  } catch (const json::ParseError& e) {
    return static_cast<long>(e.offset());
  }
  return -1;
}

std::string error_message(const std::string& text) {
  try {
    json::parse(text);
  } catch (const json::ParseError& e) {
    return e.what();
  }
  return "";
}

}  // namespace

TEST(Json, Scalars) {
  EXPECT_TRUE(json::parse("null").is_null());
  EXPECT_TRUE(json::parse(" true ").as_bool());
  EXPECT_FALSE(json::parse("false").as_bool());
  EXPECT_EQ(json::parse("0").as_int(), 0);
  EXPECT_EQ(json::parse("-17").as_int(), -17);
  EXPECT_EQ(json::parse("9223372036854775807").as_int(), INT64_MAX);
  EXPECT_EQ(json::parse("-9223372036854775808").as_int(), INT64_MIN);
  EXPECT_DOUBLE_EQ(json::parse("1.5").as_double(), 1.5);
  EXPECT_DOUBLE_EQ(json::parse("-2.5e-3").as_double(), -2.5e-3);
  EXPECT_DOUBLE_EQ(json::parse("1E2").as_double(), 100.0);
  EXPECT_DOUBLE_EQ(json::parse("4").as_double(), 4.0);  // integers are numbers too
  EXPECT_EQ(json::parse("\"abc\"").as_string(), "abc");
  EXPECT_EQ(json::parse("\t\r\n [ ] \n").size(), 0u);
}

TEST(Json, IntegersAreStrict) {
  EXPECT_TRUE(json::parse("3").is_int());
  EXPECT_FALSE(json::parse("3.0").is_int());
  EXPECT_FALSE(json::parse("3e0").is_int());
  EXPECT_THROW(json::parse("3.0").as_int(), json::Error);
  // Beyond int64: kept as a double, refused as an integer.
  const json::Value big = json::parse("9223372036854775808");
  EXPECT_FALSE(big.is_int());
  EXPECT_THROW(big.as_int(), json::Error);
  EXPECT_DOUBLE_EQ(big.as_double(), 9223372036854775808.0);
}

TEST(Json, ExtremeDoubles) {
  EXPECT_EQ(json::parse("1e-400").as_double(), 0.0);  // underflow -> 0, as Python
  EXPECT_TRUE(std::signbit(json::parse("-1e-400").as_double()));
  EXPECT_DOUBLE_EQ(json::parse("4.9e-324").as_double(), 4.9e-324);
  EXPECT_EQ(error_offset("[1, 1e400]"), 4);
  EXPECT_EQ(error_offset("-1e400"), 0);
  EXPECT_EQ(error_offset(std::string("1") + std::string(400, '0')), 0);
  // 400 zeros after the point then a digit: a tiny number, not an overflow.
  EXPECT_EQ(json::parse("0." + std::string(400, '0') + "1").as_double(), 0.0);
}

TEST(Json, ObjectsKeepOrderAndLookUp) {
  const json::Value v = json::parse(R"({"b": 1, "a": [true, null, "x"], "c": {"d": 2.5}})");
  ASSERT_TRUE(v.is_object());
  ASSERT_EQ(v.as_object().size(), 3u);
  EXPECT_EQ(v.as_object()[0].first, "b");
  EXPECT_EQ(v.as_object()[1].first, "a");
  EXPECT_EQ(v.at("b").as_int(), 1);
  EXPECT_TRUE(v.at("a").at(0).as_bool());
  EXPECT_TRUE(v.at("a").at(1).is_null());
  EXPECT_EQ(v.at("a").at(2).as_string(), "x");
  EXPECT_DOUBLE_EQ(v.at("c").at("d").as_double(), 2.5);
  EXPECT_TRUE(v.contains("c"));
  EXPECT_FALSE(v.contains("z"));
  EXPECT_EQ(v.find("z"), nullptr);
}

TEST(Json, AccessorErrorsSayWhatIsWrong) {
  const json::Value v = json::parse(R"({"n": 4, "s": "x", "l": [1]})");
  try {
    v.at("missing");
    FAIL() << "no throw";
  } catch (const json::Error& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("\"missing\""), std::string::npos) << m;
    EXPECT_NE(m.find("n, s, l"), std::string::npos) << m;
  }
  try {
    v.at("s").as_int();
    FAIL() << "no throw";
  } catch (const json::Error& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("expected integer"), std::string::npos) << m;
    EXPECT_NE(m.find("string \"x\""), std::string::npos) << m;
  }
  EXPECT_THROW(v.at("l").at(1), json::Error);
  EXPECT_THROW(v.at("n").as_string(), json::Error);
  EXPECT_THROW(v.at("n").as_array(), json::Error);
  EXPECT_THROW(v.at("n").as_object(), json::Error);
  EXPECT_THROW(v.at("n").as_bool(), json::Error);
  EXPECT_THROW(v.at("n").size(), json::Error);
  EXPECT_THROW(v.at("l").at("k"), json::Error);
  EXPECT_THROW(v.at("l").as_double(), json::Error);
}

TEST(Json, NumberVectors) {
  const json::Value v = json::parse(R"({"hooks": [0, 5, 7, 10], "x": [1, 2.5], "s": [1, "a"]})");
  EXPECT_EQ(v.at("hooks").as_int_vector(), (std::vector<int64_t>{0, 5, 7, 10}));
  EXPECT_EQ(v.at("x").as_double_vector(), (std::vector<double>{1.0, 2.5}));
  try {
    v.at("x").as_int_vector();
    FAIL() << "no throw";
  } catch (const json::Error& e) {
    EXPECT_NE(std::string(e.what()).find("array index 1"), std::string::npos) << e.what();
  }
  EXPECT_THROW(v.at("s").as_double_vector(), json::Error);
  EXPECT_THROW(v.at("hooks").at(0).as_int_vector(), json::Error);
}

TEST(Json, GetOrHelpers) {
  const json::Value v = json::parse(R"({"i": 3, "d": 0.5, "s": "t", "b": true, "z": null})");
  EXPECT_EQ(v.get_int_or("i", 7), 3);
  EXPECT_EQ(v.get_int_or("absent", 7), 7);
  EXPECT_EQ(v.get_int_or("z", 7), 7);  // null counts as absent
  EXPECT_DOUBLE_EQ(v.get_double_or("d", 1.0), 0.5);
  EXPECT_DOUBLE_EQ(v.get_double_or("i", 1.0), 3.0);
  EXPECT_DOUBLE_EQ(v.get_double_or("absent", 1.0), 1.0);
  EXPECT_EQ(v.get_string_or("s", "u"), "t");
  EXPECT_EQ(v.get_string_or("absent", "u"), "u");
  EXPECT_TRUE(v.get_bool_or("b", false));
  EXPECT_FALSE(v.get_bool_or("absent", false));
  // Present but wrong type: an error naming the key, not the default.
  try {
    v.get_int_or("s", 7);
    FAIL() << "no throw";
  } catch (const json::Error& e) {
    EXPECT_NE(std::string(e.what()).find("\"s\""), std::string::npos) << e.what();
  }
  EXPECT_THROW(v.get_int_or("d", 7), json::Error);
  EXPECT_THROW(v.get_bool_or("i", false), json::Error);
}

TEST(Json, StringEscapes) {
  EXPECT_EQ(json::parse(R"("a\"b\\c\/d\be\ff\ng\rh\ti")").as_string(), "a\"b\\c/d\be\ff\ng\rh\ti");
  EXPECT_EQ(json::parse(R"("\u0041\u00e9\u20AC")").as_string(), "A\xC3\xA9\xE2\x82\xAC");
  EXPECT_EQ(json::parse(R"("\ud83d\ude00")").as_string(), "\xF0\x9F\x98\x80");  // U+1F600
  EXPECT_EQ(json::parse(R"("\uDBFF\uDFFF")").as_string(), "\xF4\x8F\xBF\xBF");  // U+10FFFF
  EXPECT_EQ(json::parse(R"("\u0000")").as_string(), std::string(1, '\0'));
  // Raw UTF-8 passes through.
  EXPECT_EQ(json::parse("\"\xC3\xA9\xF0\x9F\x98\x80\"").as_string(), "\xC3\xA9\xF0\x9F\x98\x80");
}

TEST(Json, BadStringsReportOffsets) {
  EXPECT_EQ(error_offset(R"("\ude00")"), 1);        // lone low surrogate
  EXPECT_EQ(error_offset(R"("\ud83d")"), 1);        // lone high surrogate
  EXPECT_EQ(error_offset(R"("\ud83dx")"), 1);       // high not followed by an escape
  EXPECT_EQ(error_offset(R"("\ud83d\u0041")"), 1);  // high followed by a non-low
  EXPECT_EQ(error_offset(R"("ab\x")"), 3);          // unknown escape
  EXPECT_EQ(error_offset(R"("\u12G4")"), 5);        // bad hex digit
  EXPECT_EQ(error_offset(R"("\u12")"), 3);          // truncated \u
  EXPECT_EQ(error_offset("\"abc"), 0);              // unterminated
  EXPECT_EQ(error_offset("\"a\nb\""), 2);           // raw control character
  EXPECT_EQ(error_offset("\"a\x01\""), 2);
  EXPECT_EQ(error_offset("\"\xC0\x80\""), 1);          // overlong NUL
  EXPECT_EQ(error_offset("\"\xE0\x80\xAF\""), 1);      // overlong '/'
  EXPECT_EQ(error_offset("\"\xED\xA0\x80\""), 1);      // encoded surrogate
  EXPECT_EQ(error_offset("\"\xF4\x90\x80\x80\""), 1);  // above U+10FFFF
  EXPECT_EQ(error_offset("\"\xF5\x80\x80\x80\""), 1);
  EXPECT_EQ(error_offset("\"ok\x80\""), 3);    // stray continuation byte
  EXPECT_EQ(error_offset("\"\xE2\x82\""), 1);  // truncated sequence
  EXPECT_EQ(error_offset("'single'"), 0);
}

TEST(Json, BadSyntaxReportsOffsets) {
  EXPECT_EQ(error_offset(""), 0);
  EXPECT_EQ(error_offset("   "), 3);
  EXPECT_EQ(error_offset("[1, 2,]"), 6);  // trailing comma
  EXPECT_EQ(error_offset("{\"a\": 1,}"), 8);
  EXPECT_EQ(error_offset("[1 2]"), 3);
  EXPECT_EQ(error_offset("{\"a\" 1}"), 5);
  EXPECT_EQ(error_offset("{a: 1}"), 1);  // unquoted key
  EXPECT_EQ(error_offset("{1: 1}"), 1);
  EXPECT_EQ(error_offset("[1] x"), 4);  // trailing garbage
  EXPECT_EQ(error_offset("[1]]"), 3);
  EXPECT_EQ(error_offset("[1"), 2);  // truncated
  EXPECT_EQ(error_offset("{\"a\":"), 5);
  EXPECT_EQ(error_offset("01"), 0);  // leading zero
  EXPECT_EQ(error_offset("-"), 1);
  EXPECT_EQ(error_offset("+1"), 0);
  EXPECT_EQ(error_offset("1."), 2);
  EXPECT_EQ(error_offset(".5"), 0);
  EXPECT_EQ(error_offset("1e"), 2);
  EXPECT_EQ(error_offset("1e+"), 3);
  EXPECT_EQ(error_offset("NaN"), 0);
  EXPECT_EQ(error_offset("Infinity"), 0);
  EXPECT_EQ(error_offset("-Infinity"), 1);
  EXPECT_EQ(error_offset("tru"), 0);
  EXPECT_EQ(error_offset("nul"), 0);
  EXPECT_EQ(error_offset("[1] // c"), 4);  // no comments
  EXPECT_EQ(error_offset(std::string("[1,\0 2]", 7)), 3);
  // The message carries the offset and names the problem.
  const std::string m = error_message("[1, 2,]");
  EXPECT_NE(m.find("byte 6"), std::string::npos) << m;
  EXPECT_NE(m.find("expected a value"), std::string::npos) << m;
}

TEST(Json, DuplicateKeys) {
  EXPECT_EQ(error_offset(R"({"a": 1, "b": 2, "a": 3})"), 17);
  EXPECT_NE(error_message(R"({"a": 1, "a": 3})").find("duplicate object key \"a\""),
            std::string::npos);
  json::ParseOptions opt;
  opt.allow_duplicate_keys = true;
  const json::Value v = json::parse(R"({"a": 1, "a": 3})", opt);
  ASSERT_EQ(v.size(), 2u);
  EXPECT_EQ(v.at("a").as_int(), 1);  // first one is found
}

TEST(Json, DepthLimit) {
  const auto nested = [](std::size_t depth) {
    return std::string(depth, '[') + std::string(depth, ']');
  };
  EXPECT_EQ(error_offset(nested(64)), -1);
  EXPECT_EQ(error_offset(nested(65)), 64);
  json::ParseOptions opt;
  opt.max_depth = 3;
  EXPECT_EQ(error_offset(R"({"a": {"b": [1]}})", opt), -1);
  EXPECT_EQ(error_offset(R"({"a": {"b": [[1]]}})", opt), 13);
  // Far beyond the limit: refused without deep recursion.
  EXPECT_EQ(error_offset(std::string(1000000, '[')), 64);
}

TEST(Json, SizeLimit) {
  json::ParseOptions opt;
  opt.max_size = 10;
  EXPECT_EQ(error_offset("[1,2,3,4]", opt), -1);
  EXPECT_EQ(error_offset("[1,2,3,4,5]", opt), 0);
  try {
    json::parse("[1,2,3,4,5]", opt);
    FAIL() << "no throw";
  } catch (const json::ParseError& e) {
    EXPECT_NE(std::string(e.what()).find("exceeds the limit of 10 bytes"), std::string::npos);
  }
}

TEST(Json, ValueCountLimit) {
  json::ParseOptions opt;
  opt.max_values = 5;
  EXPECT_EQ(error_offset("[1, [2], 3]", opt), -1);  // 5 values, arrays included
  EXPECT_EQ(error_offset("[1, [2], 3, 4]", opt), 12);
  EXPECT_EQ(error_offset(R"({"a": {"b": 1, "c": 2}})", opt), -1);  // keys are not values
  opt.max_values = 3;
  EXPECT_EQ(error_offset(R"({"a": {"b": 1, "c": 2}})", opt), 20);
}

TEST(Json, DumpFormatsLikePython) {
  // Python: json.dumps([3.0, 0.0005, 1e-06, 1e16, 123.456, 0.1, -0.0, 1.5e300, 5e-324, 2.5e-05])
  const json::Value v =
      json::parse("[3.0, 0.0005, 1e-6, 1e16, 123.456, 0.1, -0.0, 1.5e300, 5e-324, 2.5e-5, 7]");
  EXPECT_EQ(v.dump(),
            "[3.0, 0.0005, 1e-06, 1e+16, 123.456, 0.1, -0.0, 1.5e+300, 5e-324, 2.5e-05, 7]");
  EXPECT_EQ(json::Value(std::string("a\"\\\n\x01\xC3\xA9")).dump(),
            "\"a\\\"\\\\\\n\\u0001\xC3\xA9\"");
  json::Value o(json::Object{});
  o.set("k", json::Array{json::Value(1), json::Value("x"), json::Value(nullptr)});
  o.set("b", false);
  o.set("k", 2);  // replaces in place
  EXPECT_EQ(o.dump(), "{\"k\": 2, \"b\": false}");
  EXPECT_EQ(o.dump(2), "{\n  \"k\": 2,\n  \"b\": false\n}");
  EXPECT_THROW(json::Value(std::nan("")), json::Error);
  EXPECT_THROW(json::Value(static_cast<uint64_t>(1) << 63), json::Error);
}

TEST(Json, DumpParsesBackEqual) {
  const std::string text =
      R"({"a": [1, -2.25, "\u00e9\ud83d\ude00", {"b": null, "c": [true, false]}], "d": {}, "e": []})";
  const json::Value v = json::parse(text);
  EXPECT_EQ(json::parse(v.dump()), v);
  EXPECT_EQ(json::parse(v.dump(4)), v);
  EXPECT_NE(json::parse(R"({"a": 1})"), json::parse(R"({"a": 2})"));
  EXPECT_EQ(json::parse(R"({"a": 1, "b": 2})"), json::parse(R"({"b": 2, "a": 1.0})"));
}

// The config in the golden checkpoints: parses, reads as the model code will
// read it, and dumps back to exactly the bytes Python's json.dumps wrote.
TEST(Json, GoldenCheckpointConfig) {
  const std::string dir = std::string(LONG3R_SHARED_DIR) + "/golden/";
  for (const char* c : {"dust3r_pair_sq224", "spann3r_seq_land96x64"}) {
    SCOPED_TRACE(c);
    const long3r::TensorFile f = long3r::load_safetensors(dir + c + "/weights.safetensors");
    const std::string& text = f.metadata.at("config");
    const json::Value cfg = json::parse(text);
    EXPECT_EQ(cfg.dump(), text);
    const json::Value& d = cfg.at("dust3r");
    EXPECT_EQ(d.at("enc_embed_dim").as_int(), 32);
    EXPECT_EQ(d.at("dec_depth").as_int(), 10);
    EXPECT_EQ(d.at("norm_layer").as_string(), "LayerNorm(eps=1e-6)");
    EXPECT_DOUBLE_EQ(d.at("mask_ratio").as_double(), 0.9);
    const json::Value& depth_mode = d.at("depth_mode");
    ASSERT_EQ(depth_mode.size(), 3u);
    EXPECT_EQ(depth_mode.at(0).as_string(), "exp");
    EXPECT_EQ(depth_mode.at(1).as_string(), "-inf");
    EXPECT_EQ(d.at("conf_mode").at(1).as_int(), 1);
    EXPECT_EQ(d.at("dpt_head").at("hooks").as_int_vector(), (std::vector<int64_t>{0, 5, 7, 10}));
    EXPECT_FALSE(d.at("dpt_head").at("use_bn").as_bool());

    // case.json holds the same config (in another key order).
    std::ifstream in(dir + c + "/case.json");
    std::stringstream ss;
    ss << in.rdbuf();
    EXPECT_EQ(json::parse(ss.str()).at("config"), cfg);
  }
}

// Tests of the command-line options table: parsing into bound variables,
// handlers, positionals, required options, the errors (each naming the
// option) and the help text generated from the same table.
#include <gtest/gtest.h>
#include <cctype>

#include <array>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "long3r/config/cli_options.hpp"
#include "support/test_support.hpp"

namespace {

using long3r::CliOptions;
using long3r::UsageError;
using long3r::test::Argv;

// A table with one option of every kind.
struct Tool {
  std::string out, mode = "fast", input;
  int frames = 50;
  int64_t big = -1;
  uint64_t seed = 7;
  double scale = 0.25;
  float conf = 1.5f;
  bool quiet = false, normals = true;
  std::vector<std::string> tags;
  std::vector<std::string> rest;
  int lo = 10, hi = 18;
  CliOptions cli{"prog", "Does things."};

  explicit Tool(bool list_positional = false) {
    cli.option("--out", "DIR", &out, "where to write").required();
    cli.option("--frames", "N", &frames, "frames per sequence").min(2).max(1000);
    cli.option("--big", "N", &big, "a large count").shown_default("");
    cli.option("--seed", "N", &seed, "seed");
    cli.option("--scale", "S", &scale, "scale factor").above(0);
    cli.option("--conf", "C", &conf, "confidence threshold");
    cli.option("--mode", "", &mode, "speed").choices({"fast", "exact"});
    cli.flag("--quiet", &quiet, "no progress output");
    cli.flag("--no-normals", &normals, "skip normals", false);
    cli.option("--tag", "T", &tags, "a tag (repeatable)");
    cli.custom(
        "--range", {"MIN", "MAX"},
        [this](const std::vector<std::string>& v) {
          lo = long3r::parse_cli_value<int>("--range", v[0]);
          hi = long3r::parse_cli_value<int>("--range", v[1]);
        },
        "count range");
    if (list_positional) {
      cli.positional("FILE", &rest, "inputs").required();
    } else {
      cli.positional("INPUT", &input, "the input").required();
    }
  }

  bool parse(std::vector<std::string> words) {
    const Argv a(std::move(words));
    return cli.parse(a.argc(), a.argv());
  }
};

// The message of the UsageError that parsing `words` throws.
std::string error_of(std::vector<std::string> words, bool list_positional = false) {
  Tool t(list_positional);
  try {
    t.parse(std::move(words));
  } catch (const UsageError& e) {
    return e.what();
  }
  ADD_FAILURE() << "no UsageError";
  return "";
}

std::size_t count(const std::string& text, const std::string& what) {
  std::size_t n = 0;
  for (std::size_t p = text.find(what); p != std::string::npos; p = text.find(what, p + 1)) ++n;
  return n;
}

TEST(CliOptions, ParsesIntoTheBoundVariables) {
  Tool t;
  ASSERT_TRUE(t.parse({"--out",   "o",          "--frames", "12",
                       "--big",   "9000000000", "--seed",   "18446744073709551615",
                       "--scale", "2.5e-1",     "--conf",   "3",
                       "--mode",  "exact",      "--quiet",  "--no-normals",
                       "--range", "-3",         "4",        "in"}));
  EXPECT_EQ(t.out, "o");
  EXPECT_EQ(t.frames, 12);
  EXPECT_EQ(t.big, 9000000000LL);
  EXPECT_EQ(t.seed, UINT64_MAX);
  EXPECT_DOUBLE_EQ(t.scale, 0.25);
  EXPECT_FLOAT_EQ(t.conf, 3.0f);
  EXPECT_EQ(t.mode, "exact");
  EXPECT_TRUE(t.quiet);
  EXPECT_FALSE(t.normals);
  EXPECT_EQ(t.lo, -3);
  EXPECT_EQ(t.hi, 4);
  EXPECT_EQ(t.input, "in");
  EXPECT_TRUE(t.cli.given("--frames"));
  EXPECT_FALSE(t.cli.given("--tag"));
}

TEST(CliOptions, DefaultsStayWhenNotGiven) {
  Tool t;
  ASSERT_TRUE(t.parse({"in", "--out", "o"}));
  EXPECT_EQ(t.frames, 50);
  EXPECT_EQ(t.big, -1);
  EXPECT_EQ(t.seed, 7u);
  EXPECT_EQ(t.mode, "fast");
  EXPECT_FALSE(t.quiet);
  EXPECT_TRUE(t.normals);
  EXPECT_FALSE(t.cli.given("--frames"));
}

TEST(CliOptions, ValuesAreTakenAsIsEvenWithALeadingDash) {
  Tool t;
  ASSERT_TRUE(t.parse({"--out", "--quiet", "--scale", "1", "in"}));
  EXPECT_EQ(t.out, "--quiet");
  EXPECT_FALSE(t.quiet);
}

TEST(CliOptions, LaterValuesOverrideAndVectorsCollect) {
  Tool t;
  ASSERT_TRUE(t.parse({"--out", "a", "--frames", "3", "--tag", "x", "--out", "b", "--frames", "4",
                       "--tag", "y", "in"}));
  EXPECT_EQ(t.out, "b");
  EXPECT_EQ(t.frames, 4);
  EXPECT_EQ(t.tags, (std::vector<std::string>{"x", "y"}));
}

TEST(CliOptions, PositionalList) {
  Tool t(true);
  ASSERT_TRUE(t.parse({"a", "--out", "o", "b", "c"}));
  EXPECT_EQ(t.rest, (std::vector<std::string>{"a", "b", "c"}));
  EXPECT_EQ(error_of({"--out", "o"}, true), "no FILE given");
}

TEST(CliOptions, HelpStopsParsing) {
  Tool t;
  EXPECT_FALSE(t.parse({"--frames", "5", "--help", "--bogus"}));
  EXPECT_EQ(t.frames, 5);
  Tool u;
  EXPECT_FALSE(u.parse({"-h"}));  // required options are not asked for
}

TEST(CliOptions, ErrorsNameTheOption) {
  EXPECT_EQ(error_of({"--out", "o", "in", "--bogus"}), "unknown option --bogus");
  // --flag=VALUE is not a spelling of --flag VALUE.
  EXPECT_EQ(error_of({"--out", "o", "in", "--frames=5"}), "unknown option --frames=5");
  EXPECT_EQ(error_of({"in", "--out"}), "--out needs a value (DIR)");
  EXPECT_EQ(error_of({"in", "--out", "o", "--range", "1"}), "--range needs 2 values (MIN MAX)");
  EXPECT_EQ(error_of({"in"}), "--out DIR is required");
  EXPECT_EQ(error_of({"--out", "o"}), "no INPUT given");
  EXPECT_EQ(error_of({"--out", "o", "a", "b"}), "unexpected argument b");
  EXPECT_EQ(error_of({"in", "--out", "o", "--frames", "12x"}),
            "--frames: \"12x\" is not an integer");
  EXPECT_EQ(error_of({"in", "--out", "o", "--frames", ""}), "--frames: \"\" is not an integer");
  EXPECT_EQ(error_of({"in", "--out", "o", "--frames", "99999999999"}),
            "--frames: \"99999999999\" is out of range");
  EXPECT_EQ(error_of({"in", "--out", "o", "--frames", "1"}), "--frames must be >= 2 (got 1)");
  EXPECT_EQ(error_of({"in", "--out", "o", "--frames", "1001"}),
            "--frames must be <= 1000 (got 1001)");
  EXPECT_EQ(error_of({"in", "--out", "o", "--seed", "-1"}),
            "--seed: \"-1\" is not a non-negative integer");
  EXPECT_EQ(error_of({"in", "--out", "o", "--scale", "abc"}), "--scale: \"abc\" is not a number");
  EXPECT_EQ(error_of({"in", "--out", "o", "--scale", "0"}), "--scale must be > 0 (got 0)");
  EXPECT_EQ(error_of({"in", "--out", "o", "--scale", "nan"}), "--scale must be > 0 (got nan)");
  EXPECT_EQ(error_of({"in", "--out", "o", "--mode", "slow"}),
            "--mode must be fast or exact (got \"slow\")");
  EXPECT_EQ(error_of({"in", "--out", "o", "--range", "1", "x"}),
            "--range: \"x\" is not an integer");
}

enum class Speed { kFast, kExact };
const std::array<std::pair<Speed, const char*>, 2>& enum_names(Speed) {
  static const std::array<std::pair<Speed, const char*>, 2> names{
      {{Speed::kFast, "fast"}, {Speed::kExact, "exact"}}};
  return names;
}

// An enum option reads the names the config files use, shows its default by
// name, and names the choices when refused.
TEST(CliOptions, EnumOptionsGoByName) {
  Speed speed = Speed::kExact;
  CliOptions cli("prog");
  cli.option("--speed", "S", &speed, "how");
  EXPECT_NE(cli.help().find("(default exact)"), std::string::npos) << cli.help();
  const Argv good({"--speed", "fast"});
  ASSERT_TRUE(cli.parse(good.argc(), good.argv()));
  EXPECT_EQ(speed, Speed::kFast);
  const Argv bad({"--speed", "slow"});
  try {
    cli.parse(bad.argc(), bad.argv());
    ADD_FAILURE() << "no UsageError";
  } catch (const UsageError& e) {
    EXPECT_EQ(std::string(e.what()), "--speed must be \"fast\" or \"exact\" (got \"slow\")");
  }
  EXPECT_EQ(speed, Speed::kFast);
}

TEST(CliOptions, HandlerExceptionsBecomeUsageErrors) {
  CliOptions cli("prog");
  cli.custom(
      "--kind", {"K"},
      [](const std::vector<std::string>& v) {
        throw std::invalid_argument("unknown kind " + v[0]);
      },
      "a kind");
  const Argv a({"--kind", "x"});
  try {
    cli.parse(a.argc(), a.argv());
    FAIL() << "no UsageError";
  } catch (const UsageError& e) {
    EXPECT_STREQ(e.what(), "--kind: unknown kind x");
  }
}

TEST(CliOptions, HelpListsEachOptionOnceWithItsDefault) {
  Tool t;
  const std::string h = t.cli.help();
  EXPECT_EQ(h.rfind("usage: prog --out DIR [options] INPUT\nDoes things.\n", 0), 0u) << h;
  for (const char* name : {"--out DIR", "--frames N", "--big N", "--seed N", "--scale S",
                           "--conf C", "--mode fast|exact", "--quiet", "--no-normals", "--tag T",
                           "--range MIN MAX", "-h, --help"}) {
    EXPECT_EQ(count(h, std::string("  ") + name + " "), 1u) << name << "\n" << h;
  }
  EXPECT_EQ(count(h, "\n  INPUT "), 1u) << h;
  EXPECT_NE(h.find("frames per sequence (default 50)"), std::string::npos) << h;
  EXPECT_NE(h.find("scale factor (default 0.25)"), std::string::npos) << h;
  EXPECT_NE(h.find("confidence threshold (default 1.5)"), std::string::npos) << h;
  EXPECT_NE(h.find("seed (default 7)"), std::string::npos) << h;
  EXPECT_NE(h.find("speed (default fast)"), std::string::npos) << h;
  EXPECT_EQ(h.find("a large count (default"), std::string::npos) << h;   // hidden
  EXPECT_EQ(h.find("where to write (default"), std::string::npos) << h;  // empty string
  EXPECT_EQ(h.find("no progress output (default"), std::string::npos) << h;
  for (std::size_t b = 0, e; b < h.size(); b = e + 1) {
    e = h.find('\n', b);
    EXPECT_LE(e - b, 80u) << h.substr(b, e - b);
  }
}

TEST(CliOptions, HelpSectionsAndWrapping) {
  std::string a, b;
  CliOptions cli("prog");
  cli.section("inputs");
  cli.option("--a", "X", &a,
             "a rather long help text that needs more than one line of the table to say all "
             "that it has to say about the option");
  cli.section("output");
  cli.option("--a-very-long-option-name", "VALUE", &b, "short");
  const std::string h = cli.help();
  EXPECT_NE(h.find("\ninputs:\n  --a X "), std::string::npos) << h;
  EXPECT_NE(h.find("\noutput:\n  --a-very-long-option-name VALUE\n"), std::string::npos) << h;
  EXPECT_GE(count(h, "\n                              "), 2u) << h;  // continuation lines
}

TEST(CliOptions, ParseOrExitStatus) {
  {
    Tool t;
    const Argv a({"--help"});
    testing::internal::CaptureStdout();
    EXPECT_EQ(t.cli.parse_or_exit(a.argc(), a.argv()), 0);
    EXPECT_EQ(testing::internal::GetCapturedStdout(), t.cli.help());
  }
  {
    Tool t;
    const Argv a({"in", "--bogus"});
    testing::internal::CaptureStderr();
    EXPECT_EQ(t.cli.parse_or_exit(a.argc(), a.argv()), 2);
    EXPECT_EQ(testing::internal::GetCapturedStderr(),
              "prog: unknown option --bogus\n" + t.cli.help());
  }
  {
    Tool t;
    const Argv a({"in", "--out", "o"});
    EXPECT_EQ(t.cli.parse_or_exit(a.argc(), a.argv()), std::nullopt);
  }
}

TEST(CliOptions, DefiningAnOptionTwiceIsAProgrammingError) {
  bool x = false;
  CliOptions cli("prog");
  cli.flag("--x", &x, "x");
  EXPECT_THROW(cli.flag("--x", &x, "x"), std::logic_error);
  EXPECT_THROW(cli.flag("--help", &x, "x"), std::logic_error);
}

// Config structs with field lists, as the pipeline's are.
enum class Colour { kRed, kGreen };
const std::array<std::pair<Colour, const char*>, 2>& enum_names(Colour) {
  static const std::array<std::pair<Colour, const char*>, 2> names{
      {{Colour::kRed, "red"}, {Colour::kGreen, "green"}}};
  return names;
}
struct Inner {
  double min_baseline_m = 0.1;
  bool freeze = true;
  Colour colour = Colour::kRed;
};
template <class S, class V>
long3r::config::FieldsOf<S, Inner> visit_fields(S& s, V& v) {
  v("min_baseline_m", s.min_baseline_m);
  v("freeze", s.freeze);
  v("colour", s.colour);
}
struct Outer {
  int lost_frames = 0;
  std::size_t cap = 5;
  Inner inner;
};
template <class S, class V>
long3r::config::FieldsOf<S, Outer> visit_fields(S& s, V& v) {
  v("lost_frames", s.lost_frames, "(no bound)");
  v("cap", s.cap);
  v.nested("inner", s.inner, "scale_");
}

TEST(CliOptions, ConfigFieldsAreOptionsByTheirFlatNames) {
  Outer c;
  CliOptions cli("prog");
  long3r::add_config_options(cli, &c);
  const Argv argv({"--lost-frames", "3", "--cap", "9", "--scale-min-baseline-m", "0.5",
                   "--scale-freeze", "false", "--scale-colour", "green"});
  ASSERT_TRUE(cli.parse(argv.argc(), argv.argv()));
  EXPECT_EQ(c.lost_frames, 3);
  EXPECT_EQ(c.cap, 9u);
  EXPECT_EQ(c.inner.min_baseline_m, 0.5);
  EXPECT_FALSE(c.inner.freeze);
  EXPECT_EQ(c.inner.colour, Colour::kGreen);
  const std::string help = cli.help();
  EXPECT_NE(help.find("--scale-freeze BOOL"), std::string::npos) << help;
  EXPECT_NE(help.find("--scale-min-baseline-m X"), std::string::npos) << help;
  EXPECT_NE(help.find("--scale-colour NAME"), std::string::npos) << help;
  EXPECT_NE(help.find("scale_colour: \"red\" or \"green\""), std::string::npos) << help;
  EXPECT_NE(help.find("(default red)"), std::string::npos) << help;
  EXPECT_NE(help.find("(default 0 (no"), std::string::npos) << help;

  // Every default is the node's here: no option says otherwise.
  EXPECT_EQ(help.find("the node's default"), std::string::npos) << help;

  Outer d;
  CliOptions strict("prog");
  long3r::add_config_options(strict, &d);
  const Argv bad({"--scale-freeze", "yes"});
  try {
    strict.parse(bad.argc(), bad.argv());
    FAIL() << "no error for a boolean written yes";
  } catch (const UsageError& e) {
    EXPECT_STREQ(e.what(), "--scale-freeze must be true or false (got \"yes\")");
  }
}

TEST(CliOptions, AToolsOwnDefaultNamesTheNodes) {
  // A tool that sets a field before adding the options (long3r_reconstruct's
  // drop_zero_stamps) shows its own default and says the node's.
  Outer c;
  c.inner.freeze = false;
  c.inner.colour = Colour::kGreen;
  CliOptions cli("prog");
  long3r::add_config_options(cli, &c);
  // The help's rows wrapped and indented: compared with single spaces.
  std::string help;
  for (const char ch : cli.help()) {
    const bool space = std::isspace(static_cast<unsigned char>(ch)) != 0;
    if (!space || (!help.empty() && help.back() != ' ')) help += space ? ' ' : ch;
  }
  for (const char* text :
       {"scale_freeze; the node's default is true, this tool's differs", "(default false)",
        "the node's default is red, this tool's differs", "(default green)"}) {
    EXPECT_NE(help.find(text), std::string::npos) << text << "\n" << help;
  }
  // Only those two.
  std::size_t notes = 0;
  for (std::size_t at = help.find("the node's default"); at != std::string::npos;
       at = help.find("the node's default", at + 1)) {
    ++notes;
  }
  EXPECT_EQ(notes, 2u) << help;
}

}  // namespace

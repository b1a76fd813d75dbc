// Command-line options of the tools in src/apps: one table in which each flag
// is written once (name, value placeholder, help text, shown default, the
// variable it sets or a handler), from which both the parsing and `--help`
// come. Torch-free.
//
// Rules (those of the tools before the table existed): `--flag VALUE` as two
// arguments (`--flag=VALUE` is an unknown option); a value is taken as is,
// even when it starts with '-'; a later repeat of a flag overrides an earlier
// one unless it is bound to a vector; `-h` / `--help` prints the help and
// exits 0; bad usage prints the error, naming the flag, and the help to
// stderr and exits 2.
#pragma once

#include <functional>
#include <limits>
#include <map>
#include <memory>
#include <optional>
#include <sstream>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include "long3r/config/config_fields.hpp"

namespace long3r {

// Bad command-line usage; the message names the option.
class UsageError : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};

// Strict conversions of one option value: the whole text must be a number
// within [lo, hi]; `flag` names the option in the error.
long long parse_cli_integer(const std::string& flag, const std::string& text, long long lo,
                            long long hi);
unsigned long long parse_cli_unsigned(const std::string& flag, const std::string& text,
                                      unsigned long long hi);
double parse_cli_double(const std::string& flag, const std::string& text);

template <typename T>
T parse_cli_value(const std::string& flag, const std::string& text) {
  if constexpr (std::is_same_v<T, std::string>) {
    return text;
  } else if constexpr (std::is_floating_point_v<T>) {
    return static_cast<T>(parse_cli_double(flag, text));
  } else {
    static_assert(std::is_integral_v<T> && !std::is_same_v<T, bool>, "unsupported option type");
    using L = std::numeric_limits<T>;
    if constexpr (std::is_unsigned_v<T>) {
      return static_cast<T>(parse_cli_unsigned(flag, text, L::max()));
    } else {
      return static_cast<T>(parse_cli_integer(flag, text, L::min(), L::max()));
    }
  }
}

class CliOptions {
 public:
  // One row of the table. The setters return the row so that a table entry
  // reads as one statement.
  class Option {
   public:
    // Refused unless given.
    Option& required();
    // Shown as the default in --help instead of the bound variable's value;
    // an empty text shows none.
    Option& shown_default(std::string text);
    // Numeric bounds, checked on the value given (inclusive; `above`: strict).
    Option& min(double lo);
    Option& above(double lo);
    Option& max(double hi);
    // The only values a string option accepts (also the placeholder when that
    // is empty).
    Option& choices(std::vector<std::string> values);

   private:
    friend class CliOptions;
    std::string name_;                       // "--flag"; a positional's placeholder
    std::vector<std::string> placeholders_;  // one a value
    std::string help_;
    std::string shown_default_;
    std::vector<std::string> choices_;
    std::optional<double> min_, above_, max_;
    bool required_ = false;
    bool positional_ = false;
    bool repeated_ = false;  // a positional list, or a flag bound to a vector
    bool given_ = false;
    std::string section_;  // heading in --help
    // Converts and stores the values given (checks by `check_number` first).
    std::function<void(const Option&, const std::vector<std::string>&)> apply_;

    void check_number(double v, const std::string& text) const;
    void check_choice(const std::string& text) const;

    template <typename T>
    T convert(const std::string& text) const {
      if constexpr (std::is_same_v<T, std::string>) {
        check_choice(text);
        return text;
      } else if constexpr (std::is_same_v<T, bool>) {
        if (text != "true" && text != "false") {
          throw UsageError(name_ + " must be true or false (got \"" + text + "\")");
        }
        return text == "true";
      } else if constexpr (std::is_enum_v<T>) {  // by its enum_names(), as the config files
        T v{};
        if (!config::enum_from_name(text, &v)) {
          throw UsageError(name_ + " must be " + config::enum_choices<T>() + " (got \"" + text +
                           "\")");
        }
        return v;
      } else {
        const T v = parse_cli_value<T>(name_, text);
        check_number(static_cast<double>(v), text);
        return v;
      }
    }
  };

  // `program` starts the usage line and every error; `description` (may hold
  // newlines) follows the usage line in --help.
  explicit CliOptions(std::string program, std::string description = "");

  // Rows added after this call are listed under `title` in --help.
  void section(std::string title);

  // A value as --help shows defaults (enums by name, booleans true / false).
  template <typename T>
  static std::string format_value(const T& v) {
    return format_default(v);
  }

  // A switch: sets *target = value when given.
  Option& flag(const std::string& name, bool* target, std::string help, bool value = true);

  // `--name VALUE` stored into *target (string, integer, floating point, or
  // an enum with enum_names(), by name); the default shown is the value
  // *target holds now (empty strings: none).
  template <typename T>
  Option& option(const std::string& name, std::string placeholder, T* target, std::string help) {
    Option& o = add(name, {std::move(placeholder)}, std::move(help));
    o.shown_default_ = format_value(*target);
    o.apply_ = [target](const Option& self, const std::vector<std::string>& v) {
      *target = self.convert<T>(v[0]);
    };
    return o;
  }

  // `--name VALUE` given any number of times, each value appended.
  template <typename T>
  Option& option(const std::string& name, std::string placeholder, std::vector<T>* target,
                 std::string help) {
    Option& o = add(name, {std::move(placeholder)}, std::move(help));
    o.repeated_ = true;
    o.apply_ = [target](const Option& self, const std::vector<std::string>& v) {
      target->push_back(self.convert<T>(v[0]));
    };
    return o;
  }

  // `--name V1 V2 ...` (one placeholder a value) passed to `handler`, which
  // converts them (parse_cli_value names the flag) and may throw UsageError.
  Option& custom(const std::string& name, std::vector<std::string> placeholders,
                 std::function<void(const std::vector<std::string>&)> handler, std::string help);

  // The next argument that is not an option; a vector takes all the rest.
  Option& positional(std::string placeholder, std::string* target, std::string help);
  Option& positional(std::string placeholder, std::vector<std::string>* target, std::string help);

  // Parses argv[1..argc). Returns false when -h / --help was given (nothing
  // after it is read); throws UsageError on bad usage.
  bool parse(int argc, const char* const* argv);

  // parse() for main(): returns the exit status when the program should stop
  // now (0 after printing the help to stdout, 2 after a usage error).
  std::optional<int> parse_or_exit(int argc, const char* const* argv);

  // Whether the option (or positional) was on the command line.
  bool given(const std::string& name) const;

  // Prints "program: message" and the help to stderr; returns 2, the status of
  // bad usage (for checks that span several options).
  int usage_error(const std::string& message) const;

  // The usage line, the description and the table.
  std::string help() const;

 private:
  Option& add(const std::string& name, std::vector<std::string> placeholders, std::string help);
  const Option* find(const std::string& name) const;
  std::string left_column(const Option& o) const;

  template <typename T>
  static std::string format_default(const T& v) {
    if constexpr (std::is_enum_v<T>) {
      return config::enum_name(v);
    } else if constexpr (std::is_same_v<T, std::string>) {
      return v;
    } else if constexpr (std::is_same_v<T, bool>) {
      return v ? "true" : "false";
    } else {
      std::ostringstream s;
      s << v;
      return s.str();
    }
  }

  std::string program_, description_, section_;
  std::vector<std::unique_ptr<Option>>
      options_;  // stable addresses: rows are returned by reference
};

// One `--flat-name VALUE` option per field of a config struct, from its
// field list (visit_fields): the flat names are the node's ROS parameter
// names, '_' written '-' (scale_min_samples: --scale-min-samples), so the
// tools and the node share every name and each is written once. Booleans
// take true / false. The default shown is the tool's (the value the field
// holds when the option is added); where that differs from the struct's
// own default, which is the node's, the help says the node's too.
class CliFieldOptions {
 public:
  // node_defaults: each flat name's default as the node has it (format_value).
  CliFieldOptions(CliOptions* cli, std::map<std::string, std::string> node_defaults)
      : cli_(cli), node_defaults_(std::move(node_defaults)) {}

  template <class T>
  void operator()(const std::string& name, T& value, const char* log_note) {
    std::string flag = "--" + name;
    for (char& c : flag) c = c == '_' ? '-' : c;
    std::string help = "the node's parameter " + name;
    if constexpr (std::is_enum_v<T>) help += ": " + config::enum_choices<T>();
    const auto node = node_defaults_.find(name);
    if (node != node_defaults_.end() && node->second != CliOptions::format_value(value)) {
      help += "; the node's default is " + node->second + ", this tool's differs";
    }
    CliOptions::Option& o = cli_->option(flag, placeholder<T>(), &value, help);
    if constexpr (!std::is_enum_v<T>) {
      if (log_note && value == T{}) o.shown_default(format_note(value, log_note));
    }
  }

 private:
  template <class T>
  static std::string placeholder() {
    if constexpr (std::is_same_v<T, bool>) {
      return "BOOL";
    } else if constexpr (std::is_same_v<T, std::string>) {
      return "S";
    } else if constexpr (std::is_enum_v<T>) {
      return "NAME";
    } else if constexpr (std::is_floating_point_v<T>) {
      return "X";
    } else {
      return "N";
    }
  }
  template <class T>
  static std::string format_note(const T& value, const char* note) {
    std::ostringstream s;
    s << value << " " << note;
    return s.str();
  }

  CliOptions* cli_;
  std::map<std::string, std::string> node_defaults_;
};

template <class T>
void add_config_options(CliOptions& cli, T* config) {
  const T defaults{};
  std::map<std::string, std::string> node_defaults;
  config::visit_flat(defaults,
                     [&node_defaults](const std::string& name, const auto& value, const char*) {
                       node_defaults[name] = CliOptions::format_value(value);
                     });
  CliFieldOptions options(&cli, std::move(node_defaults));
  config::visit_flat(*config, options);
}

}  // namespace long3r

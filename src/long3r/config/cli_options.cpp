#include "long3r/config/cli_options.hpp"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <iostream>

namespace long3r {

namespace {

constexpr std::size_t kWidth = 80;      // help lines are wrapped to this width
constexpr std::size_t kMaxColumn = 26;  // a longer flag puts its help on the next line

std::string join(const std::vector<std::string>& v, const std::string& sep) {
  std::string s;
  for (std::size_t i = 0; i < v.size(); ++i) s += (i ? sep : "") + v[i];
  return s;
}

// Words of `text` on lines of at most `width` characters (a longer word gets
// a line of its own); '\n' in the text starts a new line.
std::vector<std::string> wrap(const std::string& text, std::size_t width) {
  std::vector<std::string> lines;
  std::istringstream paragraphs(text);
  std::string paragraph;
  while (std::getline(paragraphs, paragraph)) {
    std::istringstream words(paragraph);
    std::string word, line;
    while (words >> word) {
      if (!line.empty() && line.size() + 1 + word.size() > width) {
        lines.push_back(line);
        line.clear();
      }
      line += (line.empty() ? "" : " ") + word;
    }
    lines.push_back(line);
  }
  return lines;
}

UsageError bad_value(const std::string& flag, const std::string& text, const std::string& what) {
  return UsageError(flag + ": \"" + text + "\" is " + what);
}

std::string number_text(double v) {
  std::ostringstream s;
  s << v;
  return s.str();
}

}  // namespace

long long parse_cli_integer(const std::string& flag, const std::string& text, long long lo,
                            long long hi) {
  errno = 0;
  char* end = nullptr;
  const long long v = std::strtoll(text.c_str(), &end, 10);
  if (text.empty() || *end != '\0') throw bad_value(flag, text, "not an integer");
  if (errno == ERANGE || v < lo || v > hi) {
    throw bad_value(flag, text, "out of range");
  }
  return v;
}

unsigned long long parse_cli_unsigned(const std::string& flag, const std::string& text,
                                      unsigned long long hi) {
  // strtoull would wrap "-1" round to the largest value.
  if (text.find('-') != std::string::npos) {
    throw bad_value(flag, text, "not a non-negative integer");
  }
  errno = 0;
  char* end = nullptr;
  const unsigned long long v = std::strtoull(text.c_str(), &end, 10);
  if (text.empty() || *end != '\0') {
    throw bad_value(flag, text, "not a non-negative integer");
  }
  if (errno == ERANGE || v > hi) throw bad_value(flag, text, "out of range");
  return v;
}

double parse_cli_double(const std::string& flag, const std::string& text) {
  errno = 0;
  char* end = nullptr;
  const double v = std::strtod(text.c_str(), &end);
  if (text.empty() || *end != '\0') throw bad_value(flag, text, "not a number");
  if (errno == ERANGE && (v == HUGE_VAL || v == -HUGE_VAL)) {
    throw bad_value(flag, text, "out of range");
  }
  return v;
}

// ------------------------------------------------------------------- Option

CliOptions::Option& CliOptions::Option::required() {
  required_ = true;
  return *this;
}

CliOptions::Option& CliOptions::Option::shown_default(std::string text) {
  shown_default_ = std::move(text);
  return *this;
}

CliOptions::Option& CliOptions::Option::min(double lo) {
  min_ = lo;
  return *this;
}

CliOptions::Option& CliOptions::Option::above(double lo) {
  above_ = lo;
  return *this;
}

CliOptions::Option& CliOptions::Option::max(double hi) {
  max_ = hi;
  return *this;
}

CliOptions::Option& CliOptions::Option::choices(std::vector<std::string> values) {
  choices_ = std::move(values);
  if (placeholders_.size() == 1 && placeholders_[0].empty()) placeholders_[0] = join(choices_, "|");
  return *this;
}

void CliOptions::Option::check_number(double v, const std::string& text) const {
  // Written as !(v >= lo) so that NaN fails every bound.
  if (min_ && !(v >= *min_)) {
    throw UsageError(name_ + " must be >= " + number_text(*min_) + " (got " + text + ")");
  }
  if (above_ && !(v > *above_)) {
    throw UsageError(name_ + " must be > " + number_text(*above_) + " (got " + text + ")");
  }
  if (max_ && !(v <= *max_)) {
    throw UsageError(name_ + " must be <= " + number_text(*max_) + " (got " + text + ")");
  }
}

void CliOptions::Option::check_choice(const std::string& text) const {
  if (!choices_.empty() && std::find(choices_.begin(), choices_.end(), text) == choices_.end()) {
    throw UsageError(name_ + " must be " + join(choices_, " or ") + " (got \"" + text + "\")");
  }
}

// --------------------------------------------------------------- CliOptions

CliOptions::CliOptions(std::string program, std::string description)
    : program_(std::move(program)), description_(std::move(description)) {}

void CliOptions::section(std::string title) { section_ = std::move(title); }

CliOptions::Option& CliOptions::add(const std::string& name, std::vector<std::string> placeholders,
                                    std::string help) {
  if (name == "-h" || name == "--help" || find(name) != nullptr) {
    throw std::logic_error(program_ + ": option " + name + " defined twice");
  }
  options_.push_back(std::make_unique<Option>());
  Option& o = *options_.back();
  o.name_ = name;
  o.placeholders_ = std::move(placeholders);
  o.help_ = std::move(help);
  o.section_ = section_;
  return o;
}

CliOptions::Option& CliOptions::flag(const std::string& name, bool* target, std::string help,
                                     bool value) {
  Option& o = add(name, {}, std::move(help));
  o.apply_ = [target, value](const Option&, const std::vector<std::string>&) { *target = value; };
  return o;
}

CliOptions::Option& CliOptions::custom(const std::string& name,
                                       std::vector<std::string> placeholders,
                                       std::function<void(const std::vector<std::string>&)> handler,
                                       std::string help) {
  Option& o = add(name, std::move(placeholders), std::move(help));
  o.apply_ = [handler = std::move(handler)](const Option&, const std::vector<std::string>& v) {
    handler(v);
  };
  return o;
}

CliOptions::Option& CliOptions::positional(std::string placeholder, std::string* target,
                                           std::string help) {
  Option& o = add(placeholder, {}, std::move(help));
  o.positional_ = true;
  o.apply_ = [target](const Option&, const std::vector<std::string>& v) { *target = v[0]; };
  return o;
}

CliOptions::Option& CliOptions::positional(std::string placeholder,
                                           std::vector<std::string>* target, std::string help) {
  Option& o = add(placeholder, {}, std::move(help));
  o.positional_ = true;
  o.repeated_ = true;
  o.apply_ = [target](const Option&, const std::vector<std::string>& v) {
    target->push_back(v[0]);
  };
  return o;
}

const CliOptions::Option* CliOptions::find(const std::string& name) const {
  for (const auto& o : options_) {
    if (o->name_ == name) return o.get();
  }
  return nullptr;
}

bool CliOptions::given(const std::string& name) const {
  const Option* o = find(name);
  if (o == nullptr) throw std::logic_error(program_ + ": no option " + name);
  return o->given_;
}

bool CliOptions::parse(int argc, const char* const* argv) {
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "-h" || a == "--help") return false;
    Option* o = nullptr;
    for (const auto& c : options_) {
      if (!c->positional_ && c->name_ == a) o = c.get();
    }
    std::vector<std::string> values;
    if (o != nullptr) {
      const std::size_t n = o->placeholders_.size();
      if (static_cast<std::size_t>(argc - 1 - i) < n) {
        throw UsageError(
            a + (n == 1 ? " needs a value (" : " needs " + std::to_string(n) + " values (") +
            join(o->placeholders_, " ") + ")");
      }
      for (std::size_t k = 0; k < n; ++k) values.push_back(argv[++i]);
    } else if (!a.empty() && a[0] == '-') {
      throw UsageError("unknown option " + a);
    } else {
      for (const auto& c : options_) {
        if (c->positional_ && (c->repeated_ || !c->given_)) {
          o = c.get();
          break;
        }
      }
      if (o == nullptr) throw UsageError("unexpected argument " + a);
      values.push_back(a);
    }
    try {
      o->apply_(*o, values);
    } catch (const UsageError&) {
      throw;
    } catch (const std::invalid_argument& e) {  // a handler's own conversion
      throw UsageError(o->name_ + ": " + e.what());
    } catch (const std::out_of_range& e) {
      throw UsageError(o->name_ + ": " + e.what());
    }
    o->given_ = true;
  }
  for (const auto& o : options_) {
    if (o->required_ && !o->given_ && !o->positional_) {
      throw UsageError(left_column(*o) + " is required");
    }
  }
  for (const auto& o : options_) {
    if (o->required_ && !o->given_ && o->positional_) throw UsageError("no " + o->name_ + " given");
  }
  return true;
}

std::optional<int> CliOptions::parse_or_exit(int argc, const char* const* argv) {
  try {
    if (parse(argc, argv)) return std::nullopt;
  } catch (const UsageError& e) {
    return usage_error(e.what());
  }
  std::cout << help();
  return 0;
}

int CliOptions::usage_error(const std::string& message) const {
  std::cerr << program_ << ": " << message << "\n" << help();
  return 2;
}

std::string CliOptions::left_column(const Option& o) const {
  std::string s = o.name_;
  for (const std::string& p : o.placeholders_) s += " " + p;
  return s;
}

std::string CliOptions::help() const {
  std::string usage = "usage: " + program_;
  bool optional_flags = false;
  for (const auto& o : options_) {
    if (!o->positional_ && o->required_) usage += " " + left_column(*o);
    optional_flags = optional_flags || (!o->positional_ && !o->required_);
  }
  if (optional_flags) usage += " [options]";
  for (const auto& o : options_) {
    if (!o->positional_) continue;
    const std::string p = o->name_ + (o->repeated_ ? "..." : "");
    usage += " " + (o->required_ ? p : "[" + p + "]");
  }
  std::string out = usage + "\n";
  if (!description_.empty()) {
    for (const std::string& line : wrap(description_, kWidth)) out += line + "\n";
  }

  const std::string help_flag = "-h, --help";
  std::size_t column = help_flag.size();
  for (const auto& o : options_) column = std::max(column, left_column(*o).size());
  column = 2 + std::min(column, kMaxColumn) + 2;
  auto row = [&](const std::string& left, const std::string& text) {
    std::string r = "  " + left;
    const std::vector<std::string> lines = wrap(text, kWidth - column);
    for (std::size_t k = 0; k < lines.size(); ++k) {
      if (k == 0 && r.size() < column) {
        r += std::string(column - r.size(), ' ') + lines[k];
      } else {
        r += "\n" + std::string(column, ' ') + lines[k];
      }
    }
    out += r + "\n";
  };
  std::string section;
  for (const auto& o : options_) {
    if (o->section_ != section) {
      section = o->section_;
      out += section + ":\n";
    }
    std::string text = o->help_;
    if (!o->shown_default_.empty()) text += " (default " + o->shown_default_ + ")";
    row(left_column(*o), text);
  }
  if (!section.empty()) out += "\n";
  row(help_flag, "print this help and exit");
  return out;
}

}  // namespace long3r

#include "client/cli.h"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <iomanip>
#include <ostream>

namespace loomlight::client {
namespace {

const OptionSpec* find_spec(const OptionList& specs, std::string_view name) {
  const auto it = std::find_if(specs.begin(), specs.end(), [&](const OptionSpec& s) { return s.name == name; });
  return it == specs.end() ? nullptr : &*it;
}

std::string_view trim(std::string_view text) {
  const auto first = text.find_first_not_of(" \t\r");
  if (first == std::string_view::npos) return {};
  const auto last = text.find_last_not_of(" \t\r");
  return text.substr(first, last - first + 1);
}

std::string option_label(const OptionSpec& spec) {
  std::string label = "--" + std::string(spec.name);
  if (!spec.value.empty()) label += " " + std::string(spec.value);
  return label;
}

}  // namespace

bool ParsedOptions::has(std::string_view name) const {
  return std::any_of(entries.begin(), entries.end(), [&](const Entry& e) { return e.name == name; });
}

std::optional<std::string> ParsedOptions::last(std::string_view name) const {
  const auto it = std::find_if(entries.rbegin(), entries.rend(), [&](const Entry& e) { return e.name == name; });
  if (it == entries.rend()) return std::nullopt;
  return it->value;
}

std::vector<ParsedOptions::Entry> ParsedOptions::matching(std::initializer_list<std::string_view> names) const {
  std::vector<Entry> out;
  for (const Entry& e : entries)
    if (std::find(names.begin(), names.end(), e.name) != names.end()) out.push_back(e);
  return out;
}

ParsedOptions parse_options(std::span<const std::string> args, const OptionList& specs, bool stop_at_positional) {
  ParsedOptions parsed;
  for (std::size_t i = 0; i < args.size(); ++i) {
    const std::string& arg = args[i];
    // "-" alone is a value (stdin), not an option; "--" ends the options.
    if (arg == "--") {
      parsed.positional.insert(parsed.positional.end(), args.begin() + i + 1, args.end());
      break;
    }
    if (arg.size() < 2 || arg[0] != '-') {
      if (stop_at_positional) {
        parsed.positional.assign(args.begin() + i, args.end());
        break;
      }
      parsed.positional.push_back(arg);
      continue;
    }
    if (arg == "-h") {
      parsed.entries.push_back({"help", ""});
      continue;
    }
    if (arg.rfind("--", 0) != 0) throw UsageError("unknown option '" + arg + "'");
    const auto eq = arg.find('=');
    const std::string name = arg.substr(2, eq == std::string::npos ? std::string::npos : eq - 2);
    const OptionSpec* spec = find_spec(specs, name);
    if (spec == nullptr) throw UsageError("unknown option '--" + name + "'");
    if (spec->value.empty()) {
      if (eq != std::string::npos) throw UsageError("option '--" + name + "' takes no value");
      parsed.entries.push_back({name, ""});
    } else if (eq != std::string::npos) {
      parsed.entries.push_back({name, arg.substr(eq + 1)});
    } else {
      if (i + 1 >= args.size()) throw UsageError("option '--" + name + "' needs a value " + std::string(spec->value));
      parsed.entries.push_back({name, args[++i]});
    }
  }
  return parsed;
}

double parse_number(std::string_view text, std::string_view what) {
  const std::string_view t = trim(text);
  // from_chars rejects a leading '+', which people do write.
  const std::string_view digits = !t.empty() && t[0] == '+' ? t.substr(1) : t;
  double value = 0.0;
  const auto [end, ec] = std::from_chars(digits.data(), digits.data() + digits.size(), value);
  if (digits.empty() || ec != std::errc() || end != digits.data() + digits.size())
    throw UsageError("bad number '" + std::string(text) + "' in " + std::string(what));
  return value;
}

int parse_int(std::string_view text, std::string_view what, int lo, int hi) {
  const double v = parse_number(text, what);
  if (v != std::floor(v) || v < lo || v > hi)
    throw UsageError(std::string(what) + " must be an integer in [" + std::to_string(lo) + ", " + std::to_string(hi) +
                     "], got '" + std::string(text) + "'");
  return static_cast<int>(v);
}

std::vector<double> parse_numbers(std::string_view text, std::string_view what, std::size_t count) {
  std::vector<double> values;
  for (std::size_t start = 0;;) {
    const std::size_t comma = text.find(',', start);
    values.push_back(parse_number(text.substr(start, comma - start), what));
    if (comma == std::string_view::npos) break;
    start = comma + 1;
  }
  if (count > 0 && values.size() != count)
    throw UsageError(std::string(what) + " needs " + std::to_string(count) + " comma-separated values, got '" +
                     std::string(text) + "'");
  return values;
}

void print_option_help(std::ostream& out, const OptionList& specs) {
  std::size_t width = 0;
  for (const OptionSpec& s : specs) width = std::max(width, option_label(s).size());
  for (const OptionSpec& s : specs)
    out << "  " << std::left << std::setw(static_cast<int>(width) + 2) << option_label(s) << s.help << '\n';
}

}  // namespace loomlight::client

#include "client/cli.h"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <map>

#include "client/cli11_rules.h"

namespace loomlight::client {
namespace {

std::string_view trim(std::string_view text) {
  const auto first = text.find_first_not_of(" \t\r");
  if (first == std::string_view::npos) return {};
  const auto last = text.find_last_not_of(" \t\r");
  return text.substr(first, last - first + 1);
}

// The `index`th time `option` was given; a flag's value is empty.
ParsedOptions::Entry entry(const CLI::Option& option, std::size_t index) {
  return {option.get_lnames().front(), option.get_expected_max() == 0 ? "" : option.results().at(index)};
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

void add_options(CLI::App& app, const OptionList& specs, const std::string& group) {
  for (const OptionSpec& spec : specs) {
    const std::string name = "--" + std::string(spec.name);
    CLI::Option* option =
        spec.value.empty()
            ? app.add_flag(name)->check(cli::NoValue())
            : app.add_option(name, CLI::callback_t(), "")
                  ->type_name(std::string(spec.value))
                  ->multi_option_policy(CLI::MultiOptionPolicy::TakeAll);  // every value, for ParsedOptions
    option->description(std::string(spec.help))->group(group);
    if (!spec.environment.empty()) option->envname(std::string(spec.environment));
  }
}

ParsedOptions collect_options(const std::vector<const CLI::App*>& apps) {
  ParsedOptions parsed;
  std::vector<ParsedOptions::Entry> from_environment;
  for (const CLI::App* app : apps) {
    std::map<const CLI::Option*, std::size_t> given;  // the times each option appears in the command line
    for (const CLI::Option* option : app->parse_order()) {
      parsed.entries.push_back(entry(*option, given[option]));
      ++given[option];
    }
    // CLI11 adds an environment variable's value as a result that has no place in the command line.
    for (const CLI::Option* option : app->get_options())
      if (option->nonpositional() && given[option] == 0 && !option->results().empty())
        from_environment.push_back(entry(*option, 0));
    const std::vector<std::string> extras = app->remaining();
    if (const auto unknown = cli::UnknownOption(extras)) throw UsageError(*unknown);
    parsed.positional.insert(parsed.positional.end(), extras.begin(), extras.end());
  }
  parsed.entries.insert(parsed.entries.begin(), from_environment.begin(), from_environment.end());
  return parsed;
}

ParsedOptions parse_options(const OptionList& specs, std::vector<std::string> args) {
  CLI::App app;
  cli::Configure(app, 30);
  add_options(app, specs, "options");
  std::reverse(args.begin(), args.end());  // CLI11 takes the arguments last first
  try {
    app.parse(args);
  } catch (const CLI::ParseError& e) {
    throw UsageError(e.what());
  }
  return collect_options({&app});
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

}  // namespace loomlight::client

// The rules both command lines (`loomlight` and `loomlight-server`) parse by, on top of CLI11: an unknown option
// or a bad value is refused before --help is looked at (a manifest's arguments run with --help added are checked
// that way), a flag refuses a value, and the refusals name the option in the words the tests look for.
#pragma once

#include <CLI/CLI.hpp>

#include <algorithm>
#include <optional>
#include <string>
#include <vector>

namespace loomlight::cli {

// CLI11 would take "--flag=yes" or "--flag=0" as the flag's value; a bare flag's result is "true".
inline CLI::Validator NoValue() {
  return CLI::Validator(
      [](std::string& value) { return value == "true" ? std::string() : std::string("takes no value"); }, "");
}

// Sets `app` up by the rules: extras are kept (reported by UnknownOption, after every value was checked), --help is
// an ordinary flag that the caller acts on after parsing, and the help reads "usage: ...".
inline void Configure(CLI::App& app, std::size_t help_column_width) {
  app.set_help_flag();
  app.allow_extras();
  app.get_formatter()->label("Usage", "usage");
  app.get_formatter()->column_width(help_column_width);
  app.option_defaults()->multi_option_policy(CLI::MultiOptionPolicy::TakeLast);
}

inline CLI::Option* AddHelpFlag(CLI::App& app, const std::string& group) {
  return app.add_flag("-h,--help")->description("show this help")->check(NoValue())->group(group);
}

// An argument left over that looks like an option ("-" alone is a value: stdin), without any "=VALUE".
inline bool IsOptionLike(const std::string& arg) { return arg.size() >= 2 && arg[0] == '-'; }

// "unknown option '--name'" for the first option-like argument CLI11 left over, if any.
inline std::optional<std::string> UnknownOption(const std::vector<std::string>& extras) {
  for (const std::string& arg : extras)
    if (IsOptionLike(arg)) return "unknown option '" + arg.substr(0, std::min<std::size_t>(arg.find('='), 80)) + "'";
  return std::nullopt;
}

}  // namespace loomlight::cli

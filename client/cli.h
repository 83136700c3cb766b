// Command-line plumbing of the `loomlight` client: option tables, parsing, number lists, help text.
#pragma once

#include <cstddef>
#include <initializer_list>
#include <iosfwd>
#include <optional>
#include <span>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

namespace loomlight::client {

// A bad command line or bad input data: reported with a hint to the usage, exit status 2.
struct UsageError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// One "--name [VALUE]" option. An empty `value` placeholder makes it a flag.
struct OptionSpec {
  std::string_view name;   // without the leading "--"
  std::string_view value;  // placeholder shown in the help, e.g. "HOST:PORT"
  std::string_view help;
};
using OptionList = std::vector<OptionSpec>;

// The options given, in command-line order (order matters: --wi and --wo pair up in order).
struct ParsedOptions {
  struct Entry {
    std::string name;
    std::string value;  // empty for flags
  };
  std::vector<Entry> entries;
  std::vector<std::string> positional;

  bool has(std::string_view name) const;
  std::optional<std::string> last(std::string_view name) const;  // a later option overrides an earlier one
  std::vector<Entry> matching(std::initializer_list<std::string_view> names) const;
};

// Parses "--name VALUE", "--name=VALUE" and flags against `specs`; an option not in `specs` is a UsageError.
// With `stop_at_positional`, parsing stops at the first positional argument, which is returned in
// `positional` together with everything after it unparsed (used for global options before the command).
ParsedOptions parse_options(std::span<const std::string> args, const OptionList& specs, bool stop_at_positional);

// Numbers are parsed locale-independently; `what` names the option or field in error messages.
double parse_number(std::string_view text, std::string_view what);
// An integer in [lo, hi].
int parse_int(std::string_view text, std::string_view what, int lo, int hi);
// A comma-separated list "v1,v2,..."; with `count` > 0 exactly that many values are required.
std::vector<double> parse_numbers(std::string_view text, std::string_view what, std::size_t count = 0);

// Writes one aligned "  --name VALUE   help" line per option.
void print_option_help(std::ostream& out, const OptionList& specs);

}  // namespace loomlight::client

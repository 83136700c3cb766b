// Command-line plumbing of the `loomlight` client: option tables declared to CLI11, what it parsed, number lists.
#pragma once

#include <cstddef>
#include <initializer_list>
#include <optional>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

namespace CLI {
class App;
}

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
  std::string_view environment = {};  // a variable whose value stands in when the option is not given
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

// Declares `specs` on `app` under the help heading `group`: each "--name VALUE" option keeps every value given, in
// order; an option without a value placeholder is a flag, which refuses a value.
void add_options(CLI::App& app, const OptionList& specs, const std::string& group);

// The options `apps` were given (the program's, then its command's, then a family member's), CLI11 having parsed
// them: values taken from the environment first, then each app's in command-line order, so that a later one
// overrides an earlier one; the arguments CLI11 left over are the positional arguments, an option among them a
// UsageError.
ParsedOptions collect_options(const std::vector<const CLI::App*>& apps);

// Parses `args` against `specs` alone (the options column of a batch's CSV).
ParsedOptions parse_options(const OptionList& specs, std::vector<std::string> args);

// Numbers are parsed locale-independently; `what` names the option or field in error messages.
double parse_number(std::string_view text, std::string_view what);
// An integer in [lo, hi].
int parse_int(std::string_view text, std::string_view what, int lo, int hi);
// A comma-separated list "v1,v2,..."; with `count` > 0 exactly that many values are required.
std::vector<double> parse_numbers(std::string_view text, std::string_view what, std::size_t count = 0);
// One CSV record with RFC 4180 quoting ("a ""b"", c" is one field holding `a "b", c`); a record is one line.
// `where` ("FILE:LINE") prefixes the UsageError of an unterminated quote.
std::vector<std::string> split_csv_record(std::string_view line, const std::string& where);

}  // namespace loomlight::client

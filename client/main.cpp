// `loomlight`: command-line client of the Loomlight service.
// Exit status: 0 success, 1 failure (server error, I/O), 2 usage error (bad options or malformed input).
#include <algorithm>
#include <array>
#include <exception>
#include <iomanip>
#include <iostream>
#include <span>
#include <string>
#include <vector>

#include "client/cli.h"
#include "client/commands.h"
#include "client/rpc.h"

namespace loomlight::client {
namespace {

constexpr int kExitFailure = 1;
constexpr int kExitUsage = 2;

const OptionSpec kHelpOption = {"help", "", "show this help"};

std::array<const Command*, 12> commands() {
  return {&models_command(), &scenes_command(), &eval_command(), &sample_command(), &plot_command(), &slice_command(),
          &tab_command(), &render_command(), &batch_command(), &yarn_command(), &btf_command(), &health_command()};
}

// A family member's word: "create" of "btf create".
std::string_view member_word(const Command& family, const Command& member) {
  return member.name.substr(family.name.size() + 1);
}

// The command the words begin with, descending into a family while the next word names a member; `words`
// loses the words used. `current` follows the descent, so that a usage error shows the nearest synopsis.
const Command* resolve_command(std::span<const std::string>& words, const Command*& current) {
  const auto all = commands();
  const auto found = std::find_if(all.begin(), all.end(), [&](const Command* c) { return c->name == words[0]; });
  if (found == all.end()) throw UsageError("unknown command '" + words[0] + "'");
  current = *found;
  words = words.subspan(1);
  while (!current->members.empty() && !words.empty() && !words[0].starts_with('-')) {
    const auto member = std::find_if(current->members.begin(), current->members.end(),
                                     [&](const Command* c) { return member_word(*current, *c) == words[0]; });
    if (member == current->members.end())
      throw UsageError("unknown command '" + std::string(current->name) + " " + words[0] + "'");
    current = *member;
    words = words.subspan(1);
  }
  return current;
}

// The options accepted before any command: the connection and --help.
OptionList global_options() {
  OptionList options = connection_options();
  options.push_back(kHelpOption);
  return options;
}

// A command accepts its own options plus the global ones, so `loomlight eval --server X ...` works too.
OptionList accepted_options(const Command& command) {
  OptionList options = command.options;
  const OptionList globals = global_options();
  options.insert(options.end(), globals.begin(), globals.end());
  return options;
}

void print_usage(std::ostream& out) {
  out << "usage: loomlight [--server HOST:PORT] [--timeout SECONDS] COMMAND [options]\n\ncommands:\n";
  for (const Command* c : commands()) out << "  " << std::left << std::setw(8) << c->name << c->summary << '\n';
  out << "  help    show the help of a command: loomlight help COMMAND\n\noptions:\n";
  print_option_help(out, global_options());
  out << "\nRun 'loomlight COMMAND --help' for the options of a command.\n";
}

void print_synopsis(std::ostream& out, const Command& command) {
  out << "usage: loomlight " << command.name << ' ' << command.synopsis << '\n';
}

void print_command_help(std::ostream& out, const Command& command) {
  print_synopsis(out, command);
  out << '\n' << command.summary << ".\n";
  if (!command.description.empty()) out << '\n' << command.description << '\n';
  if (!command.members.empty()) {
    out << "\ncommands:\n";
    for (const Command* m : command.members)
      out << "  " << std::left << std::setw(8) << member_word(command, *m) << m->summary << '\n';
    out << "\nRun 'loomlight " << command.name << " COMMAND --help' for the arguments and options of each.\n";
    return;
  }
  out << "\noptions:\n";
  print_option_help(out, command.options);
  out << "\ncommon options:\n";
  print_option_help(out, global_options());
}

// `loomlight help [COMMAND [MEMBER]]`.
int run_help(std::span<const std::string> args, const Command*& current) {
  if (args.empty()) {
    print_usage(std::cout);
    return 0;
  }
  print_command_help(std::cout, *resolve_command(args, current));
  return 0;
}

// Parses the command's options (global options given before the command come first, so later ones win) and runs it.
int run_command(const Command& command, const ParsedOptions& globals, std::span<const std::string> args) {
  ParsedOptions options = parse_options(args, accepted_options(command), false);
  options.entries.insert(options.entries.begin(), globals.entries.begin(), globals.entries.end());
  if (options.has("help")) {
    print_command_help(std::cout, command);
    return 0;
  }
  if (!command.members.empty()) throw UsageError("'" + std::string(command.name) + "' needs a command");
  if (options.positional.size() > command.max_arguments)
    throw UsageError("unexpected argument '" + options.positional[command.max_arguments] + "'");
  if (options.positional.size() < command.min_arguments) throw UsageError("missing arguments");
  return command.run(options);
}

int run(const std::vector<std::string>& args, const Command*& current) {
  const ParsedOptions globals = parse_options(args, global_options(), true);
  if (globals.positional.empty()) {
    if (!globals.has("help")) throw UsageError("no command given");
    print_usage(std::cout);
    return 0;
  }
  std::span<const std::string> rest(globals.positional);
  if (rest[0] == "help") return run_help(rest.subspan(1), current);
  const Command& command = *resolve_command(rest, current);
  return run_command(command, globals, rest);
}

}  // namespace
}  // namespace loomlight::client

int main(int argc, char** argv) {
  using namespace loomlight::client;
  const std::vector<std::string> args(argv + 1, argv + argc);
  const Command* command = nullptr;  // set once the command is known, for its usage on errors
  try {
    return run(args, command);
  } catch (const UsageError& e) {
    std::cerr << "error: " << e.what() << "\n\n";
    if (command != nullptr) {
      print_synopsis(std::cerr, *command);
      std::cerr << "Run 'loomlight " << command->name << " --help' for the options.\n";
    } else {
      print_usage(std::cerr);
    }
    return kExitUsage;
  } catch (const std::exception& e) {
    // RpcError's message is "<STATUS_CODE_NAME>: <message>".
    std::cerr << "error: " << e.what() << '\n';
    return kExitFailure;
  }
}

// `loomlight`: command-line client of the Loomlight service.
// Exit status: 0 success, 1 failure (server error, I/O), 2 usage error (bad options or malformed input).
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

std::array<const Command*, 10> commands() {
  return {&models_command(), &eval_command(), &sample_command(), &plot_command(), &slice_command(), &tab_command(),
          &render_command(), &batch_command(), &yarn_command(), &health_command()};
}

const Command* find_command(std::string_view name) {
  for (const Command* c : commands())
    if (c->name == name) return c;
  return nullptr;
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
  out << "\noptions:\n";
  print_option_help(out, command.options);
  out << "\ncommon options:\n";
  print_option_help(out, global_options());
}

// `loomlight help [COMMAND]`.
int run_help(std::span<const std::string> args) {
  if (args.empty()) {
    print_usage(std::cout);
    return 0;
  }
  const Command* command = find_command(args[0]);
  if (command == nullptr) throw UsageError("unknown command '" + args[0] + "'");
  print_command_help(std::cout, *command);
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
  if (!options.positional.empty()) throw UsageError("unexpected argument '" + options.positional[0] + "'");
  return command.run(options);
}

int run(const std::vector<std::string>& args, const Command*& current) {
  const ParsedOptions globals = parse_options(args, global_options(), true);
  if (globals.positional.empty()) {
    if (!globals.has("help")) throw UsageError("no command given");
    print_usage(std::cout);
    return 0;
  }
  const std::string& name = globals.positional[0];
  const std::span<const std::string> rest(globals.positional.begin() + 1, globals.positional.end());
  if (name == "help") return run_help(rest);
  current = find_command(name);
  if (current == nullptr) throw UsageError("unknown command '" + name + "'");
  return run_command(*current, globals, rest);
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

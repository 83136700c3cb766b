// `loomlight`: command-line client of the Loomlight service.
// Exit status: 0 success, 1 failure (server error, I/O), 2 usage error (bad options or malformed input).
#include <algorithm>
#include <array>
#include <exception>
#include <iostream>
#include <map>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>

#include "client/cli.h"
#include "client/cli11_rules.h"
#include "client/commands.h"
#include "client/rpc.h"

namespace loomlight::client {
namespace {

constexpr int kExitFailure = 1;
constexpr int kExitUsage = 2;
constexpr std::size_t kHelpColumnWidth = 30;
constexpr std::size_t kCommandColumnWidth = 10;  // "  health  ..."

std::array<const Command*, 14> commands() {
  return {&models_command(), &scenes_command(), &eval_command(), &sample_command(), &plot_command(), &slice_command(),
          &tab_command(), &render_command(), &batch_command(), &yarn_command(), &btf_command(), &mesh_command(),
          &fit_command(), &health_command()};
}

// A family member's word: "create" of "btf create".
std::string_view member_word(const Command& family, const Command& member) {
  return member.name.substr(family.name.size() + 1);
}

// CLI11's help laid out as the client's always was: the usage line from the command's synopsis first.
class HelpFormatter : public CLI::Formatter {
 public:
  explicit HelpFormatter(const std::map<const CLI::App*, const Command*>* commands) : commands_(commands) {}

  std::string make_usage(const CLI::App* app, std::string name) const override {
    const auto found = commands_->find(app);
    const std::string synopsis = found == commands_->end()
                                     ? "[--server HOST:PORT] [--timeout SECONDS] COMMAND [options]"
                                     : std::string(found->second->synopsis);
    return get_label("Usage") + ": " + name + (synopsis.empty() ? "" : " " + synopsis) + "\n";
  }

  // A command list shows each command's summary, not its whole description.
  std::string make_subcommand(const CLI::App* sub) const override {
    const auto found = commands_->find(sub);
    std::ostringstream out;
    CLI::detail::format_help(out, sub->get_name(),
                             found == commands_->end() ? sub->get_description() : std::string(found->second->summary),
                             kCommandColumnWidth);
    return out.str();
  }

  std::string make_help(const CLI::App* app, std::string name, CLI::AppFormatMode mode) const override {
    std::ostringstream out;
    out << make_usage(app, name);
    if (!app->get_description().empty()) out << '\n' << make_description(app);
    out << make_subcommands(app, mode) << make_groups(app, mode) << '\n' << make_footer(app);
    return out.str();
  }

 private:
  const std::map<const CLI::App*, const Command*>* commands_;
};

// The command line: the program's connection options and --help, a subcommand per command (a family's members
// its subcommands), each with its own options, the connection options again (so that `loomlight eval --server X`
// works too) and --help, and `help [COMMAND [MEMBER]]`.
class CommandLine {
 public:
  CommandLine() {
    app_.formatter(formatter_);
    cli::Configure(app_, kHelpColumnWidth);
    app_.require_subcommand(0, 1);  // a word after the command is its argument, not another command
    add_options(app_, connection_options(), "options");
    cli::AddHelpFlag(app_, "options");
    for (const Command* command : commands()) add_command(app_, *command, command->name);
    help_ = app_.add_subcommand("help", "show the help of a command: loomlight help COMMAND")->group("commands");
    help_->set_help_flag();
    help_->allow_extras();
    app_.footer("Run 'loomlight COMMAND --help' for the options of a command.");
  }

  // What a usage error shows after its message: the usage line of the command named (the member, in a family;
  // CLI11 records it as soon as it sees it, also when parsing fails later) and where its options are, else the
  // program's help.
  std::string usage_hint() const {
    const CLI::App& app = *chosen_apps().back();
    if (!commands_.contains(&app)) return help_text(app_);
    const std::string name = full_name(app);
    return formatter_->make_usage(&app, name) + "Run '" + name + " --help' for the options.\n";
  }

  int run(int argc, char** argv) {
    try {
      app_.parse(argc, argv);
    } catch (const CLI::ParseError& e) {
      throw UsageError(e.what());
    }
    if (help_->parsed()) return run_help();
    const std::vector<std::string> extras = app_.remaining();
    if (const auto unknown = cli::UnknownOption(extras)) throw UsageError(*unknown);
    if (!extras.empty()) throw UsageError("unknown command '" + extras.front() + "'");
    const std::vector<const CLI::App*> apps = chosen_apps();
    const auto found = commands_.find(apps.back());
    if (found == commands_.end()) {
      if (app_.get_option("--help")->count() == 0) throw UsageError("no command given");
      std::cout << help_text(app_);
      return 0;
    }
    const Command* chosen = found->second;
    const ParsedOptions options = collect_options(apps);
    if (options.has("help")) {
      std::cout << help_text(*apps.back());
      return 0;
    }
    if (!chosen->members.empty()) {
      if (!options.positional.empty())
        throw UsageError("unknown command '" + std::string(chosen->name) + " " + options.positional[0] + "'");
      throw UsageError("'" + std::string(chosen->name) + "' needs a command");
    }
    if (options.positional.size() > chosen->max_arguments)
      throw UsageError("unexpected argument '" + options.positional[chosen->max_arguments] + "'");
    if (options.positional.size() < chosen->min_arguments) throw UsageError("missing arguments");
    return chosen->run(options);
  }

 private:
  void add_command(CLI::App& parent, const Command& command, std::string_view word) {
    std::string description = std::string(command.summary) + ".";
    if (!command.description.empty()) description += "\n\n" + std::string(command.description);
    CLI::App* app = parent.add_subcommand(std::string(word), "")->group("commands");
    app->description(description);
    commands_[app] = &command;
    app->set_help_flag();
    app->allow_extras();
    if (!command.members.empty()) {
      app->require_subcommand(0, 1);
      app->footer("Run 'loomlight " + std::string(command.name) +
                  " COMMAND --help' for the arguments and options of each.");
      for (const Command* member : command.members) add_command(*app, *member, member_word(command, *member));
    }
    add_options(*app, command.options, "options");
    add_options(*app, connection_options(), "common options");
    cli::AddHelpFlag(*app, "common options");
  }

  // The program and the commands CLI11 has seen: [program], [program, command] or [program, family, member].
  std::vector<const CLI::App*> chosen_apps() const {
    std::vector<const CLI::App*> apps = {&app_};
    while (!apps.back()->get_subcommands().empty()) apps.push_back(apps.back()->get_subcommands()[0]);
    return apps;
  }

  // "loomlight btf create".
  std::string full_name(const CLI::App& app) const {
    std::string name;
    for (const CLI::App* at = &app; at != &app_; at = at->get_parent()) name = " " + at->get_name() + name;
    return "loomlight" + name;
  }

  // The help of the program or a command (App::help would show the help of a subcommand parsed, `help` included).
  std::string help_text(const CLI::App& app) const {
    return formatter_->make_help(&app, full_name(app), CLI::AppFormatMode::Normal);
  }

  // `loomlight help [COMMAND [MEMBER]]`.
  int run_help() {
    const CLI::App* at = &app_;
    std::string named;
    for (const std::string& word : help_->remaining()) {
      named += (named.empty() ? "" : " ") + word;
      const auto subcommands = at->get_subcommands([&](const CLI::App* app) { return app != help_; });
      const auto next = std::find_if(subcommands.begin(), subcommands.end(),
                                     [&](const CLI::App* app) { return app->get_name() == word; });
      if (next == subcommands.end()) throw UsageError("unknown command '" + named + "'");
      at = *next;
    }
    std::cout << help_text(*at);
    return 0;
  }

  std::map<const CLI::App*, const Command*> commands_;
  std::shared_ptr<HelpFormatter> formatter_ = std::make_shared<HelpFormatter>(&commands_);
  CLI::App app_{"", "loomlight"};
  CLI::App* help_ = nullptr;
};

}  // namespace
}  // namespace loomlight::client

int main(int argc, char** argv) {
  using namespace loomlight::client;
  CommandLine command_line;
  try {
    return command_line.run(argc, argv);
  } catch (const UsageError& e) {
    std::cerr << "error: " << e.what() << "\n\n" << command_line.usage_hint();
    return kExitUsage;
  } catch (const std::exception& e) {
    // RpcError's message is "<STATUS_CODE_NAME>: <message>".
    std::cerr << "error: " << e.what() << '\n';
    return kExitFailure;
  }
}

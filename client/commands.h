// The subcommands of `loomlight`. main.cpp dispatches to them and turns their exceptions into exit codes:
// UsageError -> 2, RpcError and other failures -> 1.
#pragma once

#include <string_view>

#include "client/cli.h"

namespace loomlight::client {

struct Command {
  std::string_view name;
  std::string_view synopsis;     // the arguments after the command name
  std::string_view summary;      // one line for the command list
  std::string_view description;  // further help text, may be empty
  OptionList options;            // the command's own options (main adds --help and the connection options)
  int (*run)(const ParsedOptions& options);
};

const Command& models_command();
const Command& eval_command();
const Command& plot_command();
const Command& slice_command();
const Command& tab_command();
const Command& render_command();
const Command& yarn_command();
const Command& health_command();
const Command& sample_command();
const Command& batch_command();

}  // namespace loomlight::client

// The subcommands of `loomlight`. main.cpp dispatches to them and turns their exceptions into exit codes:
// UsageError -> 2, RpcError and other failures -> 1.
#pragma once

#include <cstddef>
#include <string_view>
#include <vector>

#include "client/cli.h"

namespace loomlight::client {

struct Command {
  std::string_view name;
  std::string_view synopsis;     // the arguments after the command name
  std::string_view summary;      // one line for the command list
  std::string_view description;  // further help text, may be empty
  // The command's own options; main declares them to CLI11, with --help and the connection options.
  OptionList options;
  int (*run)(const ParsedOptions& options);
  // Arguments after the command's name and before or among its options (e.g. an asset's NAME), handed to
  // `run` as ParsedOptions::positional; main rejects fewer or more.
  std::size_t min_arguments = 0, max_arguments = 0;
  // A family of commands (`loomlight btf create ...`): the word after the family's name picks a member, whose
  // own name is "FAMILY WORD"; the family's `run` is not called.
  std::vector<const Command*> members = {};
};

const Command& models_command();
const Command& scenes_command();
const Command& eval_command();
const Command& plot_command();
const Command& slice_command();
const Command& tab_command();
const Command& render_command();
const Command& yarn_command();
const Command& health_command();
const Command& sample_command();
const Command& batch_command();
const Command& btf_command();
const Command& mesh_command();
const Command& fit_command();

}  // namespace loomlight::client

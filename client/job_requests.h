// The requests of the `render` and `tab` commands built from their parsed options. Shared with `batch`, which
// runs the same jobs from the rows of a CSV file, so a batch row means exactly what the command line would.
#pragma once

#include <string>

#include "client/cli.h"
#include "loomlight/v1/loomlight.pb.h"

namespace loomlight::client {

// `out` is the output path: its extension picks the format unless --format is given.
loomlight::v1::RenderRequest render_request(const ParsedOptions& options, const std::string& out);
loomlight::v1::TabulateRequest tabulate_request(const ParsedOptions& options, const std::string& out);

}  // namespace loomlight::client

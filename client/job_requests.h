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

// --mesh FILE or --mesh-name NAME into *mesh (untouched without them) and each --material MESH_MATERIAL=PRESET
// into *bindings (render, fit).
void mesh_from_options(const ParsedOptions& options, loomlight::v1::MeshSource* mesh,
                       google::protobuf::RepeatedPtrField<loomlight::v1::MaterialBinding>* bindings);

}  // namespace loomlight::client

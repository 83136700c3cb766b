// The direction grids of BTF assets on the client (SPEC.md section 7; Sattler et al. Table 1): the presets'
// rings and the directions they number, shared by `btf images` (one image per grid pair) and `btf upload`
// (which tells the server each image's directions), and the image file names both use.
#pragma once

#include <string>
#include <vector>

#include "client/cli.h"
#include "client/directions.h"
#include "loomlight/v1/loomlight.pb.h"

namespace loomlight::client {

// --grid h1|h2, validated (default h1), as the preset name the API takes.
std::string btf_grid_option(const ParsedOptions& options);

// A preset's rings: theta 0, 17, .. 85 (h1) or 0, 15, .. 75 (h2) degrees with 1, 6, 12, 18, 20, 24 directions.
loomlight::v1::BtfGrid btf_grid_rings(const std::string& preset);

// The grid's directions, numbered ring by ring; ring r's j-th at azimuth 360 j / count_r degrees.
std::vector<Vec3> btf_grid_directions(const loomlight::v1::BtfGrid& grid);

// "h1, 81 directions" when the rings are a preset's, else "6 rings, 81 directions".
std::string btf_grid_label(const loomlight::v1::BtfGrid& grid);

// "view_003_light_017.exr": the image of view and light grid indices 3 and 17.
std::string btf_image_name(std::size_t view, std::size_t light, const std::string& extension);

}  // namespace loomlight::client

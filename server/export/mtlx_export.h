// Writes fitted materials as a MaterialX 1.39 document (docs/materials-out.md "MaterialX"): one
// open_pbr_surface shader and one surfacematerial per `openpbr` fit, written with pugixml.
#pragma once

#include <string>
#include <vector>

#include "server/models/registry.h"

namespace loomlight::exporting {

struct MtlxMaterial {
  std::string name;            // any text; made into a valid, unique MaterialX name
  models::ParamValues params;  // an openpbr material's every parameter
};

// "" with *out the document, or why not.
std::string WriteMtlx(const std::vector<MtlxMaterial>& materials, std::string* out);

}  // namespace loomlight::exporting

// `loomlight fit`: a material fitted with a standard lobe other tools render (FitMaterial RPC; docs/materials-out.md)
// — glTF 2.0 + KHR_materials_sheen or OpenPBR Surface with fuzz — printing the fit's error and where it misses,
// and writing the .glb/.gltf (on a mesh, with colourways) or the MaterialX .mtlx.
#include <algorithm>
#include <cstdio>
#include <map>
#include <string>
#include <vector>

#include "client/commands.h"
#include "client/job_requests.h"
#include "client/material.h"
#include "client/rpc.h"

namespace loomlight::client {
namespace {

v1::FitTarget target_of(const ParsedOptions& options) {
  const auto to = options.last("to");
  if (!to) throw UsageError("--to: give gltf-sheen or openpbr");
  if (*to == "gltf-sheen") return v1::FIT_TARGET_GLTF_SHEEN;
  if (*to == "openpbr") return v1::FIT_TARGET_OPENPBR;
  throw UsageError("--to: expected gltf-sheen or openpbr, got '" + *to + "'");
}

v1::ExportFormat format_of(const std::string& out) {
  const auto ends = [&out](const std::string& ext) {
    return out.size() >= ext.size() && out.compare(out.size() - ext.size(), ext.size(), ext) == 0;
  };
  if (ends(".glb")) return v1::EXPORT_FORMAT_GLB;
  if (ends(".gltf")) return v1::EXPORT_FORMAT_GLTF;
  if (ends(".mtlx")) return v1::EXPORT_FORMAT_MTLX;
  throw UsageError("--out: the file's extension picks the format: .glb, .gltf or .mtlx, got '" + out + "'");
}

// --colourway NAME=PRESET (every panel) or NAME/MESH_MATERIAL=PRESET (one panel), grouped by NAME in order.
void colourways_from_options(const ParsedOptions& options, v1::FitMaterialRequest* request) {
  std::map<std::string, v1::Colourway*> by_name;
  for (const auto& entry : options.matching({"colourway"})) {
    const std::string& text = entry.value;
    const auto eq = text.rfind('=');
    if (eq == std::string::npos || eq == 0 || eq + 1 == text.size())
      throw UsageError("--colourway: expected NAME=PRESET or NAME/MESH_MATERIAL=PRESET, got '" + text + "'");
    const std::string who = text.substr(0, eq), preset = text.substr(eq + 1);
    const auto slash = who.find('/');
    const std::string name = who.substr(0, slash);
    v1::Colourway*& way = by_name[name];
    if (!way) {
      way = request->add_colourways();
      way->set_name(name);
    }
    if (slash == std::string::npos) {
      way->mutable_material()->set_preset(preset);
    } else {
      v1::MaterialBinding* binding = way->add_bindings();
      binding->set_mesh_material(who.substr(slash + 1));
      binding->mutable_material()->set_preset(preset);
    }
  }
}

void print_fit(const v1::MaterialFit& fit) {
  std::string who;
  if (!fit.colourway().empty()) who += " colourway " + fit.colourway();
  if (!fit.mesh_material().empty()) who += " mesh material " + fit.mesh_material();
  std::printf("%s%s: error %.2f%% (relative L1 of f cos), %.2f s, %u iterations\n", fit.fitted().model().c_str(),
              who.c_str(), 100 * fit.error(), fit.seconds(), fit.iterations());
  for (const v1::Param& p : fit.fitted().params()) {
    std::printf("  %s =", p.name().c_str());
    for (int i = 0; i < p.values_size(); ++i) std::printf("%s%.4g", i ? ", " : " ", p.values(i));
    std::printf("\n");
  }
  // The regions holding most of the error (the response lists them by relative error, which a region with
  // little light can top).
  std::vector<const v1::FitRegionError*> regions;
  for (const v1::FitRegionError& r : fit.regions()) regions.push_back(&r);
  std::stable_sort(regions.begin(), regions.end(), [](auto* a, auto* b) { return a->share() > b->share(); });
  std::printf("  most of the error:");
  for (size_t r = 0; r < regions.size() && r < 3; ++r)
    std::printf("%s %s: %.0f%% of it (error there %.1f%%)", r ? ";" : "", regions[r]->region().c_str(),
                100 * regions[r]->share(), 100 * regions[r]->error());
  std::printf("\n");
  if (!fit.poor_fit().empty()) std::printf("  poor fit: %s\n", fit.poor_fit().c_str());
}

int run_fit(const ParsedOptions& options) {
  v1::FitMaterialRequest request;
  request.set_target(target_of(options));
  v1::MeshSource mesh;
  mesh_from_options(options, &mesh, request.mutable_bindings());
  if (mesh.source_case() != v1::MeshSource::SOURCE_NOT_SET) *request.mutable_mesh() = std::move(mesh);
  colourways_from_options(options, &request);
  if (request.colourways_size() > 0 && request.bindings_size() > 0)
    throw UsageError("--material: with --colourway, bind panels as --colourway NAME/MESH_MATERIAL=PRESET");
  const bool bound_only = request.bindings_size() > 0 && !options.has("preset") && !options.has("model") &&
                          !options.has("btf");
  if (request.colourways_size() == 0 && !bound_only) *request.mutable_material() = material_request(options).material();
  if (auto name = options.last("name")) request.set_name(*name);
  const auto out = options.last("out");
  if (out) request.set_format(format_of(*out));

  const v1::FitMaterialResponse response = Client(options).fit_material(request);
  for (const v1::MaterialFit& fit : response.fits()) print_fit(fit);
  if (out) {
    write_local_file(*out, response.file());
    std::printf("wrote %s (%zu bytes)\n", out->c_str(), response.file().size());
  }
  return 0;
}

OptionList fit_options() {
  OptionList options = material_options();
  options.insert(options.end(), {
      {"to", "TARGET", "gltf-sheen (glTF 2.0 + KHR_materials_sheen) or openpbr (OpenPBR Surface with fuzz)"},
      {"out", "FILE", "write the fit: FILE.glb or FILE.gltf (gltf-sheen), FILE.mtlx (openpbr)"},
      {"name", "TEXT", "the material's name in the file (default: the preset's)"},
      {"mesh", "FILE", "put the fit on this glTF 2.0 or OBJ product mesh, sent with the request (glTF output)"},
      {"mesh-name", "NAME", "put the fit on a mesh stored on the server (`loomlight mesh upload`)"},
      {"material", "MESH_MATERIAL=PRESET", "dress one of the mesh's materials in a preset (repeatable)"},
      {"colourway", "NAME[/MESH_MATERIAL]=PRESET",
       "a colourway (repeatable, up to 16; glTF: one KHR_materials_variants variant each)"},
  });
  return options;
}

}  // namespace

const Command& fit_command() {
  static const Command command = {
      "fit",
      "MATERIAL --to gltf-sheen|openpbr [--out FILE] [--mesh FILE | --mesh-name NAME] [--material M=PRESET]...\n"
      "  [--colourway NAME[/M]=PRESET]...\n"
      "  MATERIAL: " LOOMLIGHT_MATERIAL_SYNOPSIS,
      "fit a material with a standard lobe (glTF sheen, OpenPBR fuzz) and export it",
      "Fits the material's BRDF (a BTF asset's mean) with the parameters of a lobe web viewers and renderers\n"
      "run, minimising the relative L1 error of f cos over fixed direction pairs (docs/materials-out.md), and\n"
      "prints the error, the parameters and the regions of directions it misses most.\n"
      "Examples: loomlight fit --preset silk_shot --to gltf-sheen --out silk.glb\n"
      "          loomlight fit --preset silk_shot --to openpbr --out silk.mtlx",
      fit_options(),
      run_fit,
  };
  return command;
}

}  // namespace loomlight::client

// Turns an API Material (preset, model, parameter overrides) into a validated, complete parameter set.
#pragma once

#include <string>

#include "loomlight/v1/loomlight.pb.h"
#include "server/models/registry.h"

namespace loomlight::models {

struct ResolvedMaterial {
  const Model* model = nullptr;
  ParamValues values;
  std::string label;  // preset or model name, for logs and plots
};

// Fills *out or returns the error as "field: reason", field named as in the request
// (e.g. "material.params[2].values"). Every value is checked against the schema's count and range.
std::string ResolveMaterial(const v1::Material& material, const Registry& registry, ResolvedMaterial* out,
                            const std::string& field = "material");

// Values of one parameter checked against its schema: their count, each finite within [min, max], integers
// integral. "" or "field[i]: reason" naming the parameter. Every material's and scene's parameter goes through it.
std::string CheckParamValues(const ParamSpec& spec, const std::vector<double>& values, const std::string& field);

// The most heap resolving `material` (its transmission layer too) holds for its text parameters' parses
// (Model::TextParseBytes); 0 when it has no text. Names that do not resolve count nothing: resolving refuses them.
size_t TextParseBytes(const v1::Material& material, const Registry& registry);

}  // namespace loomlight::models

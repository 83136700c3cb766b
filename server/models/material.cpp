#include "server/models/material.h"

#include <cmath>
#include <set>
#include <sstream>
#include <vector>

#include "server/models/quote.h"

namespace loomlight::models {

std::string CheckParamValues(const ParamSpec& spec, const std::vector<double>& values, const std::string& field) {
  std::ostringstream err;
  if (values.size() < spec.min_count || values.size() > spec.max_count) {
    err << field << ": parameter '" << spec.name << "' takes ";
    if (spec.min_count == spec.max_count)
      err << spec.min_count;
    else
      err << spec.min_count << " to " << spec.max_count;
    err << " value(s), got " << values.size();
    return err.str();
  }
  for (size_t i = 0; i < values.size(); ++i) {
    const double v = values[i];
    if (!std::isfinite(v) || v < spec.min || v > spec.max) {
      err << field << "[" << i << "]: parameter '" << spec.name << "' value " << v << " is outside ["
          << spec.min << ", " << spec.max << "]" << (spec.unit.empty() ? "" : " " + spec.unit);
      return err.str();
    }
    if (spec.type == ParamType::kInt && v != std::floor(v)) {
      err << field << "[" << i << "]: parameter '" << spec.name << "' must be an integer, got " << v;
      return err.str();
    }
  }
  return "";
}

size_t TextParseBytes(const v1::Material& material, const Registry& registry) {
  size_t bytes = 0;
  const Model* model = nullptr;
  for (const v1::Param& param : material.params()) {
    if (param.text().empty()) continue;
    if (!model) {
      const PresetSpec* preset = nullptr;
      model = !material.preset().empty() ? registry.FindPreset(material.preset(), &preset)
                                         : registry.FindModel(material.model());
      if (!model) return bytes;
    }
    bytes += model->TextParseBytes(param.name(), param.text().size());
  }
  return bytes + (material.has_transmission() ? TextParseBytes(material.transmission(), registry) : 0);
}

std::string ResolveMaterial(const v1::Material& material, const Registry& registry, ResolvedMaterial* out,
                            const std::string& field) {
  const Model* model = nullptr;
  if (!material.preset().empty()) {
    const PresetSpec* preset = nullptr;
    model = registry.FindPreset(material.preset(), &preset);
    if (!model) return field + ".preset: unknown preset " + Quote(material.preset());
    if (!material.model().empty() && material.model() != model->name())
      return field + ".model: preset '" + preset->name + "' belongs to model '" + model->name() + "', not " +
             Quote(material.model());
    out->values = model->PresetValues(*preset);
    out->label = preset->name;
  } else if (!material.model().empty()) {
    model = registry.FindModel(material.model());
    if (!model) return field + ".model: unknown model " + Quote(material.model());
    out->values = model->DefaultValues();
    out->label = model->name();
  } else {
    return field + ": give a preset or a model";
  }
  out->model = model;

  std::set<std::string> seen;
  std::vector<int> texts;  // indices of text parameters
  for (int i = 0; i < material.params_size(); ++i) {
    const v1::Param& param = material.params(i);
    const std::string pfield = field + ".params[" + std::to_string(i) + "]";
    const ParamSpec* spec = model->FindParam(param.name());
    if (!spec)
      return pfield + ".name: model '" + model->name() + "' has no parameter " + Quote(param.name());
    if (!seen.insert(param.name()).second)
      return pfield + ".name: parameter '" + spec->name + "' given twice";
    if (spec->type == ParamType::kText) {
      texts.push_back(i);  // applied after every value, so its parameters cannot also be given
      continue;
    }
    if (!param.text().empty())
      return pfield + ".text: parameter '" + spec->name + "' takes values, not text";
    const std::vector<double> values(param.values().begin(), param.values().end());
    std::string err = CheckParamValues(*spec, values, pfield + ".values");
    if (!err.empty()) return err;
    out->values[param.name()] = values;
  }
  for (int i : texts) {
    const v1::Param& param = material.params(i);
    const std::string pfield = field + ".params[" + std::to_string(i) + "]";
    const ParamSpec& spec = *model->FindParam(param.name());
    if (param.values_size() > 0) return pfield + ".values: parameter '" + spec.name + "' takes text, not values";
    if (param.text().empty() || param.text().size() > spec.max_count)
      return pfield + ".text: parameter '" + spec.name + "' takes 1 to " + std::to_string(spec.max_count) +
             " bytes of text, got " + std::to_string(param.text().size());
    // Applied to an empty set, so what it writes is exactly the parameters it sets: none of them may also be
    // given, whatever their values (equal values too: a client never has to guess which of two wins).
    ParamValues set;
    std::string err = model->ApplyText(spec.name, param.text(), &set);
    if (!err.empty()) return pfield + ".text: " + err;
    for (const auto& [name, v] : set)
      if (seen.count(name))
        return pfield + ".name: parameter '" + spec.name + "' sets '" + name + "', which is also given";
    for (auto& [name, v] : set) out->values[name] = std::move(v);
  }
  std::string err = model->Validate(out->values);
  if (!err.empty()) return field + ".params: " + err;
  return "";
}

}  // namespace loomlight::models

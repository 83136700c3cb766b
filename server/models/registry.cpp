#include "server/models/registry.h"

namespace loomlight::models {

const ParamSpec* Model::FindParam(const std::string& name) const {
  for (const ParamSpec& p : params())
    if (p.name == name) return &p;
  return nullptr;
}

ParamValues Model::DefaultValues() const {
  ParamValues values;
  for (const ParamSpec& p : params())
    if (p.type != ParamType::kText) values[p.name] = p.defaults;
  return values;
}

ParamValues Model::PresetValues(const PresetSpec& preset) const {
  ParamValues values = DefaultValues();
  for (const auto& [name, v] : preset.values) values[name] = v;
  return values;
}

Registry& Registry::Global() {
  static Registry* registry = [] {
    auto* r = new Registry;
    r->Add(MakeMicrocylinderModel());
    r->Add(MakeWovenModel());
    r->Add(MakeThinLayerModel());
    r->Add(MakeFiberModel());
    return r;
  }();
  return *registry;
}

void Registry::Add(std::unique_ptr<Model> model) { models_.push_back(std::move(model)); }

const Model* Registry::FindModel(const std::string& name) const {
  for (const auto& m : models_)
    if (m->name() == name) return m.get();
  return nullptr;
}

const Model* Registry::FindPreset(const std::string& name, const PresetSpec** preset) const {
  for (const auto& m : models_)
    for (const PresetSpec& p : m->presets())
      if (p.name == name) {
        if (preset) *preset = &p;
        return m.get();
      }
  return nullptr;
}

}  // namespace loomlight::models

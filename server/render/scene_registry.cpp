#include "server/render/scene_registry.h"

#include <set>
#include <utility>

#include "server/models/material.h"
#include "server/models/quote.h"

namespace loomlight::render {

const SceneRegistry& SceneRegistry::Global() {
  static const SceneRegistry* registry = [] {
    auto* r = new SceneRegistry;
    AddBuiltinScenes(r);
    return r;
  }();
  return *registry;
}

void SceneRegistry::Add(SceneSpec scene) { scenes_.push_back(std::move(scene)); }

const SceneSpec* SceneRegistry::Find(std::string_view name) const {
  for (const SceneSpec& s : scenes_)
    if (s.name == name) return &s;
  return nullptr;
}

const SceneSpec* SceneRegistry::FindPreset(int preset) const {
  for (const SceneSpec& s : scenes_)
    if (s.preset == preset && preset != SceneSpec::kNoPreset) return &s;
  return nullptr;
}

std::string ResolveScene(const v1::RenderRequest& request, const SceneRegistry& registry, ResolvedScene* out) {
  if (!request.scene_name().empty()) {
    out->spec = registry.Find(request.scene_name());
    if (!out->spec) return "scene_name: unknown scene " + models::Quote(request.scene_name()) + " (ListScenes lists them)";
  } else {
    out->spec = registry.FindPreset(request.scene());
    if (!out->spec) return "scene: unknown value " + std::to_string(request.scene());
  }
  const SceneSpec& scene = *out->spec;
  out->values = models::DefaultValues(scene.params);
  std::set<std::string> seen;
  for (int i = 0; i < request.scene_params_size(); ++i) {
    const v1::Param& param = request.scene_params(i);
    const std::string field = "scene_params[" + std::to_string(i) + "]";
    const models::ParamSpec* spec = models::FindParam(scene.params, param.name());
    if (!spec) return field + ".name: scene '" + scene.name + "' has no parameter " + models::Quote(param.name());
    if (!seen.insert(spec->name).second) return field + ".name: parameter '" + spec->name + "' given twice";
    if (!param.text().empty()) return field + ".text: parameter '" + spec->name + "' takes values, not text";
    const std::vector<double> values(param.values().begin(), param.values().end());
    if (std::string e = models::CheckParamValues(*spec, values, field + ".values"); !e.empty()) return e;
    out->values[spec->name] = values;
  }
  return "";
}

void SetUpFiberScene(Scene* scene, std::string object, CameraSpec camera, Vec3 toward_light) {
  scene->objects.push_back({std::move(object), Shape{}, 0, true});
  scene->fiber_object = 0;
  scene->default_camera = camera;
  scene->default_lights.push_back({Light::Type::kDirectional, Normalize(toward_light), {}, {3, 3, 3}, {}, {}, 0, 0});
  scene->default_environment = false;
  scene->default_ambient = 0.25;
}

models::ParamSpec ScalarParam(std::string name, models::ParamType type, std::string unit, double min, double max,
                              double default_value, std::string description) {
  return {std::move(name), type, std::move(unit), min, max, {default_value}, std::move(description), 1, 1};
}

}  // namespace loomlight::render

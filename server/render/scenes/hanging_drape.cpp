// A product scene: a curtain hanging from a rod in real folds (cloth simulation), lit by the studio softboxes. Its mesh is server/render/scenes/meshes/hanging_drape.glb (PROVENANCE.md there says how
// it was made).
#include "server/render/mesh_scene.h"
#include "server/render/scene_registry.h"

namespace loomlight::render {
namespace {

Scene Build(const models::ParamValues&) { return ProductScene("hanging_drape"); }

SceneSpec Spec() {
  return {"hanging_drape", SceneSpec::kNoPreset, "a curtain hanging from a rod in real folds (cloth simulation), lit by the studio softboxes", {}, {.uv = true, .transmission = true}, Build};
}

}  // namespace
}  // namespace loomlight::render

LOOMLIGHT_REGISTER_SCENE(hanging_drape, Spec)

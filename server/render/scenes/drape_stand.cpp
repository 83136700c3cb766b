// A product scene: a square of the fabric dropped over a round stand by cloth simulation, settled in folds. Its mesh is server/render/scenes/meshes/drape_stand.glb (PROVENANCE.md there says how
// it was made).
#include "server/render/mesh_scene.h"
#include "server/render/scene_registry.h"

namespace loomlight::render {
namespace {

Scene Build(const models::ParamValues&) { return ProductScene("drape_stand"); }

SceneSpec Spec() {
  return {"drape_stand", SceneSpec::kNoPreset, "a square of the fabric dropped over a round stand by cloth simulation, settled in folds", {}, {.uv = true}, Build};
}

}  // namespace
}  // namespace loomlight::render

LOOMLIGHT_REGISTER_SCENE(drape_stand, Spec)

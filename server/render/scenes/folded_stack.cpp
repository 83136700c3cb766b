// A product scene: folded pieces of the fabric stacked as a shop shelves them, folded by cloth simulation. Its mesh is server/render/scenes/meshes/folded_stack.glb (PROVENANCE.md there says how
// it was made).
#include "server/render/mesh_scene.h"
#include "server/render/scene_registry.h"

namespace loomlight::render {
namespace {

Scene Build(const models::ParamValues&) { return ProductScene("folded_stack", 40); }  // from above: a stack's top shows

SceneSpec Spec() {
  return {"folded_stack", SceneSpec::kNoPreset, "folded pieces of the fabric stacked as a shop shelves them, folded by cloth simulation", {}, {.uv = true}, Build};
}

}  // namespace
}  // namespace loomlight::render

LOOMLIGHT_REGISTER_SCENE(folded_stack, Spec)

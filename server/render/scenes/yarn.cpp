// Wu and Yuksel Fig. 7: one straight procedural yarn (RenderRequest.yarn, length 1 along +z), ray traced fiber
// by fiber and seen from the side.
#include "server/render/scene_registry.h"

namespace loomlight::render {
namespace {

Scene BuildYarn(const models::ParamValues& p) {
  // About three yarn widths across at the default field of view, lit from the upper left front.
  Scene scene;
  SetUpFiberScene(&scene, "yarn (fibers)", {{0.35, 0.02, 0.5}, {0, 0, 0.5}, {0, 1, 0}, p.at("fov_deg")[0]},
                  {0.8, 0.7, 0.4});
  return scene;
}

SceneSpec Yarn() {
  return {"yarn", v1::SCENE_YARN,
          "Wu and Yuksel Fig. 7: one straight yarn (RenderRequest.yarn) along +z, fiber by fiber, seen from the side",
          // Narrower is closer up: the pixel footprint, and so the yarn's level of detail, follows it.
          {ScalarParam("fov_deg", models::ParamType::kReal, "deg", 5, 90, 32,
                       "the default camera's vertical field of view")},
          {.fibers = true}, BuildYarn};
}

}  // namespace
}  // namespace loomlight::render

LOOMLIGHT_REGISTER_SCENE(yarn, Yarn)

// A close-up of a woven patch: the warp and weft of RenderRequest.woven (default cotton_twill, 2 x 2 repeats)
// laid out in the xy plane, normal +z, about 1 x 1, ray traced fiber by fiber.
#include "server/render/scene_registry.h"

namespace loomlight::render {
namespace {

Scene BuildWovenPatch(const models::ParamValues& p) {
  // Looking down at about 35 degrees from the normal at a part a few yarns wide at the default field of view.
  Scene scene;
  SetUpFiberScene(&scene, "woven patch (fibers)", {{0.5, 0.1, 0.65}, {0.5, 0.5, 0}, {0, 1, 0}, p.at("fov_deg")[0]},
                  {-0.5, 0.4, 0.8});
  return scene;
}

SceneSpec WovenPatch() {
  return {"woven_patch", v1::SCENE_WOVEN_PATCH,
          "a close-up of the warp and weft of RenderRequest.woven (default cotton_twill, 2 x 2), fiber by fiber",
          // Narrower is closer up: the pixel footprint, and so the yarns' level of detail, follows it.
          {ScalarParam("fov_deg", models::ParamType::kReal, "deg", 5, 90, 30,
                       "the default camera's vertical field of view")},
          {.fibers = true, .woven = true}, BuildWovenPatch};
}

}  // namespace
}  // namespace loomlight::render

LOOMLIGHT_REGISTER_SCENE(woven_patch, WovenPatch)

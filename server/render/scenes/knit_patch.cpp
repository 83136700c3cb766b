// A close-up of a weft knit: the courses of RenderRequest.knit (default jersey, 8 x 8 stitches) in the xy plane,
// wales along +y, face toward +z, ray traced fiber by fiber.
#include "server/render/scene_registry.h"

namespace loomlight::render {
namespace {

Scene BuildKnitPatch(const models::ParamValues& p) {
  // Looking at the face 29.4 degrees from its normal, from below along the wales, so the loops' legs and heads
  // both show; placed as Render frames the default knit (cotton1: about 2.6 x 2.1) in a square image. Render
  // moves it along this line of sight to frame the request's knit whole (at the default field of view: a
  // narrower one closes in on its centre).
  Scene scene;
  SetUpFiberScene(&scene, "knit patch (fibers)",
                  {{1.273, -1.925, 5.028}, {1.273, 0.912, 0}, {0, 1, 0}, p.at("fov_deg")[0]}, {-0.5, 0.4, 0.8});
  return scene;
}

SceneSpec KnitPatch() {
  return {"knit_patch", SceneSpec::kNoPreset,
          "a close-up of the knit of RenderRequest.knit (default jersey, 8 x 8 stitches), fiber by fiber",
          // Narrower is closer up: the pixel footprint, and so the yarns' level of detail, follows it.
          {ScalarParam("fov_deg", models::ParamType::kReal, "deg", 5, 90, 30,
                       "the default camera's vertical field of view")},
          {.fibers = true, .knit = true}, BuildKnitPatch};
}

}  // namespace
}  // namespace loomlight::render

LOOMLIGHT_REGISTER_SCENE(knit_patch, KnitPatch)

// Yarns along the client's centre curves (RenderRequest.curves; default: one yarn arching over another), ray
// traced fiber by fiber.
#include "server/render/scene_registry.h"

namespace loomlight::render {
namespace {

Scene BuildYarnCurves(const models::ParamValues& p) {
  // Looking down 40 degrees from +z, placed as Render frames the default curves in a square image; Render moves
  // it along this line of sight to frame the request's curves whole (at the default field of view: a narrower
  // one closes in).
  Scene scene;
  SetUpFiberScene(&scene, "yarn curves (fibers)", {{0, -1.691, 2.008}, {0, 0, 0}, {0, 1, 0}, p.at("fov_deg")[0]},
                  {-0.5, 0.4, 0.8});
  return scene;
}

SceneSpec YarnCurves() {
  return {"yarn_curves", SceneSpec::kNoPreset,
          "yarns along the centre curves of RenderRequest.curves (default: one yarn arching over another), fiber "
          "by fiber, framed whole",
          {ScalarParam("fov_deg", models::ParamType::kReal, "deg", 5, 90, 30,
                       "the default camera's vertical field of view")},
          {.fibers = true, .curves = true}, BuildYarnCurves};
}

}  // namespace
}  // namespace loomlight::render

LOOMLIGHT_REGISTER_SCENE(yarn_curves, YarnCurves)

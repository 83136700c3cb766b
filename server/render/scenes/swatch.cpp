// A flat square swatch tilted toward the camera: a material's pattern seen as a sample in the hand.
#include <cmath>
#include <numbers>

#include "server/render/scene_registry.h"

namespace loomlight::render {
namespace {

Scene BuildSwatch(const models::ParamValues& p) {
  // The swatch's normal leans tilt_deg from +y toward the camera (0: lying flat, 90: facing the camera).
  const double tilt = p.at("tilt_deg")[0] * std::numbers::pi / 180, half = 0.5 * p.at("size")[0];
  Scene scene;
  scene.objects.push_back(
      {"swatch", QuadShape({0, 0, 0}, {1, 0, 0}, {0, std::sin(tilt), -std::cos(tilt)}, half, half), 0});
  scene.default_camera = {{0, 1.4, 1.6}, {0, 0, 0}, {0, 1, 0}, 40};
  scene.default_texture_scale = 8;
  return scene;
}

SceneSpec Swatch() {
  return {"swatch", v1::SCENE_SWATCH, "a flat square swatch tilted toward the camera",
          {ScalarParam("tilt_deg", models::ParamType::kReal, "deg", 0, 90, 50,
                       "the swatch normal's lean from straight up toward the camera"),
           // Up to 1.5: the default camera still sees all of it at any tilt.
           ScalarParam("size", models::ParamType::kReal, "", 0.25, 1.5, 1, "the swatch's side in scene units")},
          {.uv = true}, BuildSwatch};
}

}  // namespace
}  // namespace loomlight::render

LOOMLIGHT_REGISTER_SCENE(swatch, Swatch)

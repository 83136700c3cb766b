// A hanging curtain facing the camera with a low sun behind it ("window light"): a material's transmission
// shows.
#include "server/render/scene_registry.h"

namespace loomlight::render {
namespace {

Scene BuildCurtain(const models::ParamValues& p) {
  Scene scene;
  scene.objects.push_back(
      {"curtain", QuadShape({0, 0, 0}, {1, 0, 0}, {0, 1, 0}, 0.5 * p.at("width")[0], 0.5 * p.at("height")[0]), 90});
  scene.default_camera = {{0, 0, 3.6}, {0, 0, 0}, {0, 1, 0}, 42};
  scene.default_texture_scale = 8;
  scene.default_lights.push_back({Light::Type::kDirectional, Normalize({0.3, 0.35, -1}), {}, {4, 3.8, 3.4}, {}, {}, 0, 0});
  scene.default_environment_intensity = 0.4;
  return scene;
}

SceneSpec Curtain() {
  return {"curtain", v1::SCENE_CURTAIN,
          "a hanging curtain in the plane z = 0, lit from behind by a low sun: transmission shows",
          {ScalarParam("width", models::ParamType::kReal, "", 0.5, 3, 2, "the curtain's width in scene units"),
           ScalarParam("height", models::ParamType::kReal, "", 0.5, 3, 2.4, "the curtain's height in scene units")},
          {.uv = true, .transmission = true}, BuildCurtain};
}

}  // namespace
}  // namespace loomlight::render

LOOMLIGHT_REGISTER_SCENE(curtain, Curtain)

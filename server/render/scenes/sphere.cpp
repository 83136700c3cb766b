// A sphere at the origin: a material's look over every angle at once.
#include "server/render/scene_registry.h"

namespace loomlight::render {
namespace {

Scene BuildSphere(const models::ParamValues& p) {
  Scene scene;
  scene.objects.push_back({"sphere", SphereShape({0, 0, 0}, p.at("radius")[0]), 0});
  scene.default_camera = {{0, 0.5, 3.2}, {0, 0, 0}, {0, 1, 0}, 40};
  scene.default_texture_scale = 8;
  return scene;
}

SceneSpec Sphere() {
  return {"sphere", v1::SCENE_SPHERE, "a sphere at the origin under the built-in sky",
          // Up to 1.5: the default camera, 3.2 from the centre, still sees all of it.
          {ScalarParam("radius", models::ParamType::kReal, "", 0.25, 1.5, 1, "the sphere's radius in scene units")},
          {.uv = true}, BuildSphere};
}

}  // namespace
}  // namespace loomlight::render

LOOMLIGHT_REGISTER_SCENE(sphere, Sphere)

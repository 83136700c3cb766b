// Sadeghi et al. Fig. 12: the same cloth wrapped around a row of cylinders, its threads vertical, horizontal
// and diagonal in turn.
#include <algorithm>
#include <string>

#include "server/render/scene_registry.h"

namespace loomlight::render {
namespace {

constexpr double kSpacing = 1.1;     // between the cylinders' axes
constexpr double kHalfHeight = 0.8;  // the camera stays between their ends, so their open ends never show inside
constexpr double kCameraDistance = 5;
// The row's half width the default camera frames: three cylinders of radius 0.4.
constexpr double kFramedHalfWidth = kSpacing + 0.4;

Scene BuildCylinders(const models::ParamValues& p) {
  struct Wrap {
    double thread_angle_deg;
    const char* threads;
  };
  static constexpr Wrap kWraps[] = {{90, "vertical"}, {0, "horizontal"}, {45, "diagonal"}};
  const int count = static_cast<int>(p.at("count")[0]);
  const double radius = p.at("radius")[0];
  Scene scene;
  for (int i = 0; i < count; ++i) {
    const Wrap& wrap = kWraps[i % 3];
    const double x = (i - 0.5 * (count - 1)) * kSpacing;
    scene.objects.push_back({"cylinder " + std::to_string(i + 1) + " (threads " + wrap.threads + ")",
                             CylinderShape({x, 0, 0}, radius, kHalfHeight), wrap.thread_angle_deg});
  }
  // A longer or thicker row moves the camera back until it frames the row as the default frames three.
  const double half_width = 0.5 * (count - 1) * kSpacing + radius;
  const double distance = kCameraDistance * std::max(1.0, half_width / kFramedHalfWidth);
  scene.default_camera = {{0, 0.25, distance}, {0, 0, 0}, {0, 1, 0}, 36};
  scene.default_texture_scale = 10;
  return scene;
}

SceneSpec Cylinders() {
  return {"cylinders", v1::SCENE_CYLINDERS,
          "Sadeghi et al. Fig. 12: a row of cylinders wrapped in the cloth, threads vertical, horizontal, diagonal",
          {ScalarParam("count", models::ParamType::kInt, "", 1, 5, 3,
                       "cylinders in the row (their threads repeat vertical, horizontal, diagonal)"),
           // Below half the spacing (0.55), so neighbours never touch.
           ScalarParam("radius", models::ParamType::kReal, "", 0.1, 0.5, 0.4, "each cylinder's radius in scene units")},
          {.uv = true}, BuildCylinders};
}

}  // namespace
}  // namespace loomlight::render

LOOMLIGHT_REGISTER_SCENE(cylinders, Cylinders)

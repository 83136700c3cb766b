#include "server/render/mesh_scene.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <mutex>
#include <numbers>

#include "server/render/lighting_presets.h"
#include "server/render/scenes/builtin_meshes.h"

namespace loomlight::render {

constexpr double kDegree = std::numbers::pi / 180;

Subject SubjectOf(const assets::TriangleMesh& mesh) {
  const Vec3 lo{mesh.bounds_min[0], mesh.bounds_min[1], mesh.bounds_min[2]};
  const Vec3 hi{mesh.bounds_max[0], mesh.bounds_max[1], mesh.bounds_max[2]};
  Subject s;
  s.centre = 0.5 * (lo + hi);
  s.radius = std::max(0.5 * Length(hi - lo), 1e-6);
  return s;
}

namespace {
// Rodrigues' rotation of v about the unit axis.
Vec3 Rotate(Vec3 v, Vec3 axis, double angle) {
  const double c = std::cos(angle), s = std::sin(angle);
  return c * v + s * Cross(axis, v) + (1 - c) * Dot(axis, v) * axis;
}
}  // namespace

CameraSpec FramingCamera(const assets::TriangleMesh& mesh, int width, int height, double elevation_deg,
                         double fov_deg) {
  const Subject subject = SubjectOf(mesh);
  const Vec3 direction{0, std::sin(elevation_deg * kDegree), std::cos(elevation_deg * kDegree)};
  const Vec3 up{0, 1, 0}, forward = -1.0 * direction;
  const Vec3 right = Normalize(Cross(forward, up)), camera_up = Cross(right, forward);
  // Each field of view's half-angle tangent, with a 6% margin around the product.
  const double tan_v = std::tan(0.5 * fov_deg * kDegree) / 1.06;
  const double tan_h = tan_v * double(std::max(width, 1)) / double(std::max(height, 1));
  // The nearest distance at which every corner of the bounding box lies inside the frame, in every turn of a
  // turntable about +y (16 steps): a point q from the centre is seen at depth d + q.forward, and fits while
  // |q.right| <= tan_h (d + q.forward) and |q.up| <= tan_v (d + q.forward).
  double distance = 0;
  for (int corner = 0; corner < 8; ++corner) {
    const Vec3 q{(corner & 1 ? mesh.bounds_max[0] : mesh.bounds_min[0]) - subject.centre.x,
                 (corner & 2 ? mesh.bounds_max[1] : mesh.bounds_min[1]) - subject.centre.y,
                 (corner & 4 ? mesh.bounds_max[2] : mesh.bounds_min[2]) - subject.centre.z};
    for (int step = 0; step < 16; ++step) {
      const Vec3 turned = Rotate(q, up, 2 * std::numbers::pi * step / 16);
      distance = std::max({distance, std::fabs(Dot(turned, right)) / tan_h - Dot(turned, forward),
                           std::fabs(Dot(turned, camera_up)) / tan_v - Dot(turned, forward)});
    }
  }
  // Never inside the bounding sphere.
  distance = std::max(distance, 1.01 * subject.radius);
  CameraSpec camera;
  camera.look_at = subject.centre;
  camera.position = subject.centre + distance * direction;
  camera.up = up;
  camera.fov_deg = fov_deg;
  return camera;
}

double TurntableAngle(int k, int views) { return 2 * std::numbers::pi * k / std::max(views, 1); }

std::vector<CameraSpec> TurntableCameras(const CameraSpec& first, int views) {
  std::vector<CameraSpec> cameras;
  const Vec3 axis = Normalize(first.up);
  for (int k = 0; k < std::max(views, 1); ++k) {
    CameraSpec camera = first;
    camera.position = first.look_at + Rotate(first.position - first.look_at, axis, TurntableAngle(k, views));
    cameras.push_back(camera);
  }
  return cameras;
}

Light TurnLight(const Light& light, const CameraSpec& first, double angle) {
  const Vec3 axis = Normalize(first.up);
  Light turned = light;
  turned.position = first.look_at + Rotate(light.position - first.look_at, axis, angle);
  turned.direction = Rotate(light.direction, axis, angle);
  turned.axis_u = Rotate(light.axis_u, axis, angle);
  turned.axis_v = Rotate(light.axis_v, axis, angle);
  return turned;
}

std::string MeshObjectName(std::string_view material_name) {
  return material_name.empty() ? std::string("mesh (no material)")
                               : "mesh material '" + std::string(material_name.substr(0, 64)) + "'";
}

Scene MeshScene(std::shared_ptr<const MeshGeometry> geometry, double uv_length, int width, int height,
                double elevation_deg) {
  Scene scene;
  const assets::TriangleMesh& mesh = geometry->mesh();
  for (const std::string& name : mesh.material_names) {
    SceneObject object;
    object.name = MeshObjectName(name);
    scene.objects.push_back(object);
  }
  scene.mesh = std::move(geometry);
  scene.mesh_first_object = 0;
  scene.mesh_uv_length = uv_length;
  const Subject subject = SubjectOf(mesh);
  scene.default_camera = FramingCamera(mesh, width, height, elevation_deg);
  // Repeats per unit of s = u x uv_length: one such unit spans metres_per_uv / uv_length metres of surface.
  const double metres = mesh.metres_per_uv > 0 ? mesh.metres_per_uv : 1.0;
  scene.default_texture_scale = kDefaultMeshRepeatsPerMetre * metres / uv_length;
  const LightingPreset* studio = FindLightingPreset(kDefaultMeshLighting);
  scene.default_lights = PlaceLights(*studio, subject.centre, subject.radius, scene.default_camera);
  scene.default_environment = false;
  return scene;
}

Scene ProductScene(std::string_view mesh_name, double elevation_deg) {
  std::shared_ptr<const MeshGeometry> geometry = BuiltinMeshGeometry(mesh_name);
  if (!geometry) return {};
  const double metres_per_uv = geometry->mesh().metres_per_uv > 0 ? geometry->mesh().metres_per_uv : 1.0;
  return MeshScene(std::move(geometry), metres_per_uv, 1, 1, elevation_deg);
}

std::shared_ptr<const MeshGeometry> BuiltinMeshGeometry(std::string_view name) {
  static std::mutex lock;
  static std::map<std::string, std::shared_ptr<const MeshGeometry>, std::less<>> built;
  std::lock_guard guard(lock);
  if (auto it = built.find(name); it != built.end()) return it->second;
  const std::string_view bytes = BuiltinMesh(name);
  if (bytes.empty()) return nullptr;
  auto mesh = std::make_shared<assets::TriangleMesh>();
  std::shared_ptr<const MeshGeometry> geometry;
  if (!assets::ParseMesh(bytes, v1::MESH_FORMAT_AUTO, assets::MeshLimits{}, mesh.get()).empty() ||
      !MeshGeometry::Build(std::move(mesh), uint64_t{1} << 30, {}, &geometry).empty())
    geometry = nullptr;
  built.emplace(std::string(name), geometry);
  return geometry;
}

}  // namespace loomlight::render

#include "server/render/lighting_presets.h"

#include <algorithm>
#include <cmath>
#include <numbers>

#include "server/render/mesh_geometry.h"
#include "server/yarn/fiber_scene.h"

namespace loomlight::render {
namespace {

constexpr double kPi = std::numbers::pi;
constexpr double kDegree = kPi / 180;

// Whether unit a and b are (nearly) parallel, as the validation of RenderLight.up and RenderCamera.up judges.
bool Parallel(Vec3 a, Vec3 b) { return Length(Cross(a, b)) < 1e-6; }

}  // namespace

Light RectLight(Vec3 centre, Vec3 facing, double width, double height, Vec3 up, Rgb radiance) {
  Light light;
  light.type = Light::Type::kRect;
  light.position = centre;
  light.direction = Normalize(facing);
  light.rgb = radiance;
  light.width = width;
  light.height = height;
  for (const Vec3 candidate : {Normalize(up), Vec3{0, 1, 0}, Vec3{0, 0, 1}}) {
    if (Length(candidate) == 0 || Parallel(candidate, light.direction)) continue;
    light.axis_v = Normalize(candidate - Dot(candidate, light.direction) * light.direction);
    break;
  }
  light.axis_u = Cross(light.axis_v, light.direction);  // so that Cross(axis_u, axis_v) = direction
  return light;
}

bool SampleRectLight(const Light& light, Vec3 point, double u0, double u1, RectLightSample* out) {
  const Vec3 n = light.direction;
  const double area = light.width * light.height;
  if (!(area > 0) || !(Dot(point - light.position, n) > 0)) return false;
  // The rectangle in a frame at the point: x along axis_u, y along axis_v, z = n; its corner (x0, y0, z0) with
  // z0 < 0 (the point is in front).
  const Vec3 corner = light.position - (0.5 * light.width) * light.axis_u - (0.5 * light.height) * light.axis_v;
  const Vec3 d = corner - point;
  const double x0 = Dot(d, light.axis_u), y0 = Dot(d, light.axis_v), z0 = Dot(d, n);
  const double x1 = x0 + light.width, y1 = y0 + light.height;
  // The normals of the planes through the point and each edge, and the spherical rectangle's inner angles.
  const Vec3 v00{x0, y0, z0}, v01{x0, y1, z0}, v10{x1, y0, z0}, v11{x1, y1, z0};
  const Vec3 n0 = Normalize(Cross(v00, v10)), n1 = Normalize(Cross(v10, v11));
  const Vec3 n2 = Normalize(Cross(v11, v01)), n3 = Normalize(Cross(v01, v00));
  const auto angle = [](Vec3 a, Vec3 b) { return std::acos(std::clamp(-Dot(a, b), -1.0, 1.0)); };
  const double g0 = angle(n0, n1), g1 = angle(n1, n2), g2 = angle(n2, n3), g3 = angle(n3, n0);
  const double k = 2 * kPi - g2 - g3;
  const double solid_angle = g0 + g1 - k;
  Vec3 target;
  if (solid_angle >= kMinSphericalRectSolidAngle && solid_angle < 2 * kPi - 1e-6) {
    // Urena et al.'s Algorithm 1: x from u0 by the area of the sub-rectangle left of it, then y from u1
    // uniformly in the solid angle along that column.
    const double b0 = n0.z, b1 = n2.z;
    const double au = u0 * solid_angle + k;
    const double fu = (std::cos(au) * b0 - b1) / std::sin(au);
    const double cu = std::clamp((fu > 0 ? 1.0 : -1.0) / std::sqrt(fu * fu + b0 * b0), -1.0, 1.0);
    const double xu = std::clamp(-(cu * z0) / std::max(std::sqrt(1 - cu * cu), 1e-300), x0, x1);
    const double dist = std::sqrt(xu * xu + z0 * z0);
    const double h0 = y0 / std::sqrt(dist * dist + y0 * y0), h1 = y1 / std::sqrt(dist * dist + y1 * y1);
    const double hv = h0 + u1 * (h1 - h0), hv2 = hv * hv;
    const double yv = std::clamp(hv2 < 1 - 1e-12 ? hv * dist / std::sqrt(1 - hv2) : y1, y0, y1);
    target = point + xu * light.axis_u + yv * light.axis_v + z0 * n;
    const Vec3 w = target - point;
    out->distance = Length(w);
    if (!(out->distance > 0)) return false;
    out->direction = (1 / out->distance) * w;
    out->incident = solid_angle * light.rgb;  // radiance over the density 1 / solid_angle
    return IsFinite(out->direction) && IsFinite(out->incident);
  }
  // Small (or, from within its plane's rounding, almost a hemisphere): uniformly by area, the density per
  // steradian d^2 / (area cos) at the light.
  target = corner + (u0 * light.width) * light.axis_u + (u1 * light.height) * light.axis_v;
  const Vec3 w = target - point;
  const double d2 = Dot(w, w);
  if (!(d2 > 0)) return false;
  out->distance = std::sqrt(d2);
  out->direction = (1 / out->distance) * w;
  const double cos_light = -Dot(out->direction, n);
  if (!(cos_light > 0)) return false;
  out->incident = (cos_light * area / d2) * light.rgb;
  return IsFinite(out->direction) && IsFinite(out->incident);
}

std::span<const LightingPreset> LightingPresets() {
  // Softboxes at about 4 radii, radiance neutral so a fabric's colour reads true. Irradiance at the subject's centre,
  // facing each (the closed form for a point on a rectangle's axis): "studio" key 2.85, fill 0.78, rim 2.0, the
  // map at half its radiance 0.45 sideways (with the map, the key side about 3:1 over the fill side, for modelling);
  // "studio_high_key" 2.6, 2.3, 2.3 and the map 1.8 sideways; "softbox_top" 4.1.
  static const std::vector<LightingPreset> presets = {
      {"studio",
       "Key softbox 45 degrees camera-left above, fill camera-right lower (about a quarter of the key), a strip rim "
       "light behind on the right, over the studio map (bright top, grey walls, darker floor) at half its radiance",
       {{"key", -45, 35, 4, 3, 3, {6, 6, 6}},
        {"fill", 50, 15, 4.5, 3, 3, {2, 2, 2}},
        {"rim", 155, 35, 4, 1.5, 3.5, {7, 7, 7}}},
       0.5},
      {"studio_high_key",
       "Catalogue shots on white: two large softboxes either side of the camera and one overhead, nearly equal, "
       "over a bright studio map: soft shadows, low contrast",
       {{"key", -40, 30, 4, 4, 4, {3.5, 3.5, 3.5}},
        {"fill", 40, 25, 4, 4, 4, {3, 3, 3}},
        {"top", 0, 90, 4, 4, 4, {3, 3, 3}}},
       2},
      {"softbox_top",
       "One large softbox above and slightly in front of the subject (flat lays, folded stacks), over the studio map",
       {{"top", 0, 70, 4, 5, 5, {4, 4, 4}}},
       1},
  };
  return presets;
}

const LightingPreset* FindLightingPreset(std::string_view name) {
  for (const LightingPreset& preset : LightingPresets())
    if (preset.name == name) return &preset;
  return nullptr;
}

std::vector<Light> PlaceLights(const LightingPreset& preset, Vec3 centre, double radius, const CameraSpec& camera) {
  // The camera's frame about its up (the image's right, level; toward the camera, level): a camera tilted down
  // at the subject leaves the key's elevation above the floor as the preset says.
  const Vec3 vertical = Normalize(camera.up);
  const Vec3 forward = Normalize(camera.look_at - camera.position);
  const Vec3 right = Normalize(Cross(forward, vertical));
  const Vec3 front = Cross(right, vertical);
  std::vector<Light> lights;
  for (const PresetLight& p : preset.lights) {
    const double azimuth = p.azimuth_deg * kDegree, elevation = p.elevation_deg * kDegree;
    const Vec3 from_centre = std::cos(elevation) * (std::cos(azimuth) * front + std::sin(azimuth) * right) +
                             std::sin(elevation) * vertical;
    const Vec3 position = centre + (p.distance * radius) * from_centre;
    // Upright where it can be; an overhead softbox's height runs toward the camera.
    const Vec3 up = Parallel(from_centre, vertical) ? front : vertical;
    lights.push_back(RectLight(position, -from_centre, p.width * radius, p.height * radius, up, p.radiance));
  }
  return lights;
}

void SubjectSphere(const Scene& scene, const CameraSpec& camera, Vec3* centre, double* radius) {
  Vec3 lower{INFINITY, INFINITY, INFINITY}, upper{-INFINITY, -INFINITY, -INFINITY};
  const auto include = [&](Vec3 p) {
    lower = {std::min(lower.x, p.x), std::min(lower.y, p.y), std::min(lower.z, p.z)};
    upper = {std::max(upper.x, p.x), std::max(upper.y, p.y), std::max(upper.z, p.z)};
  };
  // A mesh's objects stand for its materials (their shapes are never intersected): its bounds count instead.
  const size_t mesh_begin = scene.mesh ? size_t(scene.mesh_first_object) : scene.objects.size();
  const size_t mesh_end = scene.mesh ? mesh_begin + scene.mesh->mesh().material_names.size() : mesh_begin;
  if (scene.mesh) {
    const assets::TriangleMesh& mesh = scene.mesh->mesh();
    include({mesh.bounds_min[0], mesh.bounds_min[1], mesh.bounds_min[2]});
    include({mesh.bounds_max[0], mesh.bounds_max[1], mesh.bounds_max[2]});
  }
  for (size_t o = 0; o < scene.objects.size(); ++o) {
    const SceneObject& object = scene.objects[o];
    if (object.fibers || (o >= mesh_begin && o < mesh_end)) continue;
    const Shape& s = object.shape;
    switch (s.kind) {
      case Shape::Kind::kSphere:
        include(s.centre - Vec3{s.radius, s.radius, s.radius});
        include(s.centre + Vec3{s.radius, s.radius, s.radius});
        break;
      case Shape::Kind::kCylinder:
        include(s.centre - Vec3{s.radius, s.half_height, s.radius});
        include(s.centre + Vec3{s.radius, s.half_height, s.radius});
        break;
      case Shape::Kind::kQuad:
        for (const double i : {-1.0, 1.0})
          for (const double j : {-1.0, 1.0}) include(s.centre + (i * s.half_width) * s.axis_s + (j * s.half_height) * s.axis_t);
        break;
    }
  }
  if (scene.fibers && !scene.fibers->empty()) {
    const yarn::Float3 lo = scene.fibers->lower(), hi = scene.fibers->upper();
    if (lo.x <= hi.x && lo.y <= hi.y && lo.z <= hi.z) {
      include({lo.x, lo.y, lo.z});
      include({hi.x, hi.y, hi.z});
    }
  }
  const double half_diagonal = 0.5 * Length(upper - lower);
  if (IsFinite(lower) && IsFinite(upper) && half_diagonal > 0) {
    *centre = 0.5 * (lower + upper);
    *radius = half_diagonal;
    return;
  }
  *centre = camera.look_at;
  *radius = 0.25 * Length(camera.look_at - camera.position);
}

}  // namespace loomlight::render

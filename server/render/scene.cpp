#include "server/render/scene.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <numbers>
#include <utility>

#include "server/models/float_angles.h"
#include "server/render/mesh_geometry.h"
#include "server/render/scene_registry.h"
#include "server/yarn/fiber_scene.h"

namespace loomlight::render {
namespace {

constexpr double kDegree = std::numbers::pi / 180;

// Smallest root of a x^2 + 2 b x + c = 0 in (lo, hi) that passes `accept`, by the stable quadratic formula.
template <class Accept>
bool NearestRoot(double a, double b, double c, double lo, double hi, Accept accept, double* t) {
  const double disc = b * b - a * c;
  if (a == 0 || disc < 0) return false;
  const double q = -(b + std::copysign(std::sqrt(disc), b));
  double r0 = q / a, r1 = q != 0 ? c / q : r0;
  if (r0 > r1) std::swap(r0, r1);
  for (double r : {r0, r1})
    if (r > lo && r < hi && accept(r)) {
      *t = r;
      return true;
    }
  return false;
}

// The surface at a point on the shape: its normal, tangents and surface coordinates (s, t).
void SurfaceAt(const Shape& shape, Vec3 position, Hit* hit) {
  hit->position = position;
  switch (shape.kind) {
    case Shape::Kind::kSphere: {
      hit->normal = Normalize(position - shape.centre);
      const Vec3 n = hit->normal;
      Vec3 around = Cross({0, 1, 0}, n);  // east; undefined at the poles
      if (Length(around) < 1e-9) around = {1, 0, 0};
      hit->tangent_s = Normalize(around);
      hit->tangent_t = Cross(n, hit->tangent_s);
      hit->s = shape.radius * models::float_angles::Atan2(float(n.x), float(n.z));  // in float: ~1e-7 of the radius
      hit->t = shape.radius * std::asin(std::clamp(n.y, -1.0, 1.0));
      return;
    }
    case Shape::Kind::kCylinder: {
      const Vec3 radial = position - shape.centre;
      hit->normal = Normalize({radial.x, 0, radial.z});
      hit->tangent_s = {hit->normal.z, 0, -hit->normal.x};  // (+y) x n: around the axis
      hit->tangent_t = {0, 1, 0};
      hit->s = shape.radius * models::float_angles::Atan2(float(hit->normal.x), float(hit->normal.z));
      hit->t = radial.y;
      return;
    }
    case Shape::Kind::kQuad:
      hit->normal = Cross(shape.axis_s, shape.axis_t);
      hit->tangent_s = shape.axis_s;
      hit->tangent_t = shape.axis_t;
      hit->s = Dot(position - shape.centre, shape.axis_s);
      hit->t = Dot(position - shape.centre, shape.axis_t);
      return;
  }
}

// The distance along d to the shape's first point in (lo, hi), without its surface (all an occlusion test needs).
bool ShapeDistance(const Shape& shape, Vec3 o, Vec3 d, double lo, double hi, double* t) {
  switch (shape.kind) {
    case Shape::Kind::kSphere: {
      const Vec3 oc = o - shape.centre;
      return NearestRoot(Dot(d, d), Dot(oc, d), Dot(oc, oc) - shape.radius * shape.radius, lo, hi,
                         [](double) { return true; }, t);
    }
    case Shape::Kind::kCylinder: {
      const Vec3 oc = o - shape.centre;
      const auto within = [&](double r) { return std::fabs(oc.y + r * d.y) <= shape.half_height; };
      return NearestRoot(d.x * d.x + d.z * d.z, oc.x * d.x + oc.z * d.z, oc.x * oc.x + oc.z * oc.z - shape.radius * shape.radius,
                         lo, hi, within, t);
    }
    case Shape::Kind::kQuad: {
      const Vec3 n = Cross(shape.axis_s, shape.axis_t);
      const double denom = Dot(d, n);
      if (std::fabs(denom) < 1e-12) return false;
      const double along = Dot(shape.centre - o, n) / denom;
      if (!(along > lo && along < hi)) return false;
      const Vec3 p = o + along * d;
      const double s = Dot(p - shape.centre, shape.axis_s), v = Dot(p - shape.centre, shape.axis_t);
      if (std::fabs(s) > shape.half_width || std::fabs(v) > shape.half_height) return false;
      *t = along;
      return true;
    }
  }
  return false;
}

bool IntersectShape(const Shape& shape, Vec3 o, Vec3 d, double lo, double hi, Hit* hit) {
  double t;
  if (!ShapeDistance(shape, o, d, lo, hi, &t)) return false;
  hit->distance = t;
  SurfaceAt(shape, o + t * d, hit);
  return true;
}

}  // namespace

Shape SphereShape(Vec3 centre, double radius) {
  Shape s;
  s.centre = centre;
  s.radius = radius;
  return s;
}

Shape CylinderShape(Vec3 centre, double radius, double half_height) {
  Shape s;
  s.kind = Shape::Kind::kCylinder;
  s.centre = centre;
  s.radius = radius;
  s.half_height = half_height;
  return s;
}

Shape QuadShape(Vec3 centre, Vec3 axis_s, Vec3 axis_t, double half_width, double half_height) {
  Shape s;
  s.kind = Shape::Kind::kQuad;
  s.centre = centre;
  s.axis_s = Normalize(axis_s);
  s.axis_t = Normalize(axis_t);
  s.half_width = half_width;
  s.half_height = half_height;
  return s;
}

Hit PointOnShape(const Shape& shape, double s, double t) {
  Vec3 position = shape.centre + s * shape.axis_s + t * shape.axis_t;  // a quad
  if (shape.kind != Shape::Kind::kQuad) {
    // SurfaceAt's arc lengths inverted: s around +y from +z toward +x; t up (a sphere's latitude times r).
    const double around = s / shape.radius, up = shape.kind == Shape::Kind::kSphere ? t / shape.radius : 0.0;
    const Vec3 normal{std::cos(up) * std::sin(around), std::sin(up), std::cos(up) * std::cos(around)};
    const Vec3 along{0, shape.kind == Shape::Kind::kCylinder ? t : 0.0, 0};
    position = shape.centre + shape.radius * normal + along;
  }
  Hit hit;
  SurfaceAt(shape, position, &hit);
  return hit;
}

PinholeCamera::PinholeCamera(const CameraSpec& spec, int width, int height)
    : position_(spec.position), width_(width), height_(height) {
  forward_ = Normalize(spec.look_at - spec.position);
  right_ = Normalize(Cross(forward_, spec.up));
  up_ = Cross(right_, forward_);
  pixel_angle_ = 2 * std::tan(0.5 * spec.fov_deg * kDegree) / height;
}

Vec3 PinholeCamera::Direction(double px, double py) const {
  const double x = (px - 0.5 * width_) * pixel_angle_, y = (0.5 * height_ - py) * pixel_angle_;
  return Normalize(forward_ + x * right_ + y * up_);
}

namespace {
yarn::FiberRay ToFiberRay(Vec3 o, Vec3 d, double lo, double hi) {
  return {{float(o.x), float(o.y), float(o.z)}, {float(d.x), float(d.y), float(d.z)}, float(lo), float(hi)};
}
Vec3 ToVec(yarn::Float3 v) { return {v.x, v.y, v.z}; }
}  // namespace

namespace {

// A periodic fiber scene traces at most this many hops from tile to tile (a ray along the cloth that long is
// inside it: Intersect reports a miss, Occluded a blocked ray).
constexpr int kMaxTileHops = 64;

// Calls trace(origin, tnear, tfar) on the ray's pieces, the origin moved into the central tile for each (above):
// `trace` returns true to stop (a hit). Returns the piece's start distance along the ray in *travelled; true
// when a piece stopped it, false when the ray left the fibers' slab or ran out of hops (*exhausted).
template <class Trace>
bool TraceTiled(const Scene::Tiling& tiling, double z_lo, double z_hi, Vec3 origin, Vec3 direction,
                double min_distance, double max_distance, Trace trace, double* travelled, bool* exhausted) {
  *travelled = 0;
  *exhausted = false;
  for (int hop = 0; hop < kMaxTileHops; ++hop) {
    origin.x -= std::floor((origin.x - tiling.x0) / tiling.period_x) * tiling.period_x;
    origin.y -= std::floor((origin.y - tiling.y0) / tiling.period_y) * tiling.period_y;
    // Distance until the piece leaves the 3 x 3 block laterally (at least one period from the central tile).
    double exit = INFINITY;
    const auto bound = [&](double o, double d, double lo, double period) {
      if (d > 0) exit = std::min(exit, (lo + 2 * period - o) / d);
      if (d < 0) exit = std::min(exit, (lo - period - o) / d);
    };
    bound(origin.x, direction.x, tiling.x0, tiling.period_x);
    bound(origin.y, direction.y, tiling.y0, tiling.period_y);
    const double lo = std::max(min_distance - *travelled, 0.0), hi = std::min(max_distance - *travelled, exit);
    if (lo <= hi && trace(origin, lo, hi)) return true;
    if (max_distance - *travelled <= exit) return false;
    const Vec3 next = origin + exit * direction;
    if ((direction.z >= 0 && next.z > z_hi) || (direction.z <= 0 && next.z < z_lo)) return false;  // out of the slab
    origin = next;
    *travelled += exit;
  }
  *exhausted = true;
  return false;
}

}  // namespace

namespace {

// A fiber hit as the renderer's Hit: at `distance` along the ray, at `position` (in the central tile's copy when
// periodic).
void FiberHitToHit(const yarn::FiberHit& h, double distance, Vec3 position, int object, Hit* hit) {
  hit->distance = distance;
  hit->object = object;
  hit->position = position;
  hit->normal = ToVec(h.normal);
  hit->fiber = true;
  hit->fiber_axis = ToVec(h.shading_tangent);
  hit->fiber_radius = 0.5 * h.width;
  hit->fiber_yarn = h.yarn;
  hit->fiber_core = h.type == yarn::FiberType::kCore;
  hit->fiber_core_axis = ToVec(h.tangent);
  hit->fiber_core_free_path = h.core_free_path;
  hit->fiber_core_fiber_width = h.core_fiber_width;
  // The axis made perpendicular to the normal (they are perpendicular on a straight fiber's side).
  Vec3 along = hit->fiber_axis - Dot(hit->fiber_axis, hit->normal) * hit->normal;
  if (Length(along) < 1e-9) along = AnyPerpendicular(hit->normal);
  hit->tangent_s = Normalize(along);
  hit->tangent_t = Cross(hit->normal, hit->tangent_s);
  hit->s = hit->t = 0;
}

}  // namespace

bool Scene::IsShape(size_t i) const {
  if (objects[i].fibers) return false;
  if (!mesh) return true;
  const size_t first = static_cast<size_t>(std::max(mesh_first_object, 0));
  return i < first || i - first >= mesh->materials();
}

bool Scene::IntersectShapes(Vec3 origin, Vec3 direction, double min_distance, double max_distance, Hit* hit) const {
  bool found = false;
  for (size_t i = 0; i < objects.size(); ++i) {
    if (!IsShape(i)) continue;
    Hit candidate;
    if (IntersectShape(objects[i].shape, origin, direction, min_distance, max_distance, &candidate)) {
      max_distance = candidate.distance;
      candidate.object = static_cast<int>(i);
      *hit = candidate;
      found = true;
    }
  }
  return found;
}

bool Scene::Intersect(Vec3 origin, Vec3 direction, double min_distance, double max_distance, Hit* hit) const {
  bool found = false;
  if (fibers) {
    yarn::FiberHit h;
    Vec3 piece_origin = origin;
    const auto trace = [&](Vec3 o, double lo, double hi) {
      const yarn::FiberRay ray = ToFiberRay(o, direction, lo, hi);
      piece_origin = o;
      return fibers->Intersect({&ray, 1}, {&h, 1}).empty() && h.hit && h.t < hi;
    };
    double travelled = 0;
    bool exhausted = false;
    const bool hit_fiber =
        tiling.period_x > 0
            ? TraceTiled(tiling, fibers->lower().z, fibers->upper().z, origin, direction, min_distance, max_distance,
                         trace, &travelled, &exhausted)
            : trace(origin, min_distance, max_distance);
    if (hit_fiber) {
      found = true;
      max_distance = travelled + h.t;
      FiberHitToHit(h, max_distance, piece_origin + double(h.t) * direction, fiber_object, hit);
    }
  }
  Hit mesh_hit;
  if (mesh && mesh->Intersect(origin, direction, min_distance, max_distance, mesh_uv_length, &mesh_hit)) {
    mesh_hit.object += mesh_first_object;
    *hit = mesh_hit;
    max_distance = mesh_hit.distance;
    found = true;
  }
  return IntersectShapes(origin, direction, min_distance, max_distance, hit) || found;
}

void Scene::IntersectFrom(Vec3 origin, std::span<const Vec3> directions, std::span<Hit> hits,
                          std::span<uint8_t> found) const {
  const size_t n = directions.size();
  if (mesh && !fibers && n >= 2) {
    mesh->IntersectFrom(origin, directions, mesh_uv_length, hits, found);
    for (size_t i = 0; i < n; ++i) {
      if (found[i]) hits[i].object += mesh_first_object;
      const double max_distance = found[i] ? hits[i].distance : INFINITY;
      found[i] = IntersectShapes(origin, directions[i], 0.0, max_distance, &hits[i]) || found[i];
    }
    return;
  }
  // A periodic scene's rays part ways at its tiles' edges; a mesh among fibers (no scene has both) ray by ray.
  if (!fibers || mesh || tiling.period_x > 0 || n < 2) {
    for (size_t i = 0; i < n; ++i) found[i] = Intersect(origin, directions[i], 0.0, INFINITY, &hits[i]);
    return;
  }
  std::array<yarn::FiberRay, kMaxPacket> rays;
  std::array<yarn::FiberHit, kMaxPacket> fiber_hits;
  for (size_t first = 0; first < n; first += kMaxPacket) {
    const size_t m = std::min(kMaxPacket, n - first);
    for (size_t k = 0; k < m; ++k) rays[k] = ToFiberRay(origin, directions[first + k], 0.0, INFINITY);
    const bool traced = fibers->Intersect({rays.data(), m}, {fiber_hits.data(), m}).empty();
    for (size_t k = 0; k < m; ++k) {
      const size_t i = first + k;
      const yarn::FiberHit& h = fiber_hits[k];
      double max_distance = INFINITY;
      found[i] = traced && h.hit;
      if (found[i]) {
        max_distance = h.t;
        FiberHitToHit(h, max_distance, origin + double(h.t) * directions[i], fiber_object, &hits[i]);
      }
      found[i] = IntersectShapes(origin, directions[i], 0.0, max_distance, &hits[i]) || found[i];
    }
  }
}

bool Scene::Occluded(Vec3 origin, Vec3 direction, double max_distance, double min_distance) const {
  double distance;
  for (size_t i = 0; i < objects.size(); ++i)
    if (IsShape(i) && ShapeDistance(objects[i].shape, origin, direction, min_distance, max_distance, &distance))
      return true;
  if (mesh && mesh->Occluded(origin, direction, min_distance, max_distance)) return true;
  if (!fibers) return false;
  const auto trace = [&](Vec3 o, double lo, double hi) {
    const yarn::FiberRay ray = ToFiberRay(o, direction, lo, hi);
    uint8_t occluded = 0;
    return fibers->Occluded({&ray, 1}, {&occluded, 1}).empty() && occluded;
  };
  if (tiling.period_x <= 0) return trace(origin, min_distance, max_distance);
  double travelled = 0;
  bool exhausted = false;
  return TraceTiled(tiling, fibers->lower().z, fibers->upper().z, origin, direction, min_distance, max_distance, trace,
                    &travelled, &exhausted) ||
         exhausted;
}

Scene MakeScene(SceneKind kind) {
  const SceneSpec& spec = *SceneRegistry::Global().FindPreset(static_cast<int>(kind));
  return spec.build(models::DefaultValues(spec.params));
}

}  // namespace loomlight::render

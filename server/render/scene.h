// The Render RPC's scenes: analytic shapes (sphere, y-axis cylinders, quads) with texture coordinates whose
// axes are the thread directions, a pinhole camera and analytic lights; ray casting on the host. World
// space is right-handed, +y up, lengths in scene units (docs/thumbnails.md "Scenes").
#pragma once

#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "server/render/vec.h"

namespace loomlight::yarn {
class FiberScene;
class YarnVisibility;
}

namespace loomlight::render {

class MeshGeometry;  // server/render/mesh_geometry.h

// The registered scenes (server/render/scene_registry.h) by their ScenePreset value (the same order), for
// callers that name one in code.
// kYarn and kWovenPatch are fiber scenes: their one object is fiber curves (Scene::fibers, which the caller
// generates and builds: server/api/render_rpc.cpp), shaded one fiber at a time.
enum class SceneKind { kSphere, kCylinders, kSwatch, kCurtain, kYarn, kWovenPatch };

struct CameraSpec {
  Vec3 position, look_at;
  Vec3 up{0, 1, 0};
  double fov_deg = 40;  // vertical field of view
};

// Rays through the image plane; pixel (0, 0) is the top-left corner, x grows right, y down.
class PinholeCamera {
 public:
  PinholeCamera(const CameraSpec& spec, int width, int height);
  Vec3 position() const { return position_; }
  // The unit direction through image position (px, py) in pixels.
  Vec3 Direction(double px, double py) const;
  // The world size of one pixel at unit distance along the view axis (2 tan(fov/2) / height).
  double pixel_angle() const { return pixel_angle_; }

 private:
  Vec3 position_, forward_, right_, up_;
  double pixel_angle_;
  int width_, height_;
};

struct Light {
  enum class Type { kDirectional, kPoint, kRect };
  Type type = Type::kDirectional;
  Vec3 direction;  // directional: unit, toward the light; rect: unit, the way its emitting side faces
  Vec3 position;   // point; rect: its centre
  Rgb rgb;         // directional: irradiance perpendicular to the beam; point: radiant intensity; rect: radiance
  // Rect (a softbox, one-sided; server/render/lighting_presets.h RectLight): unit edge directions with
  // Cross(axis_u, axis_v) = direction, and the full extents along them.
  Vec3 axis_u, axis_v;
  double width = 0, height = 0;
};

struct Shape {
  enum class Kind { kSphere, kCylinder, kQuad };
  Kind kind = Kind::kSphere;
  Vec3 centre;
  double radius = 1;       // sphere, cylinder
  double half_height = 1;  // cylinder (along +y); quad: half extent along axis_t
  double half_width = 1;   // quad: half extent along axis_s
  Vec3 axis_s{1, 0, 0}, axis_t{0, 1, 0};  // quad; its front normal is axis_s x axis_t
};

struct SceneObject {
  std::string name;
  Shape shape;
  double thread_angle_deg = 0;  // the object's thread 1 direction, from the surface's s axis toward t
  bool fibers = false;          // the object is Scene::fibers (its shape is unused)
};

// A ray-surface intersection. (tangent_s, tangent_t, normal) is right-handed and orthonormal; s and t are
// surface coordinates in scene units along the tangents (arc lengths on curved shapes). On a fiber, normal
// faces the ray, tangent_s is the fiber's axis made perpendicular to it, and fiber_axis the axis itself.
struct Hit {
  double distance = 0;
  int object = -1;
  Vec3 position, normal, tangent_s, tangent_t;
  double s = 0, t = 0;
  bool fiber = false;
  Vec3 fiber_axis;
  double fiber_radius = 0;
  int fiber_yarn = -1;  // the yarn the fiber belongs to (the fiber scene's yarn index)
  bool fiber_core = false;  // a ply's core fiber (standing for its inner fibers)
  // Cores: the curve's own direction (fiber_axis is its fibers' at the hit), the mean free path across its
  // fibers and their width.
  Vec3 fiber_core_axis;
  double fiber_core_free_path = 0;
  double fiber_core_fiber_width = 0;
};

// The shapes scenes are built of (server/render/scenes/): a sphere; a cylinder along +y, open at its ends; a quad
// whose axes are normalised here.
Shape SphereShape(Vec3 centre, double radius);
Shape CylinderShape(Vec3 centre, double radius, double half_height);
Shape QuadShape(Vec3 centre, Vec3 axis_s, Vec3 axis_t, double half_width, double half_height);

// The surface point of a (non-fiber) shape at surface coordinates (s, t), as a hit there would report it
// (distance 0, object -1): s around the axis and t along it on spheres (latitude) and cylinders, along the
// axes on quads.
Hit PointOnShape(const Shape& shape, double s, double t);

struct Scene {
  std::vector<SceneObject> objects;
  CameraSpec default_camera;
  double default_texture_scale = 8;      // pattern repeats per unit
  std::vector<Light> default_lights;     // used, with the built-in sky, when a request gives no lighting
  double default_environment_intensity = 1;
  bool default_environment = true;       // default lighting includes the built-in sky
  // Fiber scenes: the fiber curves, hit as object fiber_object; constant ambient radiance (Wu and Yuksel
  // Eq. 7's L_amb) for the default lighting.
  std::shared_ptr<const yarn::FiberScene> fibers;
  // The same yarns' cheap visibility (cross-section slices and occlusion, other yarns as tubes).
  std::shared_ptr<const yarn::YarnVisibility> fiber_visibility;
  int fiber_object = -1;
  double default_ambient = 0;
  // Fiber scenes standing for an endless periodic cloth (a BTF's tile, server/render/btf_capture.h): the fibers
  // repeat with periods (period_x, period_y) in the xy plane, and `fibers` holds at least the 3 x 3 tiles
  // around the central one, [x0, x0 + period_x] x [y0, y0 + period_y]. A ray is traced from its origin moved
  // into the central tile by whole periods until it leaves the 3 x 3 block, then moved back again, so it never
  // meets the block's edges. (Each hop meets a different instance of the random fibers: the seam is where a
  // period would join in any case.) period_x = 0: not periodic.
  struct Tiling {
    double x0 = 0, y0 = 0, period_x = 0, period_y = 0;
  } tiling;
  // A triangle mesh (a client's garment or product, server/render/mesh_geometry.h), hit together with the shapes
  // and fibers: a hit on its material k is object mesh_first_object + k (those objects, one per material name of
  // the mesh, stand for the mesh: their shapes are not intersected); its texture coordinates are the UVs times
  // mesh_uv_length (scene units per UV unit).
  std::shared_ptr<const MeshGeometry> mesh;
  int mesh_first_object = 0;
  double mesh_uv_length = 1;

  // The nearest hit with distance in (min_distance, max_distance); false when there is none.
  bool Intersect(Vec3 origin, Vec3 direction, double min_distance, double max_distance, Hit* hit) const;
  // The closest hits of rays from one origin (a pixel's camera rays), as Intersect from 0 to infinity would
  // find them: found[i] = 1 with hits[i] filled, or 0. The fibers or the mesh take them as packets of up to
  // kMaxPacket (Embree's coherent rays). Spans of one length.
  static constexpr size_t kMaxPacket = 16;
  void IntersectFrom(Vec3 origin, std::span<const Vec3> directions, std::span<Hit> hits, std::span<uint8_t> found) const;
  bool Occluded(Vec3 origin, Vec3 direction, double max_distance, double min_distance = 0) const;

 private:
  // The analytic objects only: the closest hit closer than max_distance, into *hit.
  bool IntersectShapes(Vec3 origin, Vec3 direction, double min_distance, double max_distance, Hit* hit) const;
  // Object i is an analytic shape: neither the fibers nor one of the mesh's materials.
  bool IsShape(size_t i) const;
};

// The registered scene of that kind at its parameters' defaults (SceneRegistry::Global()).
Scene MakeScene(SceneKind kind);

}  // namespace loomlight::render

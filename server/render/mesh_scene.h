// Scenes of meshes (docs/products.md): a client's garment or product, or a built-in product scene's mesh made
// by cloth simulation (server/render/scenes/meshes/). One scene object per material of the mesh, named as the
// mesh names it; a camera that frames the mesh; the thread directions from the mesh's UV layout.
#pragma once

#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "server/render/mesh_geometry.h"
#include "server/render/scene.h"

namespace loomlight::render {

// Pattern repeats per metre of surface when a request gives no texture_scale for a mesh: 2 mm per repeat, a
// fine shirting or suiting weave seen at catalogue distance (its threads smaller than a pixel, its texture in
// close-ups).
constexpr double kDefaultMeshRepeatsPerMetre = 500;
constexpr double kDefaultMeshFovDeg = 30;
constexpr double kDefaultMeshElevationDeg = 17;  // the camera a little above the product's middle
constexpr std::string_view kDefaultMeshLighting = "studio";  // a lighting preset (lighting_presets.h)

// The sphere around the mesh's bounds: what the camera frames and the studio lights are placed around.
struct Subject {
  Vec3 centre;
  double radius = 1;
};
Subject SubjectOf(const assets::TriangleMesh& mesh);

// A camera seeing the whole mesh from the front (+z, glTF's forward), `elevation_deg` above its middle, as near
// as lets every corner of its bounding box stay in the frame with a margin, in any turn of a turntable about +y.
CameraSpec FramingCamera(const assets::TriangleMesh& mesh, int width, int height,
                         double elevation_deg = kDefaultMeshElevationDeg, double fov_deg = kDefaultMeshFovDeg);

// A turntable: `views` cameras, the first `first`, each turned by 360 / views degrees more about the axis
// through first.look_at along first.up.
std::vector<CameraSpec> TurntableCameras(const CameraSpec& first, int views);
// The turn of turntable view k of `views` (radians) and a light turned with it about the same axis.
double TurntableAngle(int k, int views);
Light TurnLight(const Light& light, const CameraSpec& first, double angle);

// The scene of a built mesh: object k is the mesh's material k ("mesh material 'NAME'"); texture coordinates in
// scene units are the UVs times uv_length (scene units per UV unit: 1 counts repeats per UV unit, the mesh's
// metres_per_uv counts them per metre); default camera framing it at `width` x `height` (the request's), lit by
// the studio preset, on no environment, with kDefaultMeshRepeatsPerMetre converted to uv_length's unit.
Scene MeshScene(std::shared_ptr<const MeshGeometry> geometry, double uv_length, int width = 1, int height = 1,
                double elevation_deg = kDefaultMeshElevationDeg);
// The name the fidelity report gives mesh material `name`.
std::string MeshObjectName(std::string_view material_name);

// A built-in product mesh (server/render/scenes/builtin_meshes.h) parsed and built once, on first use, and
// kept for the process (they are small). Null when there is no such mesh or it does not parse (a build error).
std::shared_ptr<const MeshGeometry> BuiltinMeshGeometry(std::string_view name);

// A built-in product scene: its mesh's scene (texture scale in repeats per metre of cloth), framed, lit by the
// studio preset; every object wears the request's material. A mesh that is missing gives a scene with no objects.
Scene ProductScene(std::string_view mesh_name, double elevation_deg = kDefaultMeshElevationDeg);

}  // namespace loomlight::render

// Fuzz target: client mesh files (server/assets/mesh_file.h), glTF (GLB and JSON) through tinygltf and OBJ through
// tinyobjloader, the format told by the bytes as MESH_FORMAT_AUTO tells it. Input: the file's bytes, parsed under
// small limits. Checks ParseMesh's contract: an error is a bounded one-line message and leaves the output
// untouched; a success is a mesh the renderer can take: every index in range, every number finite, unit normals,
// unit tangents perpendicular to them with w = +-1, bounds that hold every position, the limits kept.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>

#include "server/assets/mesh_file.h"
#include "tests/fuzz/fuzz_check.h"

namespace loomlight::fuzz {
namespace {

using assets::MeshLimits;
using assets::TriangleMesh;

MeshLimits SmallLimits() {
  MeshLimits limits;
  limits.max_bytes = (uint64_t{1} << 20) + 4096;
  limits.max_triangles = 20000;
  limits.max_vertices = 20000;
  limits.max_materials = 8;
  limits.max_uv_sets = 4;
  return limits;
}

bool Finite(double v) { return std::isfinite(v); }

template <size_t N>
bool Finite(const std::array<float, N>& v) {
  for (float x : v) {
    if (!std::isfinite(x)) return false;
  }
  return true;
}

double Length3(const float* v) { return std::sqrt(double(v[0]) * v[0] + double(v[1]) * v[1] + double(v[2]) * v[2]); }

void CheckMesh(const TriangleMesh& mesh, const MeshLimits& limits, uint64_t dropped) {
  const size_t vertices = mesh.positions.size();
  FUZZ_CHECK(!mesh.triangles.empty(), "a parsed mesh without triangles");
  FUZZ_CHECK(mesh.triangles.size() + dropped <= limits.max_triangles,
             std::to_string(mesh.triangles.size()) + " + " + std::to_string(dropped) + " triangles");
  FUZZ_CHECK(vertices <= limits.max_vertices, std::to_string(vertices) + " vertices");
  FUZZ_CHECK(!mesh.material_names.empty() && mesh.material_names.size() <= limits.max_materials,
             std::to_string(mesh.material_names.size()) + " materials");
  FUZZ_CHECK(mesh.triangle_material.size() == mesh.triangles.size(), "a material per triangle");
  FUZZ_CHECK(mesh.normals.size() == vertices, "a normal per vertex");
  FUZZ_CHECK(mesh.uvs.empty() == !mesh.file_uvs, "uvs present exactly when the file gave them");
  FUZZ_CHECK(mesh.uvs.empty() || mesh.uvs.size() == vertices, "a uv per vertex");
  FUZZ_CHECK(mesh.tangents.size() == mesh.uvs.size(), "a tangent per uv");
  std::vector<uint8_t> used(vertices), material_used(mesh.material_names.size());
  for (size_t t = 0; t < mesh.triangles.size(); ++t) {
    for (uint32_t v : mesh.triangles[t]) {
      FUZZ_CHECK(v < vertices, "triangle " + std::to_string(t) + " index " + std::to_string(v) + " of " +
                                   std::to_string(vertices));
      used[v] = 1;
    }
    FUZZ_CHECK(mesh.triangle_material[t] < mesh.material_names.size(), "material index out of range");
    material_used[mesh.triangle_material[t]] = 1;
  }
  for (size_t v = 0; v < vertices; ++v) {
    const std::string at = "vertex " + std::to_string(v);
    FUZZ_CHECK(used[v], at + " unused");
    const auto& p = mesh.positions[v];
    FUZZ_CHECK(Finite(p), at + " position not finite");
    for (int c = 0; c < 3; ++c) {
      FUZZ_CHECK(p[c] >= mesh.bounds_min[c] && p[c] <= mesh.bounds_max[c], at + " outside the bounds");
    }
    FUZZ_CHECK(Finite(mesh.normals[v]) && std::fabs(Length3(mesh.normals[v].data()) - 1) < 1e-4,
               at + " normal length " + std::to_string(Length3(mesh.normals[v].data())));
    if (mesh.uvs.empty()) continue;
    FUZZ_CHECK(Finite(mesh.uvs[v]), at + " uv not finite");
    const auto& t = mesh.tangents[v];
    const auto& n = mesh.normals[v];
    FUZZ_CHECK(Finite(t) && std::fabs(Length3(t.data()) - 1) < 1e-4, at + " tangent not unit");
    FUZZ_CHECK(std::fabs(double(t[0]) * n[0] + double(t[1]) * n[1] + double(t[2]) * n[2]) < 1e-3,
               at + " tangent not perpendicular to the normal");
    FUZZ_CHECK(t[3] == 1 || t[3] == -1, at + " tangent w " + std::to_string(t[3]));
  }
  for (size_t m = 0; m < material_used.size(); ++m) FUZZ_CHECK(material_used[m], "material " + std::to_string(m) + " unused");
  for (const std::string& name : mesh.material_names) {
    FUZZ_CHECK(name.empty() || MessageDefect(name).empty(), "material name " + MessageDefect(name));
  }
  FUZZ_CHECK(Finite(mesh.surface_area) && mesh.surface_area > 0, "surface area " + std::to_string(mesh.surface_area));
  FUZZ_CHECK(Finite(mesh.metres_per_uv) && mesh.metres_per_uv >= 0 && (mesh.file_uvs || mesh.metres_per_uv == 0),
             "metres_per_uv " + std::to_string(mesh.metres_per_uv));
  FUZZ_CHECK(!mesh.file_tangents || mesh.file_uvs, "tangents from the file without uvs");
  v1::MeshInfo info;
  assets::DescribeMesh(mesh, &info);
  FUZZ_CHECK(info.triangles() == mesh.triangles.size() && info.vertices() == vertices &&
                 size_t(info.materials_size()) == mesh.material_names.size() && info.bounds_min_size() == 3,
             info.ShortDebugString());
}

}  // namespace
}  // namespace loomlight::fuzz

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace loomlight::fuzz;
  const std::string_view bytes(reinterpret_cast<const char*>(data), size);
  const MeshLimits limits = SmallLimits();
  TriangleMesh mesh;
  mesh.material_names = {"untouched"};
  uint64_t dropped = 0;
  const std::string error =
      loomlight::assets::ParseMesh(bytes, loomlight::v1::MESH_FORMAT_AUTO, limits, &mesh, &dropped);
  if (error.empty()) {
    CheckMesh(mesh, limits, dropped);
    return 0;
  }
  FUZZ_CHECK(MessageDefect(error).empty(), MessageDefect(error) + ": " + error);
  FUZZ_CHECK(mesh.positions.empty() && mesh.material_names.size() == 1 && mesh.material_names[0] == "untouched",
             "a failed parse changed the output: " + error);
  return 0;
}

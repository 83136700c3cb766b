// A client's mesh file, parsed and checked (docs/products.md "Meshes"): glTF 2.0 (GLB, or JSON with its buffers
// embedded as data: URIs) through tinygltf, Wavefront OBJ through tinyobjloader, into one indexed triangle mesh
// in world space (a glTF's node transforms applied) with per-vertex normals, texture coordinates and UV tangents
// (computed where the file has none). Nothing a file names is ever opened: tinygltf's file callbacks refuse every
// path and URI, and OBJ's material libraries are not read (usemtl names are kept). Embedded images are not
// decoded. Every limit below is checked before the memory it guards is taken, so the cost of a parse grows with
// the file's size, not faster.
#pragma once

#include <array>
#include <cstdint>
#include <functional>
#include <string>
#include <string_view>
#include <vector>

#include "loomlight/v1/loomlight.pb.h"

namespace loomlight::assets {

struct MeshLimits {
  uint64_t max_bytes = uint64_t{64} << 20;  // the file
  uint64_t max_triangles = 4'000'000;
  uint64_t max_vertices = 4'000'000;
  uint32_t max_materials = 64;
  uint32_t max_uv_sets = 8;                 // glTF TEXCOORD_n; only TEXCOORD_0 is used
};

// A triangle mesh ready for the renderer. Vertices are welded only as the file shares them.
struct TriangleMesh {
  std::vector<std::array<float, 3>> positions;  // world space (glTF: metres; OBJ: the file's units)
  std::vector<std::array<float, 3>> normals;    // unit, per vertex
  // Per vertex; empty unless the file gives every vertex one. OBJ's (and OpenGL's) convention: v runs up the
  // texture; glTF's texcoords (v down) are read as v' = 1 - v, so a glTF and an OBJ export of one mesh agree.
  std::vector<std::array<float, 2>> uvs;
  // Per vertex: unit tangent along +u (dP/du made perpendicular to the normal) and the sign w of the bitangent
  // (bitangent = w * normal x tangent points along +v), as glTF's TANGENT; empty when there are no uvs.
  std::vector<std::array<float, 4>> tangents;
  std::vector<std::array<uint32_t, 3>> triangles;
  std::vector<uint32_t> triangle_material;  // per triangle: an index into material_names
  // In order of first use; "" for triangles without a material. glTF: the material's name, or "materials[N]" for
  // an unnamed one; OBJ: the usemtl name. Printable UTF-8, at most 256 bytes (else the file is refused).
  std::vector<std::string> material_names;
  bool file_normals = false, file_uvs = false, file_tangents = false;
  std::array<double, 3> bounds_min{0, 0, 0}, bounds_max{0, 0, 0};
  double surface_area = 0;   // mesh units squared
  double metres_per_uv = 0;  // sqrt(surface area / UV area): the surface length one UV unit spans, on average
  uint64_t memory_bytes() const;  // what the vectors hold
};

// The format the bytes are in: `declared` unless AUTO, else sniffed ("glTF" magic: GLB; '{' first: glTF JSON;
// otherwise OBJ).
v1::MeshFormat DetectMeshFormat(std::string_view bytes, v1::MeshFormat declared);

// Parses and checks `bytes`. "" with *out filled, or "reason" (a client's text in it quoted and cut short): not a
// mesh of that format, an external uri, over a limit (naming it), NaN or infinite positions, normals or UVs,
// indices out of range, no triangles, every triangle degenerate; also refused: sparse accessors, required glTF
// extensions other than KHR_materials_*, KHR_texture_transform and KHR_lights_punctual, node hierarchies deeper
// than 64 or with cycles, JSON nested deeper than 64, OBJ faces of more than 64 vertices (tinyobjloader's
// triangulation of an n-gon costs n^2 or more) and OBJ 't' lines (tinyobjloader sizes their arrays from the counts
// they state). glTF: the default scene (else the first, else every root node),
// triangles, strips and fans (points and lines are skipped); a mesh under several nodes counts once per node
// against max_triangles before any is expanded. Degenerate triangles (zero area) among good ones are dropped
// and counted in *dropped (may be null); *out is written only on success. `stop` is asked between stages and
// every ~64k elements; true stops the parse with "stopped".
std::string ParseMesh(std::string_view bytes, v1::MeshFormat format, const MeshLimits& limits, TriangleMesh* out,
                      uint64_t* dropped = nullptr, const std::function<bool()>& stop = {});

// The MeshInfo of a parsed mesh (name, bytes and format left to the caller).
void DescribeMesh(const TriangleMesh& mesh, v1::MeshInfo* info);

}  // namespace loomlight::assets
